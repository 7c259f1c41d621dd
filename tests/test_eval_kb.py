"""``craft eval kb``: metrics by hand, chance/oracle rows, leave-verbs-out, the CLI (synthetic labels)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from runtime_fixtures import RuntimeKBs, runtime_kbs_fixture  # noqa: F401
from typer.testing import CliRunner

from craft_e.paths import SIM_DEV_LABELS
from craft_e.runtime.cli.main import app
from craft_e.runtime.evaluation.kb_eval import (
    KBLabelsError,
    Scored,
    auc,
    episode_top1,
    episodes,
    evaluate_kbs,
    json_labels,
    leave_verbs_out,
)
from craft_e.runtime.grounding.energies import ENERGY_FORMS


def test_auc_by_hand() -> None:
    # positives score 3 and 2, negatives 2 and 1: 3>2, 3>1, 2=2 (1/2), 2>1 -> 3.5 / 4
    assert auc(np.array([3.0, 2.0, 2.0, 1.0]), np.array([True, False, True, False])) == 0.875
    assert np.isnan(auc(np.ones(3), np.ones(3, dtype=bool)))


def test_episode_top1_shares_ties() -> None:
    energy = np.array([-1.0, -1.0, 0.0, -0.5, 0.0])
    eps = np.array([[0, 1, 2, 3, 4], [3, 0, 1, 2, 4]])  # the affording candidate is column 0
    # episode 1: objects 0 and 1 tie for the best -> 1/2; episode 2: object 3 (-0.5) loses -> 0
    assert episode_top1(energy, eps) == 0.25


def write_labels(tmp: Path, objects: list[str]) -> Path:
    path = tmp / "synthetic.json"
    path.write_text(json.dumps({"_comment": "synthetic test labels", "_objects": objects,
                                "cut": ["cleaver", "hatchet"], "pour": ["teapot", "pitcher"],
                                "fly": ["broom"]}))  # fmt: skip
    return path


def test_labels_and_episodes(tmp_path: Path, runtime_kbs: RuntimeKBs) -> None:
    labels = json_labels(write_labels(tmp_path, runtime_kbs.objects))
    assert labels.name == "synthetic" and labels.objects == runtime_kbs.objects
    assert int(labels.positives["cut"].sum()) == 2
    eps = episodes(labels, "cut", 50, seed=1)
    assert eps is not None and eps.shape == (50, 5)
    assert labels.positives["cut"][eps[:, 0]].all() and not labels.positives["cut"][eps[:, 1:]].any()
    assert all(len(set(row)) == 5 for row in eps.tolist())
    again = episodes(labels, "cut", 50, seed=1)
    assert again is not None and (again == eps).all()
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"_objects": ["cup"], "cut": ["knife"]}))
    with pytest.raises(KBLabelsError, match="knife"):
        json_labels(bad)


def test_evaluate_rows(tmp_path: Path, runtime_kbs: RuntimeKBs) -> None:
    path = write_labels(tmp_path, runtime_kbs.objects)
    report = evaluate_kbs([runtime_kbs.kb, tmp_path / "missing"], [str(path)], episodes_per_verb=40, folds=2)
    rows = {r.name: r for r in report.rows}
    assert set(rows) == {"chance", "label oracle"} | {f"runtime-kb ({f})" for f in ENERGY_FORMS}
    assert rows["label oracle"].mean("synthetic", "ap") == 1.0
    assert rows["label oracle"].mean("synthetic", "top1") == 1.0
    n = len(runtime_kbs.objects)
    assert rows["chance"].mean("synthetic", "ap") == pytest.approx((2 / n + 2 / n + 1 / n) / 3)
    assert rows["chance"].mean("synthetic", "top1") == pytest.approx(0.2)
    # "fly" is not a KB verb: all-zero energies score as chance and are noted
    kb_row = rows["runtime-kb (sum-tanh)"]
    assert kb_row.per_verb["synthetic"]["fly"] == {"ap": 1 / n, "auc": 0.5, "top1": 0.2}
    assert any("fly" in note for note in kb_row.notes)
    assert [s.name for s in report.skipped] == [str(tmp_path / "missing")]
    data = report.to_dict()
    assert json.loads(json.dumps(data)) == data
    assert set(data["leave_verbs_out"]["bundles"]["runtime-kb"]["forms"]) == set(ENERGY_FORMS)
    again = evaluate_kbs([runtime_kbs.kb, tmp_path / "missing"], [str(path)], episodes_per_verb=40, folds=2)
    assert again.to_dict() == data and again.to_markdown() == report.to_markdown()


def test_leave_verbs_out_by_hand() -> None:
    units = [("s", f"v{i}") for i in range(4)]
    a = Scored("kb (A)", "kb", "A", {"s": {f"v{i}": {"ap": 0.8} for i in range(4)}})
    b = Scored("kb (B)", "kb", "B", {"s": {f"v{i}": {"ap": 0.6 if i else 1.0} for i in range(4)}})
    out = leave_verbs_out([a, b], units, ["A", "B"], folds=2, seed=0)["bundles"]["kb"]
    assert [f["verbs"] for f in out["folds"]] == [2, 2]
    for fold in out["folds"]:
        held_b = fold["held_out_ap"]["B"]
        # B wins a fold's training half only if v0 (AP 1.0) is in it together with... never:
        # B's training mean is (1.0 + 0.6) / 2 = 0.8 (a tie, A first) or 0.6 -> A is chosen
        assert fold["chosen"] == "A" and fold["held_out_ap"]["A"] == pytest.approx(0.8)
        assert held_b in (pytest.approx(0.8), pytest.approx(0.6))
    assert out["chosen_held_out_mean_ap"] == pytest.approx(0.8)
    assert out["held_out_mean_ap"]["B"] == pytest.approx(0.7)


def test_cli(tmp_path: Path, runtime_kbs: RuntimeKBs) -> None:
    path = write_labels(tmp_path, runtime_kbs.objects)
    out_json, out_md = tmp_path / "kb.json", tmp_path / "kb.md"
    result = CliRunner().invoke(app, ["eval", "kb", "--kb", str(runtime_kbs.kb), "--kb", str(runtime_kbs.direct),
                                      "--labels", str(path), "--energy-form", "sum-tanh",
                                      "--energy-form", "specificity", "--episodes", "20",
                                      "--json", str(out_json), "--markdown", str(out_md)])  # fmt: skip
    assert result.exit_code == 0, result.output
    md = out_md.read_text()
    assert "| chance |" in md and "| label oracle |" in md and "runtime-direct (specificity)" in md
    assert "Leave-verbs-out, `runtime-kb`" in md
    assert json.loads(out_json.read_text())["config"]["forms"] == ["sum-tanh", "specificity"]
    bad = CliRunner().invoke(app, ["eval", "kb", "--kb", str(runtime_kbs.kb), "--labels", str(path),
                                   "--energy-form", "veto"])  # fmt: skip
    assert bad.exit_code == 2 and "specificity-veto" in bad.output
    bad = CliRunner().invoke(app, ["eval", "kb", "--kb", str(runtime_kbs.kb), "--labels", "nope.txt"])
    assert bad.exit_code == 2 and "zhu, sim-dev" in bad.output


@pytest.mark.parametrize("command", [
    ["eval", "kb"],
    ["eval", "sim", "--labels", str(SIM_DEV_LABELS.resolve()), "--max-pairs", "1"],  # labels are read first
    ["eval", "static", "--max-pairs", "1"],
])
def test_a_named_bundle_that_does_not_load_is_an_error_not_a_skip(tmp_path: Path, command: list[str]) -> None:
    """``--kb`` the user named, missing or tampered: exit 2 before any work, no results file
    (a default bundle that is missing is skipped with the reason instead)."""
    missing = tmp_path / "nope"
    out = tmp_path / "out.json"
    result = CliRunner().invoke(app, [*command, "--kb", str(missing), "--json", str(out)])
    assert result.exit_code == 2, result.output
    assert f"--kb {missing}" in result.output.replace("\n", "") and "not a bundle folder" in result.output
    assert not out.exists()


def test_folds_are_at_most_the_labelled_verbs(tmp_path: Path, runtime_kbs: RuntimeKBs) -> None:
    """More --folds than verbs: one verb per fold (no empty fold reported as NaN)."""
    path = write_labels(tmp_path, runtime_kbs.objects)
    out_json = tmp_path / "kb.json"
    result = CliRunner().invoke(app, ["eval", "kb", "--kb", str(runtime_kbs.kb), "--labels", str(path),
                                      "--energy-form", "sum-tanh", "--episodes", "5", "--folds", "50",
                                      "--json", str(out_json)])
    assert result.exit_code == 0, result.output
    data = json.loads(out_json.read_text())
    assert data["config"]["folds"] == 3 and "nan" not in result.output.lower()  # cut, pour, fly


def test_the_committed_sim_label_sets_load_and_do_not_share_a_verb() -> None:
    """sim-val covers sim verbs that sim-dev lacks (a check on verbs no default was chosen on)."""
    from craft_e.runtime.evaluation.kb_eval import resolve_labels

    dev, val = resolve_labels("sim-dev"), resolve_labels("sim-val")
    assert val.name == "sim-val" and len(val.positives) == 23
    assert not set(dev.positives) & set(val.positives)


@pytest.mark.parametrize(("labels", "message"), [
    ({"_objects": ["cup", "knife"], " ": ["cup"]}, "the verb name ' ' is blank"),
    ({"_objects": ["cup", "knife"], "cut": []}, "'cut' lists no objects"),
    ({"_objects": ["cup", "knife"], "cut": ["knife"], "Cut ": ["cup"]}, "'cut' and 'Cut ' name the same verb 'cut'"),
    ({"_objects": "cup", "cut": ["cup"]}, '"_objects" must be a list of object names'),
])
def test_json_labels_refuse_what_they_would_misread(tmp_path: Path, labels: dict[str, object], message: str) -> None:
    """As ``craft eval imagenet``'s labels: a blank verb, a verb without objects (NaN AP left out
    of every mean) and two spellings of one verb (the second list replaced the first) are errors."""
    path = tmp_path / "labels.json"
    path.write_text(json.dumps(labels), encoding="utf-8")
    with pytest.raises(KBLabelsError) as caught:
        json_labels(path)
    assert str(caught.value).startswith(f"{path}: {message}")
    path.write_text('{"_objects": ["cup", "knife"], "cut": ["knife"], "cut": ["cup"]}', encoding="utf-8")
    with pytest.raises(KBLabelsError, match="key 'cut' appears twice"):
        json_labels(path)
