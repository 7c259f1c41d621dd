"""Verb senses: a gloss on a verbs-file line is asked with prompt v3 (v2 + the verb's sense).

A glossed verb gets new stage-1 and direct records; an unglossed verb keeps its v2 record (its
key does not change), the verb node carries the gloss, ``craftc explain`` prints it, and
``--object-pass reuse`` builds from stage 2b alone where no per-object record exists.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import KB_SMALL, MODEL, PROVIDER, fixture_source

from craft_e.compiler.build import BuildConfig, build
from craft_e.compiler.curate import (
    pending_direct_requests,
    pending_property_requests,
    pending_verb_requests,
    record_answers,
)
from craft_e.compiler.llm_knowledge import verb_call
from craft_e.compiler.sources.llm import MissingRecordError
from craft_e.compiler.vocab import read_vocabulary
from craft_e.runtime.grounding.explain import explain_pair
from craft_e.runtime.kb.bundle import load_bundle

NOTE = "test fixture (not knowledge to ship)"
SCOOP_SENSE = "to take up loose material with a concave tool; the object is the tool"


def _vocab(tmp: Path) -> tuple[Path, Path]:
    verbs, objects = tmp / "verbs.txt", tmp / "objects.txt"
    verbs.write_text(f"cut\nscoop\t{SCOOP_SENSE}\n", encoding="utf-8")
    objects.write_text((KB_SMALL / "objects.txt").read_text(encoding="utf-8"), encoding="utf-8")
    return verbs, objects


def _answer(cache: Path, prompt: str, rows: list[dict[str, object]], verbs: Path, objects: Path) -> None:
    answers = cache.parent / f"{prompt}.jsonl"
    answers.write_text("\n".join(json.dumps(r) for r in rows) + "\n", encoding="utf-8")
    vv = read_vocabulary(verbs, kind="verbs")
    ov = read_vocabulary(objects, kind="objects")
    result = record_answers(
        fixture_source(cache), prompt, answers, vv.names, ov.names, note=NOTE,
        version="v2", glosses=ov.glosses, verb_glosses=vv.glosses,
    )  # fmt: skip
    assert not result.skipped and result.stored == len(rows), result


def _props(verb: str, *names: str) -> dict[str, object]:
    return {"verb": verb, "properties": [
        {"name": n, "definition": f"{n} (fixture definition)", "role": "helpful", "weight": 0.8}
        for n in names]}  # fmt: skip


def _config(cache: Path, verbs: Path, objects: Path, out: Path, **extra: object) -> BuildConfig:
    return BuildConfig(
        verbs_file=verbs, objects_file=objects, out=out, name="sensed", provider=PROVIDER,
        model=MODEL, cache_root=cache, prompt_version="v2", property_pass=True, **extra,
    )  # fmt: skip


def test_glossed_verb_is_asked_in_its_sense_and_others_keep_their_key() -> None:
    plain = verb_call("scoop", version="v2")
    sensed = verb_call("scoop", version="v2", gloss=SCOOP_SENSE)
    assert plain.template.ref == "verb_properties@v2" and "verb_gloss" not in plain.variables
    assert sensed.template.ref == "verb_properties@v3"
    assert SCOOP_SENSE in sensed.template.render(**sensed.variables)[1].content
    # v1 prompts state no sense: a gloss must not change what they ask
    assert verb_call("scoop", version="v1", gloss=SCOOP_SENSE) == verb_call("scoop", version="v1")
    source = fixture_source(Path("unused"))
    assert source.request_for(plain).key() != source.request_for(sensed).key()


def test_build_with_a_glossed_verb_from_stage_2b_alone(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    verbs, objects = _vocab(tmp_path)
    pending = pending_verb_requests(
        fixture_source(cache), ["cut", "scoop"], [], version="v2", verb_glosses={"scoop": SCOOP_SENSE}
    )
    assert [(p["verb"], p["gloss"]) for p in pending] == [("cut", ""), ("scoop", SCOOP_SENSE)]
    _answer(cache, "verb_properties", [_props("cut", "sharp edge", "hard blade", "has a handle"),
                                       _props("scoop", "concave", "has a handle", "rigid")],
            verbs, objects)  # fmt: skip
    source = fixture_source(cache)
    vv = read_vocabulary(verbs, kind="verbs")
    names = read_vocabulary(objects, kind="objects").names
    assert pending_verb_requests(source, vv.names, names, verb_glosses=vv.glosses) == []
    props = pending_property_requests(source, vv.names, names, verb_glosses=vv.glosses)
    assert sorted(p["property"] for p in props) == [
        "concave", "hard blade", "has a handle", "rigid", "sharp edge"]  # fmt: skip
    _answer(cache, "property_objects", [
        {"property": "concave", "scores": [{"object": "spoon", "weight": 1.0}, {"object": "bowl", "weight": 0.9}]},
        {"property": "sharp edge", "scores": [{"object": "knife", "weight": 1.0}]},
        {"property": "hard blade", "scores": [{"object": "knife", "weight": 1.0}]},
        {"property": "has a handle", "scores": [{"object": "knife", "weight": 1.0}, {"object": "cup", "weight": 0.6}]},
        {"property": "rigid", "scores": []},
    ], verbs, objects)  # fmt: skip
    direct = pending_direct_requests(source, vv.names, names, verb_glosses=vv.glosses)
    assert SCOOP_SENSE in str(direct[1]["prompt"]) and SCOOP_SENSE not in str(direct[0]["prompt"])

    # no per-object (stage 2) record exists: asking for it fails offline, reusing builds
    with pytest.raises(MissingRecordError):
        build(_config(cache, verbs, objects, tmp_path / "ask"))
    out = build(_config(cache, verbs, objects, tmp_path / "kb", object_pass="reuse")).out
    graph = json.loads((out / "graph.json").read_text())
    nodes = {n["id"]: n for n in graph["nodes"]}
    assert nodes["verb:scoop"]["gloss"] == SCOOP_SENSE and "gloss" not in nodes["verb:cut"]
    manifest = json.loads((out / "manifest.json").read_text())
    prompts = {p for s in manifest["sources"] for p in s["prompts"]}
    assert {"verb_properties@v2", "verb_properties@v3"} <= prompts
    report = json.loads((out / "report.json").read_text())
    assert report["pass_counts"]["stage2_object_properties"]["objects with properties left to stage 2b"] == 4
    explanation = explain_pair(load_bundle(out), "scoop", "spoon")
    assert explanation.paths and f"scoop (verb): {SCOOP_SENSE}" in explanation.render()
    assert "(verb)" not in explain_pair(load_bundle(out), "cut", "knife").render()


def test_object_pass_reuse_needs_the_property_pass(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from craft_e.compiler.cli import app

    verbs, objects = _vocab(tmp_path)
    result = CliRunner().invoke(app, [
        "build", "--verbs", str(verbs), "--objects", str(objects), "--object-pass", "reuse",
        "--out", str(tmp_path / "kb"), "--cache", str(tmp_path / "cache")])  # fmt: skip
    assert result.exit_code == 2 and "--property-pass" in result.output
    assert not (tmp_path / "kb").exists()
