"""The Zhu dev-set evaluation: AP arithmetic, tie handling, and the CLI on the shipped bundles."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from craft_e.paths import KB_DIR, shared_dir
from craft_e.runtime.cli.main import app
from craft_e.runtime.evaluation.zhu import (
    ZHU_AFFORDANCES,
    average_precision,
    chance_ap,
    read_zhu_matrix,
)

MATRIX = shared_dir() / "data/affordance_dev/zhu2014_affordance_matrix.csv"


def test_average_precision_matches_hand_computation() -> None:
    scores = np.array([3.0, 2.0, 1.0, 0.0])
    labels = np.array([True, False, True, False])
    assert average_precision(scores, labels) == pytest.approx((1.0 + 2.0 / 3.0) / 2.0)


def test_all_tied_scores_give_the_positive_rate() -> None:
    # A KB that reaches no object must not get credit from an arbitrary tie-break.
    labels = np.array([True, False, False, True, False])
    assert average_precision(np.zeros(5), labels) == pytest.approx(0.4)


def test_matrix_reads_every_affordance_and_object() -> None:
    matrix = read_zhu_matrix(MATRIX)
    assert set(matrix.labels) == set(ZHU_AFFORDANCES.values())
    assert "axe" in matrix.objects and "walkie-talkie" in matrix.objects
    assert all(len(v) == len(matrix.objects) for v in matrix.labels.values())
    assert 0.0 < chance_ap(matrix)["ride"] < 1.0


def test_cli_scores_shipped_bundles(tmp_path: Path) -> None:
    out = tmp_path / "zhu.json"
    result = CliRunner().invoke(
        app, ["eval", "zhu", "--kb", str(KB_DIR / "craft-e-default"), "--json", str(out)]
    )
    assert result.exit_code == 0, result.output
    columns = json.loads(out.read_text())
    ours = columns["craft-e-default (sum-tanh)"]
    chance = columns["chance"]
    mean = lambda col: float(np.mean([col[v] for v in ZHU_AFFORDANCES.values()]))  # noqa: E731
    assert mean(ours) > mean(chance) + 0.2  # the curated KB ranks far above chance
    assert ours["write with"] > 0.9


def _matrix(tmp_path: Path, rows: list[str]) -> Path:
    path = tmp_path / "zhu.csv"
    path.write_text("".join(r + "\n" for r in rows), encoding="utf-8")
    return path


@pytest.mark.parametrize(("rows", "message"), [
    ([], "empty; expected a header row"),
    (["synset,Grasp"], ":1: the header lacks the column(s)"),
    (["HEADER", "axe.n.01,1"], ":2: 2 cells, the header has"),
    (["HEADER", "ROW:x"], ":2: affordance cells must be 0 or 1"),
    (["HEADER", "ROW:0", "ROW:1"], ":3: object 'axe' again (first on line 2)"),
    (["HEADER"], "no object rows after the header"),
])
def test_a_malformed_matrix_is_named_with_its_line(tmp_path: Path, rows: list[str], message: str) -> None:
    header = "synset," + ",".join(ZHU_AFFORDANCES)
    cells = len(ZHU_AFFORDANCES)
    filled = [header if r == "HEADER" else
              "axe.n.01," + ",".join([r.split(":")[1]] * cells) if r.startswith("ROW:") else r for r in rows]
    path = _matrix(tmp_path, filled)
    result = CliRunner().invoke(app, ["eval", "zhu", "--matrix", str(path)])
    assert result.exit_code == 2, result.output
    assert message in " ".join(result.output.split())
