"""``craft eval compare``: paired episodes, Wilson intervals, McNemar's exact test, and refusals
of runs that share no scene (``runtime/evaluation/compare.py``)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from craft_e.files import read_json
from craft_e.runtime.cli.main import app
from craft_e.runtime.evaluation.compare import (
    CompareError,
    compare_methods,
    compare_runs,
    load_run,
    mcnemar_exact,
    wilson_interval,
)

runner = CliRunner()
ROOT = Path(__file__).resolve().parent.parent
SIM = "sim (CR3 testbed; the paper's real-world protocol)"


def _sim_run(path: Path, outcomes: dict[str, dict[str, str]], seed: int = 0) -> Path:
    """A results file shaped as ``craft eval sim --json`` writes it: episode id -> method -> failure class."""
    episodes = [{"id": eid, "scene_seed": 1000 * seed + n, "methods": {
        m: {"success": f == "success", "detect": f in ("success", "missed"), "failure": f} for m, f in per.items()}}
        for n, (eid, per) in enumerate(outcomes.items())]
    path.write_text(json.dumps({"benchmark": SIM, "config": {"seed": seed}, "episodes": episodes}))
    return path


def _invoke(*args: object) -> Any:
    return runner.invoke(app, ["eval", "compare", *[str(a) for a in args]], env={"COLUMNS": "300"})


def test_wilson_interval_and_mcnemar_match_their_closed_forms() -> None:
    # Wilson at 0 of n: upper bound z² / (n + z²), not the normal approximation's zero width
    z2 = 1.959963984540054 ** 2
    low, high = wilson_interval(0, 10)
    assert low == pytest.approx(0.0, abs=1e-12) and high == pytest.approx(z2 / (10 + z2), rel=1e-9)
    # 5 gained, 0 lost: each changed episode a coin flip, two-sided p = 2 / 2**5
    assert mcnemar_exact(5, 0) == pytest.approx(2 / 32)
    assert mcnemar_exact(3, 3) == pytest.approx(1.0)
    assert mcnemar_exact(0, 0) == 1.0


def test_two_runs_pair_episodes_and_list_what_changed(tmp_path: Path) -> None:
    ids = [f"cut/knife/{i}" for i in range(10)]
    before = {eid: {"CRAFT-E": "missed" if i < 6 else "success", "CRAFT": "wrong_object"} for i, eid in enumerate(ids)}
    after = {eid: {"CRAFT-E": "missed" if i == 5 else ("lift_failed" if i == 8 else "success"),
                   "CRAFT": "wrong_object"} for i, eid in enumerate(ids)}
    after["extra/one/0"] = {"CRAFT-E": "success", "CRAFT": "success"}
    comparison = compare_runs(load_run(_sim_run(tmp_path / "a.json", before)),
                              load_run(_sim_run(tmp_path / "b.json", after)))
    rows = {r.label: r for r in comparison.rows}
    craft_e = rows["CRAFT-E"]
    assert (craft_e.episodes, craft_e.base_hits, craft_e.new_hits) == (10, 4, 8)
    assert [(c.id, c.before, c.after) for c in craft_e.gained] == [(ids[i], "missed", "success") for i in range(5)]
    assert [(c.id, c.before, c.after) for c in craft_e.lost] == [(ids[8], "success", "lift_failed")]
    assert craft_e.p_value == pytest.approx(14 / 64)  # 5 gains, 1 loss: P(X <= 1 or X >= 5), X ~ Bin(6, 1/2)
    assert rows["CRAFT"].p_value == 1.0 and not rows["CRAFT"].lost and not rows["CRAFT"].gained
    assert comparison.unpaired == (0, 1)
    table = comparison.to_markdown()
    assert "| CRAFT-E | 10 | 40.0 (16.8–68.7) | 80.0 (49.0–94.3) | +40.0 | 5 | 1 | 0.22 |" in table
    assert "`cut/knife/8` (success → lift_failed)" in table and "1 only in the new one" in table


def test_methods_of_one_run_reproduce_the_committed_grasp_rates() -> None:
    """On the committed sim-val run: each side's rate is the file's own Grasp Rate, and the
    gained and lost episodes account for the whole difference."""
    path = ROOT / "docs" / "results" / "sim_val.json"
    data = read_json(path, "results file")
    comparison = compare_methods(load_run(path), "direct-LLM")
    assert [r.new_method for r in comparison.rows] == ["CRAFT", "CRAFT-E", "alignment-only"]
    for row in comparison.rows:
        assert row.episodes == len(data["episodes"])
        assert row.base_hits / row.episodes == pytest.approx(data["methods"]["direct-LLM"]["grasp_rate"], abs=1e-6)
        assert row.new_hits / row.episodes == pytest.approx(data["methods"][row.new_method]["grasp_rate"], abs=1e-6)
        assert row.new_hits - row.base_hits == len(row.gained) - len(row.lost)
    assert all(c.before == "success" for r in comparison.rows for c in r.lost)


def test_the_cli_writes_json_and_markdown_and_fails_on_a_significant_loss(tmp_path: Path) -> None:
    ids = [f"pour/cup/{i}" for i in range(8)]
    before = _sim_run(tmp_path / "before.json", {eid: {"CRAFT-E": "success"} for eid in ids})
    after = _sim_run(tmp_path / "after.json", {eid: {"CRAFT-E": "missed"} for eid in ids})
    out_json, out_md = tmp_path / "cmp.json", tmp_path / "cmp.md"
    ok = _invoke(before, after, "--json", out_json, "--markdown", out_md)
    assert ok.exit_code == 0, ok.output
    written = read_json(out_json, "comparison")
    assert written["rows"][0]["lost"][0] == {"id": "pour/cup/0", "before": "success", "after": "missed"}
    assert written["rows"][0]["mcnemar_p"] == pytest.approx(2 / 256, abs=1e-6)
    assert out_md.read_text().startswith("### Paired comparison")
    failed = _invoke(before, after, "--fail-on-loss")
    assert failed.exit_code == 1 and "lost more episodes than it gained" in failed.output
    assert _invoke(after, before, "--fail-on-loss").exit_code == 0  # a gain never fails
    detect = _invoke(before, after, "--metric", "detect", "--fail-on-loss")  # missed still detected
    assert detect.exit_code == 0 and "| CRAFT-E | 8 | 100.0" in detect.output


def test_static_runs_compare_the_chosen_view(tmp_path: Path) -> None:
    def static(name: str, gt_ok: bool) -> Path:
        views = {"gt/gt": {"methods": {"CRAFT-E": {"success": gt_ok, "detect": gt_ok}}},
                 "grconvnet/predicted": {"methods": {"CRAFT-E": {"success": True, "detect": True}}}}
        episodes = [{"id": f"cut/knife/{i}", "scene_seed": i, "levels": {"clean": views}} for i in range(3)]
        path = tmp_path / name
        path.write_text(json.dumps({"benchmark": "static (rendered)", "config": {}, "episodes": episodes}))
        return path

    a, b = static("a.json", False), static("b.json", True)
    assert compare_runs(load_run(a), load_run(b)).rows[0].gained == ()  # the full pipeline, unchanged
    row = compare_runs(load_run(a, "clean:gt/gt"), load_run(b, "clean:gt/gt")).rows[0]
    assert [c.after for c in row.gained] == ["success"] * 3
    with pytest.raises(CompareError, match="write LEVEL:GRASP/ROIS"):
        load_run(a, "clean")
    with pytest.raises(CompareError, match="no grasp/ROI setting 'gt/predicted'"):
        load_run(a, "clean:gt/predicted")


def test_runs_that_share_no_scene_or_method_are_refused(tmp_path: Path) -> None:
    per = {"cut/knife/0": {"CRAFT-E": "success"}}
    seed0, seed1 = _sim_run(tmp_path / "s0.json", per, 0), _sim_run(tmp_path / "s1.json", per, 1)
    with pytest.raises(CompareError, match=r"scene seed 0\).*scene seed 1000\).*same --seed"):
        compare_runs(load_run(seed0), load_run(seed1))
    with pytest.raises(CompareError, match="no method 'CRAFTE'; it has CRAFT-E"):
        compare_methods(load_run(seed0), "CRAFTE")
    other = _sim_run(tmp_path / "other.json", {"eat/apple/0": {"CRAFT-E": "success"}})
    with pytest.raises(CompareError, match="share no episode id"):
        compare_runs(load_run(seed0), load_run(other))
    twice = tmp_path / "twice.json"
    data = json.loads(seed0.read_text())
    data["episodes"] *= 2
    twice.write_text(json.dumps(data))
    with pytest.raises(CompareError, match=re.escape("twice.json, episode cut/knife/0: the id appears twice")):
        load_run(twice)
    data = json.loads(seed0.read_text())
    data["episodes"][0]["methods"]["CRAFT-E"]["success"] = "yes"
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(data))
    with pytest.raises(CompareError, match=re.escape("edited.json, episode cut/knife/0, method CRAFT-E: \"success\" is 'yes'")):
        load_run(edited)
    not_results = tmp_path / "labels.json"
    not_results.write_text(json.dumps({"cut": ["knife"]}))
    with pytest.raises(CompareError, match="not a results file of craft eval sim, pickability or static"):
        load_run(not_results)


@pytest.mark.parametrize(("args", "message"), [
    ((), "give a second results file to compare with, or --against METHOD"),
    (("--metric", "speed"), "--metric 'speed': choose one of success, detect"),
    (("SECOND", "--against", "CRAFT-E"), "--against compares two methods of one run"),
    (("--against", "CRAFT-E", "--method", "CRAFT-E"), "a method against itself changes nothing"),
    (("--against", "CRAFT-E", "--json", "SECOND"), "is a results file being compared"),
])
def test_cli_usage_errors_exit_2_with_the_fix(tmp_path: Path, args: tuple[str, ...], message: str) -> None:
    run = _sim_run(tmp_path / "run.json", {"cut/knife/0": {"CRAFT-E": "success", "CRAFT": "missed"}})
    result = _invoke(run, *[str(run) if a == "SECOND" else a for a in args])
    assert result.exit_code == 2 and message in " ".join(result.output.split()), result.output
    assert read_json(run, "results file")["episodes"][0]["id"] == "cut/knife/0"  # the input is untouched
