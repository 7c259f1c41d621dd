"""``craft eval sim``: labels, scene sampling, the CLI's JSON, determinism; the full run is slow."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from craft_e.paths import REPO_ROOT
from craft_e.runtime.evaluation.methods import select_methods
from craft_e.runtime.evaluation.sim_eval import (
    LabelsError,
    load_sim_labels,
    make_episode_specs,
)
from craft_e.runtime.sim.assets import object_catalog

DEV_LABELS = REPO_ROOT / "artifacts/labels/sim_dev_labels.csv"


def test_labels_accept_asset_ids_and_plain_names(tmp_path: Path) -> None:
    path = tmp_path / "labels.csv"
    path.write_text("# comment\nverb,object\ncut,knife\nwrite,Marker\nwrite,black_marker\n\n")
    labels = load_sim_labels(path)
    assert [(p.verb, p.object) for p in labels.pairs] == [("cut", "knife"), ("write", "marker"),
                                                          ("write", "black_marker")]
    markers = {a for a, o in object_catalog().items() if o.name == "marker"}
    assert set(labels.pairs[1].assets) == markers and len(markers) == 4
    assert labels.affording["write"] == markers
    path.write_text("cut,knive\n")
    with pytest.raises(LabelsError, match="knife"):
        load_sim_labels(path)
    path.write_text("cut,knife,extra\n")
    with pytest.raises(LabelsError, match=":1: expected"):
        load_sim_labels(path)


def test_dev_labels_cover_a_dozen_verbs() -> None:
    labels = load_sim_labels(DEV_LABELS)
    assert len(labels.verbs) == 12 and len(labels.pairs) >= 30


def test_scenes_follow_the_protocol_and_do_not_depend_on_other_pairs() -> None:
    labels = load_sim_labels(DEV_LABELS)
    catalog = object_catalog()
    specs = make_episode_specs(labels, layouts=2, max_pairs=2, min_gap=None)
    assert [s.id for s in specs] == ["cut/knife/0", "cut/knife/1", "cut/scissors/0", "cut/scissors/1"]
    for s in specs:
        names = [catalog[a].name for a in s.scene.assets]
        assert len(set(names)) == 5  # distinct objects
        assert not set(s.scene.distractors) & labels.affording["cut"]
    assert specs[0].scene != specs[1].scene
    again = make_episode_specs(labels, layouts=2, max_pairs=1, min_gap=None)
    assert again == specs[:2]
    assert make_episode_specs(labels, layouts=1, max_pairs=1, seed=1, min_gap=None)[0] != specs[0]


def test_method_selection() -> None:
    assert [m.name for m in select_methods()] == ["CRAFT-E", "CRAFT", "direct-LLM", "alignment-only"]
    with pytest.raises(ValueError, match="unknown method"):
        select_methods(["GPT-5"])


def _run_cli(tmp_path: Path, name: str) -> dict[str, Any]:
    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app

    labels = tmp_path / "labels.csv"  # the same file for both runs: its path is in the JSON
    if not labels.exists():
        labels.write_text("verb,object\ncut,knife\n")
    out = tmp_path / f"{name}.json"
    result = CliRunner().invoke(app, ["eval", "sim", "--labels", str(labels), "--max-pairs", "1",
                                      "--layouts", "1", "--json", str(out), "--markdown",
                                      str(tmp_path / f"{name}.md")])
    assert result.exit_code == 0, result.output
    assert "Grasp Rate" in result.output
    data: dict[str, Any] = json.loads(out.read_text())
    return data


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("eval_sim")


@pytest.fixture(scope="module")
def first_run(run_dir: Path) -> dict[str, Any]:
    return _run_cli(run_dir, "first")


def test_cli_writes_the_paper_table_as_json(first_run: dict[str, Any]) -> None:
    methods = first_run["methods"]
    assert set(methods) == {"CRAFT-E", "CRAFT", "direct-LLM", "alignment-only"}
    for row in methods.values():
        for key in ("three_d", "detect", "grasp_rate"):
            assert 0.0 <= row[key] <= 1.0
        assert sum(row["failures"].values()) == 1 and len(row["episodes"]) == 1
        episode = row["episodes"][0]
        assert row["grasp_rate"] == float(episode["success"])
        assert row["detect"] == float(episode["detect"])
    assert first_run["config"]["episodes"] == 1 and len(first_run["episodes"]) == 1
    assert first_run["episodes"][0]["target"] == "knife"


def test_two_runs_give_identical_json(first_run: dict[str, Any], run_dir: Path) -> None:
    second = _run_cli(run_dir, "second")
    assert json.dumps(second, sort_keys=True) == json.dumps(first_run, sort_keys=True)


@pytest.mark.slow
def test_full_dev_run(tmp_path: Path) -> None:
    """The whole dev label set (105 episodes, ~6 min on 2 cores)."""
    from craft_e.runtime.evaluation.sim_eval import evaluate_sim

    report = evaluate_sim(DEV_LABELS)
    data = report.to_dict()
    assert data["config"]["episodes"] == 105
    assert all(0.0 <= m["grasp_rate"] <= 1.0 for m in data["methods"].values())
