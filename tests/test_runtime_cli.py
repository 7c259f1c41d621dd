"""``craft ground`` and ``craft eval imagenet`` through the CLI (in-process, CliRunner)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import typer
from runtime_fixtures import DEV_LABELS, RUNTIME_KB, RuntimeKBs, runtime_kbs_fixture, shared_image  # noqa: F401
from typer.testing import CliRunner

from craft_e.runtime.cli.ground import parse_box
from craft_e.runtime.cli.main import app, eval_app, sim_app

runner = CliRunner()


def test_ground_two_boxes_prints_ranking_and_writes_png(runtime_kbs: RuntimeKBs, tmp_path: Path) -> None:
    image = shared_image("teapot")
    png, out = tmp_path / "g.png", tmp_path / "g.json"
    result = runner.invoke(app, ["ground", "--kb", str(runtime_kbs.kb), "--verb", "pour", "--image", str(image),
                                 "--box", "0,0,200,200", "--box", "100,50,250,250", "--plot", str(png),
                                 "--json", str(out), "--threads", "1"])
    assert result.exit_code == 0, result.output
    text = result.output
    assert "E_total" in text and "chosen: ROI" in text and "grasp scores default to 1.0" in text
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    data = json.loads(out.read_text())
    assert data["verb"] == "pour" and len(data["ranked"]) == 2
    assert data["ranked"][0]["total"] <= data["ranked"][1]["total"]
    assert all(r["e_grasp"] == 0.0 for r in data["ranked"])


def test_ground_notes_a_box_that_reaches_past_the_image(runtime_kbs: RuntimeKBs, tmp_path: Path) -> None:
    """As ``/ground_image`` does: the crop of such a box holds only the part inside the image."""
    from PIL import Image

    image = shared_image("teapot")
    with Image.open(image) as img:
        width, height = img.size
    out = tmp_path / "g.json"
    result = runner.invoke(app, ["ground", "--kb", str(runtime_kbs.kb), "--verb", "pour", "--image", str(image),
                                 "--box", "0,0,100,100", "--box", f"{width - 50},10,100,100", "--json", str(out),
                                 "--threads", "1"])
    assert result.exit_code == 0, result.output
    note = f"box 1 [{width - 50:.1f}, 10.0, 100.0, 100.0] reaches past the {width}x{height} image"
    assert note in " ".join(result.output.split())
    notes = json.loads(out.read_text())["notes"]
    assert sum("reaches past" in n for n in notes) == 1


def test_ground_with_rois_file_and_grasp_scores(runtime_kbs: RuntimeKBs, tmp_path: Path) -> None:
    rois = tmp_path / "rois.json"
    rois.write_text(json.dumps({"rois": [
        {"box": [0, 0, 150, 150], "grasp_scores": [0.2, 0.9], "label": "left"},
        {"box": [150, 0, 150, 150], "grasp_scores": [], "label": "right"},
    ]}))
    result = runner.invoke(app, ["ground", "--kb", str(runtime_kbs.kb), "--verb", "cut", "--image",
                                 str(shared_image("hatchet")), "--rois", str(rois), "--threads", "1"])
    assert result.exit_code == 0, result.output
    assert "excluded: no grasp candidates" in result.output and "default to 1.0" not in result.output


@pytest.mark.parametrize(("args", "message"), [
    (["--verb", "cut"], "either as --box"),
    (["--verb", "cut", "--box", "1,2,3"], "expected x,y,w,h"),
    (["--verb", "cutt", "--box", "0,0,50,50"], "close matches: cut"),
    (["--verb", "  ", "--box", "0,0,50,50", "--open-vocab"], "--verb is blank"),
    (["--verb", "cut", "--box", "0,0,50,50", "--alpha", "nan"], "--alpha nan"),
    (["--verb", "cut", "--box", "0,0,50,50", "--gamma", "-1"], "--gamma -1.0"),
    (["--verb", "cut", "--box", "0,0,50,50", "--grasp", "foo"], "--grasp 'foo': use auto or one of"),
    (["--verb", "cut", "--box", "0,0,50,50", "--aff-norm", "max"], "--aff-norm 'max': use one of none, verb-best"),
    (["--verb", "cut", "--box", "0,0,50,50", "--grasp", "ggcnn"], "pass --depth FILE.npy too"),
])
def test_ground_usage_errors(runtime_kbs: RuntimeKBs, args: list[str], message: str) -> None:
    result = runner.invoke(app, ["ground", "--kb", str(runtime_kbs.kb), "--image", str(shared_image("cup")), *args])
    assert result.exit_code == 2
    assert message in " ".join(result.output.split())



@pytest.mark.parametrize(("roi", "message"), [
    ({"box": [0, 0, 50, 50], "grasp_scores": [float("nan")]}, "finite numbers"),
    ({"box": [0, 0, 50, 50], "grasp_scores": [5.0]}, "must lie in [0, 1]"),
    ({"box": [0, 0, float("nan"), 50]}, "finite numbers"),
    ({"box": [True, 0, 50, 50]}, "finite numbers"),
    ({"box": [0, 0, 0, 50]}, "width and height must be > 0"),
])
def test_ground_rois_file_rejects_what_the_server_rejects(
    runtime_kbs: RuntimeKBs, tmp_path: Path, roi: dict[str, object], message: str
) -> None:
    rois = tmp_path / "rois.json"
    rois.write_text(json.dumps([roi]))  # json writes NaN, as a hand-edited file might hold it
    result = runner.invoke(app, ["ground", "--kb", str(runtime_kbs.kb), "--verb", "cut", "--image",
                                 str(shared_image("cup")), "--rois", str(rois)])
    assert result.exit_code == 2, result.output
    assert f"{rois}: ROI 0" in "".join(result.output.split("\n")) and message in " ".join(result.output.split())

def test_ground_refuses_bundle_of_other_encoder(runtime_kbs: RuntimeKBs) -> None:
    result = runner.invoke(app, ["ground", "--kb", str(runtime_kbs.other_encoder), "--verb", "cut",
                                 "--image", str(shared_image("cup")), "--box", "0,0,50,50"])
    assert result.exit_code == 2 and "manifest.json" in result.output


def test_eval_imagenet_cli(runtime_kbs: RuntimeKBs, tmp_path: Path) -> None:
    """With --kb-dir empty, the baselines are reported as skipped, not silently dropped."""
    out, md = tmp_path / "r.json", tmp_path / "r.md"
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps({"cut": ["cleaver", "hatchet"], "eat": ["banana", "orange"]}))
    (tmp_path / "none").mkdir()  # an empty folder of bundles (a missing one is an error)
    result = runner.invoke(app, ["eval", "imagenet", "--labels", str(labels), "--kb", str(runtime_kbs.kb),
                                 "--kb-dir", str(tmp_path / "none"), "--episodes", "5", "--json", str(out),
                                 "--markdown", str(md), "--no-cache", "--threads", "1",
                                 "--classes", str(RUNTIME_KB / "objects.txt")])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    # every table carries a chance row and a label-oracle row beside the methods (issue 9 item 7)
    assert {"CRAFT-E", "alignment-only", "affordance-only", "chance", "label oracle"} == set(
        data["methods"]
    )
    assert {s["method"] for s in data["skipped_methods"]} == {"CRAFT", "direct-LLM"}
    assert "| CRAFT | skipped" in md.read_text()


def _small_imagenet_run(runtime_kbs: RuntimeKBs, tmp_path: Path, flags: list[str]) -> dict[str, Any]:
    """``craft eval imagenet`` on one verb of the test bundle's objects, with ``flags``: its report."""
    out = tmp_path / "r.json"
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps({"cut": ["cleaver", "hatchet"]}))
    (tmp_path / "none").mkdir()
    result = runner.invoke(app, ["eval", "imagenet", "--labels", str(labels), "--kb", str(runtime_kbs.kb),
                                 "--kb-dir", str(tmp_path / "none"), "--episodes", "3", "--json", str(out),
                                 "--no-cache", "--threads", "1", "--classes", str(RUNTIME_KB / "objects.txt"),
                                 *flags])
    assert result.exit_code == 0, result.output
    report: dict[str, Any] = json.loads(out.read_text())
    return report


@pytest.mark.parametrize(("flags", "weights"), [
    ([], {"CRAFT-E": (8.0, 1.0), "alignment-only": (0.0, 1.0), "affordance-only": (8.0, 0.0)}),
    (["--beta", "1", "--gamma", "1"], {"CRAFT-E": (1.0, 1.0), "alignment-only": (0.0, 1.0), "affordance-only": (1.0, 0.0)}),
])
def test_eval_weights_reach_every_method(runtime_kbs: RuntimeKBs, tmp_path: Path, flags: list[str],
                                         weights: dict[str, tuple[float, float]]) -> None:
    """``--beta/--gamma`` (the paper's 1 / 1) replace the default weights of every method; each
    single-term ablation keeps its one term off."""
    report = _small_imagenet_run(runtime_kbs, tmp_path, flags)
    settings = {name: m["settings"] for name, m in report["methods"].items() if name in weights}
    assert {name: (s["beta"], s["gamma"]) for name, s in settings.items()} == weights


@pytest.mark.parametrize(("flags", "suffix"), [([], "+senses0.5+t2"), (["--conse-temperature", "1"], "+senses0.5")])
def test_conse_temperature_reaches_the_encoder(runtime_kbs: RuntimeKBs, tmp_path: Path, flags: list[str],
                                               suffix: str) -> None:
    """``--conse-temperature`` (default 2; 1: ConSE's own weights, every run from before) builds
    the evaluation's encoder, whose id in the report says which."""
    report = _small_imagenet_run(runtime_kbs, tmp_path, flags)
    assert report["config"]["image_encoder"].endswith("+minilm-l6-v2@53aa51172d14" + suffix)


@pytest.mark.parametrize("value", ["0", "-1", "inf", "nan"])
@pytest.mark.parametrize("command", [["eval", "sim"], ["eval", "static"], ["eval", "imagenet"], ["sim", "demo"]])
def test_a_bad_conse_temperature_is_a_usage_error(command: list[str], value: str) -> None:
    result = runner.invoke(app, [*command, "--conse-temperature", value])
    assert result.exit_code == 2 and "Invalid value for '--conse-temperature'" in result.output


@pytest.mark.parametrize("weight", [["--beta", "-1"], ["--beta", "inf"], ["--gamma", "inf"]])
@pytest.mark.parametrize("command", [["eval", "sim"], ["eval", "static"], ["eval", "imagenet"], ["sim", "demo"]])
def test_a_negative_or_infinite_weight_is_a_usage_error(command: list[str], weight: list[str]) -> None:
    result = runner.invoke(app, [*command, *weight])
    assert result.exit_code == 2 and f"Invalid value for '{weight[0]}'" in result.output


def _commands(group: typer.Typer) -> set[str]:
    names = {c.name or (c.callback.__name__ if c.callback else "") for c in group.registered_commands}
    return names | {f"{g.name}/{n}" for g in group.registered_groups if g.typer_instance
                    for n in _commands(g.typer_instance)}


def test_every_command_is_wired_and_answers_help() -> None:
    """The whole ``craft`` tree, spelled out: a command module that is not wired into ``main``
    (or a group that lost a command) fails here, and each command's options parse."""
    assert parse_box(" 1, 2,3,4 ") == (1.0, 2.0, 3.0, 4.0)
    expected = {"ground", "perceive", "install", "rollback", "installed", "serve",
                "eval/imagenet", "eval/sim", "eval/static", "eval/zhu", "eval/kb", "eval/open-world", "eval/recognition",
                "eval/pickability", "eval/compare",
                "eval/robustness/imagenet", "sim/demo", "sim/collision-meshes"}
    assert _commands(app) == expected
    for path in expected:
        r = runner.invoke(app, [*path.split("/"), "--help"])
        assert r.exit_code == 0, (path, r.output)
    assert _commands(eval_app) >= {"imagenet", "robustness/imagenet"} and _commands(sim_app) == {"demo", "collision-meshes"}
    _ = DEV_LABELS


@pytest.mark.parametrize(("args", "message"), [
    (["eval", "kb", "--json", "{dir}"], "is a folder; give a file path inside it, e.g. {dir}/out.json"),
    (["eval", "sim", "--labels", "x.csv", "--markdown", "{dir}"], "give a file path inside it, e.g. {dir}/out.md"),
    (["ground", "--kb", "x", "--verb", "cut", "--image", "y", "--box", "0,0,5,5", "--plot", "{dir}"],
     "give a file path inside it, e.g. {dir}/out.png"),
    (["eval", "kb", "--markdown", "{file}/t.md"], "is a file, so"),
    (["eval", "sim", "--labels", "x.csv", "--json", "{dir}"], "is a folder"),
    (["eval", "zhu", "--json", "{file}/z.json"], "is a file, so"),
    (["ground", "--kb", "x", "--verb", "cut", "--image", "y", "--box", "0,0,5,5", "--plot", "{dir}/f.xyz"],
     "unknown figure format '.xyz'"),
    (["sim", "demo", "--verb", "cut", "--out", "{file}"], "is a file; give a folder"),
    (["sim", "demo", "--verb", "cut", "--seed", "-5"], "--seed"),
    (["eval", "kb", "--seed", "-1"], "--seed"),
])
def test_bad_outputs_and_seeds_fail_before_any_work(tmp_path: Path, args: list[str], message: str) -> None:
    """Checked as the options are parsed: nothing runs, nothing is written (exit 2)."""
    (tmp_path / "a-file").write_text("mine\n")
    filled = [a.format(dir=tmp_path, file=tmp_path / "a-file") for a in args]
    result = runner.invoke(app, filled, env={"COLUMNS": "300"})
    assert result.exit_code == 2, result.output
    assert message.format(dir=tmp_path) in " ".join(result.output.replace("│", " ").split())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]


@pytest.mark.parametrize("command", ["sim", "static"])
def test_bad_labels_fail_before_the_progress_bar(tmp_path: Path, command: str) -> None:
    """A labels error used to come after an empty 'episodes 0/?' bar and the models' loading."""
    labels = tmp_path / "labels.csv"
    labels.write_text("cut,nothing_here\n", encoding="utf-8")
    result = runner.invoke(app, ["eval", command, "--labels", str(labels)], env={"COLUMNS": "300"})
    assert result.exit_code == 2, result.output
    assert "'nothing_here' is neither a sim asset id nor a plain name" in result.output
    assert "episodes" not in result.output


@pytest.mark.parametrize("command", ["sim", "static"])
def test_unknown_classifier_is_refused_before_any_scene(tmp_path: Path, command: str) -> None:
    labels = tmp_path / "labels.csv"
    labels.write_text("cut,knife\n", encoding="utf-8")
    result = runner.invoke(app, ["eval", command, "--labels", str(labels), "--classifier", "efficientnet-lite9"],
                           env={"COLUMNS": "300"})
    assert result.exit_code == 2, result.output
    assert "--classifier 'efficientnet-lite9': choose one of efficientnet-lite0, efficientnet-lite1" in result.output
    assert "episodes" not in result.output and "scenes" not in result.output


def test_non_utf8_labels_name_the_file(tmp_path: Path) -> None:
    labels = tmp_path / "labels.csv"
    labels.write_bytes(b"cut,knife\n\xff\xfe,bad\n")
    result = runner.invoke(app, ["eval", "sim", "--labels", str(labels), "--max-pairs", "1"])
    assert result.exit_code == 2, result.output
    assert f"{labels}: not UTF-8 text" in "".join(result.output.split("\n"))


def test_ground_names_a_depth_file_of_the_wrong_shape(runtime_kbs: RuntimeKBs, tmp_path: Path) -> None:
    import numpy as np
    from PIL import Image

    image = shared_image("cup")
    w, h = Image.open(image).size
    depth = tmp_path / "depth.npy"
    np.save(depth, np.ones((h, w, 3), dtype=np.float32))
    result = runner.invoke(app, ["ground", "--kb", str(runtime_kbs.kb), "--verb", "cut", "--image", str(image),
                                 "--box", "0,0,50,50", "--depth", str(depth)])
    assert result.exit_code == 2, result.output
    assert "depth must be an H x W array" in " ".join(result.output.split())
