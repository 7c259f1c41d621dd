"""Bad input to ``craft ground``, ``craft eval imagenet``/``kb``/``sim``/``robustness``, ``craft sim
demo`` and ``craftc curate``/``diagnose``/``cache``: exit 2 with a message naming the option or file
and the problem, before any model or bundle loads, never a traceback, a NaN result or a run that
does nothing and exits 0."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import typer
from typer.testing import CliRunner

from craft_e.compiler.cli import app as craftc
from craft_e.files import read_json
from craft_e.runtime.cli.ground import parse_box
from craft_e.runtime.cli.main import app

runner = CliRunner()
KB_SMALL = Path(__file__).parent / "fixtures" / "kb_small"


def flat(text: str) -> str:
    """Output with rich's wrapping and box drawing undone, for substring checks."""
    return " ".join(text.replace("│", " ").split())


def run(args: list[str], cli: Any = app) -> Any:
    result = runner.invoke(cli, [str(a) for a in args], env={"COLUMNS": "300"})
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    return result


# --------------------------------------------------------------------------- craft ground --box


@pytest.mark.parametrize("text", ["inf,0,10,10", "nan,0,10,10", "nan,nan,nan,nan", "0,0,inf,inf", "1e400,0,5,5"])
def test_parse_box_refuses_non_finite_numbers(text: str) -> None:
    """``float`` reads nan and inf: a NaN box was ranked and written to --json, an infinite one
    overflowed the crop (OverflowError traceback)."""
    with pytest.raises(ValueError, match=r"--box .*must be finite numbers"):
        parse_box(text)


def test_ground_non_finite_box_is_a_usage_error_before_the_bundle(tmp_path: Path) -> None:
    out = tmp_path / "g.json"
    result = run(["ground", "--kb", tmp_path / "no-kb", "--verb", "cut", "--image", tmp_path / "no.png",
                  "--box", "nan,0,10,10", "--json", out])
    assert "--box 'nan,0,10,10': x,y,w,h must be finite numbers" in flat(result.output)
    assert not out.exists()


# --------------------------------------------------------------------------- read_json


def test_read_json_names_the_file_and_the_problem(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    binary = tmp_path / "bin.json"
    binary.write_bytes(b'{"cut": ["knife"]}\n\xff\xfe')
    with pytest.raises(ValueError, match=rf"^{binary}: labels file is not UTF-8 text \(byte 0xff at offset 19\)"):
        read_json(binary, "labels file")
    folder = tmp_path / "dir.json"
    folder.mkdir()
    with pytest.raises(ValueError, match=rf"^{folder}: is a folder; give the path of the labels file itself"):
        read_json(folder, "labels file")
    locked = tmp_path / "locked.json"
    locked.write_text("{}", encoding="utf-8")

    def denied(self: Path, *args: object, **kwargs: object) -> str:
        raise PermissionError(13, "Permission denied", str(self))

    with monkeypatch.context() as patch:  # chmod 000 does not stop root, so the error is simulated
        patch.setattr(Path, "read_text", denied)
        with pytest.raises(ValueError, match=rf"^{locked}: cannot read the labels file \(permission denied\)"):
            read_json(locked, "labels file")
    twice = tmp_path / "twice.json"
    twice.write_text('{"carry": ["hammer"], "carry": ["cleaver"]}', encoding="utf-8")
    assert read_json(twice, "labels file") == {"carry": ["cleaver"]}  # plain JSON: the last one wins
    with pytest.raises(ValueError, match="key 'carry' appears twice"):
        read_json(twice, "labels file", unique_keys=True)


@pytest.mark.parametrize("kind", ["binary", "folder"])
def test_unreadable_labels_and_rois_files_are_usage_errors(tmp_path: Path, kind: str) -> None:
    bad = tmp_path / "bad.json"
    if kind == "binary":
        bad.write_bytes(b"\xff\xfe{}")
        expected = f"{bad}: labels file is not UTF-8 text (byte 0xff at offset 0)"
    else:
        bad.mkdir()
        expected = f"{bad}: is a folder; give the path of the labels file itself"
    assert expected in flat(run(["eval", "imagenet", "--labels", bad, "--episodes", "1"]).output)
    assert expected in flat(run(["eval", "kb", "--labels", bad]).output)
    rois = run(["ground", "--kb", tmp_path / "no-kb", "--verb", "cut", "--image", tmp_path / "no.png",
                "--rois", bad])
    assert expected.replace("labels file", "ROIs file") in flat(rois.output)


# --------------------------------------------------------------------------- empty vocabularies


@pytest.mark.parametrize("text", ["", "\n\n  \n", "# only a comment\n"])
def test_an_empty_vocab_or_classes_file_fails_before_the_bundle(tmp_path: Path, text: str) -> None:
    """The KB named here does not exist: the message is about the file, so nothing loaded first."""
    names = tmp_path / "names.txt"
    names.write_text(text, encoding="utf-8")
    ground = run(["ground", "--kb", tmp_path / "no-kb", "--verb", "cut", "--image", tmp_path / "no.png",
                  "--box", "0,0,10,10", "--vocab", names])
    assert f"--vocab {names}: the vocabulary names nothing" in flat(ground.output)
    labels = tmp_path / "labels.json"
    labels.write_text('{"cut": ["cleaver"]}', encoding="utf-8")
    imagenet = run(["eval", "imagenet", "--labels", labels, "--kb", tmp_path / "no-kb", "--episodes", "1",
                    "--classes", names])
    assert f"--classes {names}: the classes file names nothing" in flat(imagenet.output)
    kb = run(["eval", "kb", "--labels", labels, "--objects", names])
    assert f"--objects {names}: the objects file names nothing" in flat(kb.output)


# --------------------------------------------------------------------------- imagenet labels


@pytest.mark.parametrize(("labels", "message"), [
    ('{" ": ["hammer"]}', "the verb name ' ' is blank"),
    ('{"cut": []}', "'cut' lists no objects"),
    ('{"carry": ["hammer"], "CARRY": ["cleaver"]}', "'carry' and 'CARRY' name the same verb 'carry'"),
    ('{"carry": ["hammer"], "carry": ["cleaver"]}', "key 'carry' appears twice"),
])
def test_eval_imagenet_refuses_labels_it_would_misread(tmp_path: Path, labels: str, message: str) -> None:
    path = tmp_path / "labels.json"
    path.write_text(labels, encoding="utf-8")
    result = run(["eval", "imagenet", "--labels", path, "--episodes", "1"])
    assert f"{path}: {message}" in flat(result.output)


def test_eval_imagenet_refuses_classes_no_episode_can_be_drawn_from(tmp_path: Path) -> None:
    """One class cannot fill a 5-candidate episode: an empty table and exit 0 before."""
    labels, classes = tmp_path / "labels.json", tmp_path / "classes.txt"
    labels.write_text('{"carry": ["hammer", "cleaver"]}', encoding="utf-8")
    classes.write_text("hammer\n", encoding="utf-8")
    out = tmp_path / "r.json"
    result = run(["eval", "imagenet", "--labels", labels, "--episodes", "1", "--classes", classes, "--json", out])
    text = flat(result.output)
    assert f"{labels}: no episode can be formed from the 1 --classes" in text
    assert "carry (single): only 0 non-affording classes (need 4)" in text and not out.exists()


def test_eval_imagenet_turns_a_grounder_error_into_exit_2(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A bundle that loads but cannot ground (open_world.json = {"objects": 3}) raised a
    ValueError from the Grounder, shown inside a traceback."""
    import craft_e.runtime.evaluation.imagenet as imagenet

    def broken(*args: object, **kwargs: object) -> None:
        raise ValueError("kb/open_world.json: objects: TypeError(...); rebuild the bundle")

    monkeypatch.setattr(imagenet, "evaluate_imagenet", broken)
    labels = tmp_path / "labels.json"
    labels.write_text('{"cut": ["cleaver"]}', encoding="utf-8")
    result = run(["eval", "imagenet", "--labels", labels, "--episodes", "1"])
    assert "error: kb/open_world.json: objects: TypeError(...); rebuild the bundle" in flat(result.output)


# --------------------------------------------------------------------------- sim demo


def test_sim_demo_replays_any_layout_with_one_scene_build() -> None:
    """``--episode cut/knife/N`` used to build layouts 0..N in turn (~0.8 s each: N = 99999999
    ran for years); each layout is drawn from (seed, verb, object, layout) alone, so only layout
    N is built, and it is the scene the full run builds."""
    from craft_e.paths import SIM_DEV_LABELS
    from craft_e.runtime.evaluation.sim_eval import SimLabels, load_sim_labels, make_episode_specs

    labels = load_sim_labels(SIM_DEV_LABELS)
    pair = next(p for p in labels.pairs if p.verb == "cut" and p.object == "knife")
    one = SimLabels(labels.path, (pair,), labels.affording)
    full = make_episode_specs(one, layouts=3, min_gap=None)
    assert make_episode_specs(one, only_layout=2, min_gap=None) == [full[2]]
    far = make_episode_specs(one, only_layout=99999999, min_gap=None)
    assert [s.id for s in far] == ["cut/knife/99999999"] and far[0].scene != full[0].scene


@pytest.mark.parametrize(("name", "text"), [("labels.json", "cut,knife\n"), ("labels.csv", '{"cut": ["knife", "sci'),
                                            ("labels.txt", '\n  ["cut"]')])
@pytest.mark.parametrize("command", [["sim", "demo", "--verb", "cut"], ["eval", "sim"]])
def test_sim_labels_given_as_json_say_the_format_is_csv(tmp_path: Path, name: str, text: str,
                                                        command: list[str]) -> None:
    labels = tmp_path / name
    labels.write_text(text, encoding="utf-8")
    result = run([*command, "--labels", labels])
    assert f"{labels}: sim labels are a CSV, not JSON" in flat(result.output)
    assert "a header line `verb,object`" in flat(result.output)


# --------------------------------------------------------------------------- craftc curate record


def curate(tmp_path: Path, answers: Path, prompt: str = "verb_properties") -> Any:
    return run(["curate", "record", "--prompt", prompt, "--answers", answers, "--verbs", KB_SMALL / "verbs.txt",
                "--objects", KB_SMALL / "objects.txt", "--cache", tmp_path / "cache", "--prompts", "v1"], craftc)


def test_curate_record_names_a_folder_or_an_empty_answers_file(tmp_path: Path) -> None:
    folder = tmp_path / "dir.jsonl"
    folder.mkdir()
    assert f"{folder}: is a folder; give the path of the answers file itself" in flat(curate(tmp_path, folder).output)
    for text in ("", "\n  \n// a comment only\n"):
        empty = tmp_path / "empty.jsonl"
        empty.write_text(text, encoding="utf-8")
        result = curate(tmp_path, empty)
        assert f"{empty}: no answers" in flat(result.output) and "stored 0 records" not in result.output
    assert not (tmp_path / "cache").exists()  # refused before the cache (or its lock) is made


def test_curate_record_lists_the_prompts_for_an_unknown_one(tmp_path: Path) -> None:
    result = curate(tmp_path, KB_SMALL / "verb_properties.jsonl", prompt="bogus")
    assert "unknown prompt 'bogus'; choose one of verb_properties, object_properties" in flat(result.output)
    assert "object_lookalike" in result.output and not (tmp_path / "cache").exists()


# --------------------------------------------------------------------------- eval sim / static options


@pytest.mark.parametrize("command", [["eval", "sim", "--labels", str(Path(__file__).resolve().parents[1] / "artifacts/labels/sim_dev_labels.csv")],
                                     ["eval", "static"]])
@pytest.mark.parametrize("value", ["", " ", "CRAFT-E,,", ",CRAFT-E"])
def test_an_empty_method_name_is_refused_before_any_episode(command: list[str], value: str) -> None:
    """``--methods ''`` ran the default methods and ``CRAFT-E,,`` dropped the blank: both started
    a full run as if the option said something."""
    result = run([*command, "--methods", value])
    assert result.exit_code == 2, result.output
    assert "an empty name (a blank value or a doubled comma)" in flat(result.output)


@pytest.mark.parametrize("spec", ["grasp=nan", "box=nan", "grasp=inf", "grasp=-1", "box=1"])
def test_static_noise_levels_must_be_finite_and_in_range(spec: str) -> None:
    result = run(["eval", "static", "--noise", spec])
    assert result.exit_code == 2, result.output
    assert "grasp sigma must be finite and >= 0, box fraction in [0, 1)" in flat(result.output)


def test_static_unknown_grasp_backend_fails_before_the_scenes() -> None:
    result = run(["eval", "static", "--grasp", "grconvnet,bogus"])
    assert result.exit_code == 2, result.output
    assert "--grasp: unknown grasp backend(s) bogus; choose from grconvnet" in flat(result.output)
    assert "episodes" not in result.output  # no progress bar: nothing was drawn or rendered


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc, where no file can be created")
@pytest.mark.parametrize("args", [["eval", "zhu", "--markdown", "/proc/x.md"],
                                  ["eval", "open-world", "--json", "/proc/nope/x.json"]])
def test_an_output_that_cannot_be_written_is_named_not_a_traceback(args: list[str]) -> None:
    """The up-front check catches a parent that is a file; a mount that refuses writes (here
    /proc), a race or a full disk is found only when writing, which raised a traceback."""
    result = run(args)
    assert result.exit_code == 2, result.output
    assert f"{args[-1]}: cannot write it" in flat(result.output)


def test_emit_names_an_output_it_cannot_write(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from craft_e.runtime.cli.common import emit
    from craft_e.runtime.evaluation import common

    def refused(path: Path, data: object) -> None:
        raise OSError(30, "Read-only file system", str(path))

    monkeypatch.setattr(common, "write_json", refused)
    with pytest.raises(typer.Exit) as stopped:
        emit("| t |\n", {}, tmp_path / "r.json", None, lambda _: None)
    assert stopped.value.exit_code == 2


# --------------------------------------------------------------------------- craftc diagnose / review / cache


def test_diagnose_refuses_an_unknown_energy_form_beside_all(tmp_path: Path) -> None:
    """``--energy-form all --energy-form bogus`` diagnosed every form and ignored ``bogus``
    (exit 0); a lone unknown form was named only after the bundle loaded."""
    shipped = Path(__file__).resolve().parents[1] / "artifacts" / "kb" / "craft-e-default"
    for bundle in (shipped, tmp_path / "no-kb"):  # the missing bundle: refused before loading it
        result = run(["diagnose", bundle, "--energy-form", "all", "--energy-form", "bogus", "--format", "json"],
                     craftc)
        assert ("--energy-form 'bogus': unknown E_aff form; use one of sum-tanh, normalized-product, "
                "specificity, required-veto, specificity-veto, or all (every form)") in flat(result.output)
        assert "content_sha256" not in result.stdout
    two = run(["diagnose", tmp_path / "no-kb", "--energy-form", "veto", "--energy-form", "sum-tanh",
               "--energy-form", "x"], craftc)
    assert "--energy-form 'veto', 'x': unknown E_aff forms" in flat(two.output)


def test_review_says_when_the_sample_is_capped(kb_a: Any) -> None:
    """``--sample 1000000`` printed every path without a word: a reader took it for a sample."""
    from craft_e.runtime.kb.bundle import load_bundle

    paths = len(load_bundle(kb_a.bundle, check_encoder=False).paths())
    result = runner.invoke(craftc, ["review", str(kb_a.bundle), "--sample", "1000000"], env={"COLUMNS": "300"})
    assert result.exit_code == 0, result.output
    assert len(result.stdout.splitlines()) == paths
    assert result.stderr.strip() == (f"--sample 1000000: the bundle has {paths} verb -> property -> object paths; "
                                     f"printing all {paths}")
    within = runner.invoke(craftc, ["review", str(kb_a.bundle), "--sample", str(paths)])
    assert within.exit_code == 0 and within.stderr == "", within.output
    # a default the user did not type (20 on a bundle of fewer paths; here a default of 1000)
    default = runner.invoke(craftc, ["review", str(kb_a.bundle)], default_map={"review": {"sample": 1000}})
    assert default.exit_code == 0 and default.stderr == "" and len(default.stdout.splitlines()) == paths


@pytest.mark.parametrize(("option", "message"), [
    (["--mode", "bogus"], "--mode 'bogus': unknown mode; choose from llm, direct, llm+direct"),
    (["--mode", "llm", "--mode", "direkt"], "--mode 'direkt': unknown mode"),
    (["--prompts", "v9"], "unknown prompt version 'v9'; choose one of v1, v2"),
])
@pytest.mark.parametrize("yes", [[], ["--yes"]])
def test_cache_clean_refuses_unknown_modes_without_verbs(tmp_path: Path, option: list[str], message: str,
                                                         yes: list[str]) -> None:
    """The modes and prompt version of the build to keep were read only with ``--verbs``: without
    it a typo passed (a dry run or a clean, exit 0)."""
    cache = tmp_path / "cache"
    cache.mkdir()
    result = run(["cache", "clean", "--cache", cache, *option, *yes], craftc)
    assert message in flat(result.output)
    assert list(cache.iterdir()) == []  # refused before the clean's lock is taken


@pytest.mark.parametrize("command", [["cache", "verify"], ["cache", "index"], ["cache", "stats"], ["cache", "clean"],
                                     ["curate", "pending"], ["build", "--verbs", str(KB_SMALL / "verbs.txt")]])
def test_a_file_given_as_the_cache_is_called_a_file(tmp_path: Path, command: list[str]) -> None:
    """The cache commands said "no such record cache folder" of a file that exists; ``curate
    pending`` raised NotADirectoryError (a traceback)."""
    afile = tmp_path / "cache.txt"
    afile.write_text("not a cache\n", encoding="utf-8")
    result = run([*command, "--cache", afile, *(["--out", tmp_path / "b"] if command[0] == "build" else [])],
                 craftc)
    assert f"{afile}: is a file, not a record cache folder; give the cache's folder" in flat(result.output)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache.txt"]


# --------------------------------------------------------------------------- eval sim / robustness before models


def never(what: str) -> Any:
    """A stand-in for a loader the command must not reach: a call is a test failure (exit 1)."""

    def called(*args: object, **kwargs: object) -> None:
        raise AssertionError(f"{what} ran before the bad input was refused")

    return called


SIM_LABELS = Path(__file__).resolve().parents[1] / "artifacts" / "labels" / "sim_dev_labels.csv"


@pytest.mark.parametrize("bad", ["energy-form", "labels"])
def test_eval_sim_checks_the_energy_form_and_labels_before_the_pipeline(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, bad: str) -> None:
    """The simulator and grasp pipeline, the --kb bundles and the classifier (torch) were set up
    first: a typo was named seconds later (~15-20 s on a busy machine)."""
    from craft_e.runtime.cli import episodes

    for name in ("pick_pipeline", "scene_methods", "check_classifier"):
        monkeypatch.setattr(episodes, name, never(f"episodes.{name}"))
    labels = tmp_path / "labels.json"
    labels.write_text('{"cut": ["knife"]}', encoding="utf-8")
    if bad == "energy-form":
        result = run(["eval", "sim", "--labels", SIM_LABELS, "--energy-form", "bogus"])
        assert "--energy-form 'bogus': use one of sum-tanh, normalized-product" in flat(result.output)
    else:
        result = run(["eval", "sim", "--labels", labels])
        assert f"{labels}: sim labels are a CSV, not JSON" in flat(result.output)


def test_eval_robustness_checks_the_labels_before_the_image_encoder(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The ConSE image encoder (and the recognition row's bundle) loaded before the labels were
    read, so bad labels failed only after the model had loaded."""
    import craft_e.runtime.encoders.conse as conse
    import craft_e.runtime.evaluation.imagenet as imagenet
    import craft_e.runtime.kb.bundle as bundle

    monkeypatch.setattr(conse, "ConSEImageEncoder", never("the ConSE image encoder"))
    monkeypatch.setattr(imagenet, "_default_encoder", never("the default image encoder"))
    monkeypatch.setattr(bundle, "load_bundle", never("load_bundle"))
    labels = tmp_path / "labels.json"
    labels.write_text('{"cut": []}', encoding="utf-8")
    result = run(["eval", "robustness", "imagenet", "--labels", labels, "--episodes", "1"])
    assert f"{labels}: 'cut' lists no objects" in flat(result.output)


@pytest.mark.parametrize("command", [["eval", "imagenet"], ["eval", "robustness", "imagenet"]])
def test_imagenet_energy_form_is_checked_before_the_named_bundles(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, command: list[str]) -> None:
    import craft_e.runtime.kb.bundle as bundle

    monkeypatch.setattr(bundle, "load_bundle", never("load_bundle"))
    labels = tmp_path / "labels.json"
    labels.write_text('{"cut": ["cleaver"]}', encoding="utf-8")
    result = run([*command, "--labels", labels, "--kb", tmp_path / "kb", "--energy-form", "bogus"])
    assert "--energy-form 'bogus': use one of sum-tanh" in flat(result.output)
