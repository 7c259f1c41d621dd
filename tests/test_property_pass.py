"""Stage 2b (``--property-pass``): per-property answers merged into the per-object w_po.

Fixture pair: the kb_small cache plus one per-property answer; the built graph gains the new
edge, keeps the larger weight where both passes answered, and records both provenances. Adding
an object asks each property only about the new object.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from conftest import KB_SMALL, FixtureKB, build_config, fixture_source

from craft_e.compiler.build import build
from craft_e.compiler.curate import pending_property_requests, record_answers
from craft_e.compiler.vocab import read_vocabulary

NOTE = "test fixture (not knowledge to ship)"


def _names(file: str) -> list[str]:
    return read_vocabulary(KB_SMALL / file, kind="objects").names


def _record(cache: Path, rows: list[dict[str, object]], objects: str = "objects.txt") -> None:
    answers = cache.parent / "property_objects.jsonl"
    answers.write_text("\n".join(json.dumps(r) for r in rows) + "\n", encoding="utf-8")
    result = record_answers(
        fixture_source(cache), "property_objects", answers,
        read_vocabulary(KB_SMALL / "verbs.txt", kind="verbs").names, _names(objects),
        note=NOTE, version="v1",
    )  # fmt: skip
    assert not result.skipped, result.skipped


def _edges(bundle: Path) -> dict[tuple[str, str], dict[str, object]]:
    graph = json.loads((bundle / "graph.json").read_text())
    return {(e["source"], e["target"]): e for e in graph["edges"]}


def test_property_pass_adds_and_raises_edges(
    kb_a: FixtureKB, tmp_path: Path, clone_cache: Callable[[Path], Path]
) -> None:
    cache = clone_cache(tmp_path / "cache")
    verbs = read_vocabulary(KB_SMALL / "verbs.txt", kind="verbs").names
    pending = pending_property_requests(
        fixture_source(cache), verbs, _names("objects.txt"), version="v1"
    )
    rows: list[dict[str, object]] = [
        {"property": str(p["property"]), "scores": []}
        for p in pending
        if p["property"] != "concave"
    ]
    rows.append({"property": "concave", "scores": [
        {"object": "cup", "weight": 0.9}, {"object": "spoon", "weight": 1.0}]})  # fmt: skip
    _record(cache, rows)
    base = _edges(build(build_config(cache, tmp_path / "base")).out)
    config = build_config(cache, tmp_path / "merged").model_copy(update={"property_pass": True})
    merged = _edges(build(config).out)
    spoon = merged[("prop:concave", "obj:spoon")]
    assert spoon["weight"] == max(1.0, float(base[("prop:concave", "obj:spoon")]["weight"]))  # type: ignore[arg-type]
    assert len(spoon["provenance"]) == 2  # type: ignore[arg-type]
    cup = merged[("prop:concave", "obj:cup")]
    assert cup["weight"] >= 0.9  # type: ignore[operator]
    report = json.loads((tmp_path / "merged" / "report.json").read_text())
    assert report["pass_counts"]["stage2b_property_objects"]["records read"] >= 1


def test_adding_an_object_asks_each_property_only_about_it(
    kb_a: FixtureKB, tmp_path: Path, clone_cache: Callable[[Path], Path]
) -> None:
    cache = clone_cache(tmp_path / "cache")
    source = fixture_source(cache)
    verbs = read_vocabulary(KB_SMALL / "verbs.txt", kind="verbs").names
    before = pending_property_requests(source, verbs, _names("objects.txt"), version="v1")
    assert before and all(p["objects"] == sorted(_names("objects.txt")) for p in before)
    _record(cache, [{"property": str(p["property"]), "scores": []} for p in before])
    assert pending_property_requests(source, verbs, _names("objects.txt"), version="v1") == []
    grown = [*_names("objects.txt"), "ladle"]
    after = pending_property_requests(source, verbs, grown, version="v1")
    assert after and all(p["objects"] == ["ladle"] for p in after)


def test_direct_answers_grow_incrementally(tmp_path: Path) -> None:
    """Direct (v2) records cover the objects they offered; a bigger vocabulary asks only about
    the new objects, and the build combines both records for each verb."""
    from craft_e.compiler.build import BuildConfig
    from craft_e.compiler.curate import pending_direct_requests

    cache = tmp_path / "cache"
    source = fixture_source(cache)
    verbs = read_vocabulary(KB_SMALL / "verbs.txt", kind="verbs").names
    objects = _names("objects.txt")
    first = pending_direct_requests(source, verbs, objects)
    assert [p["verb"] for p in first] == verbs
    answers = tmp_path / "direct.jsonl"
    answers.write_text("\n".join(json.dumps({"verb": v, "ranking": [
        {"object": "spoon" if v == "scoop" else "knife", "score": 0.9}]}) for v in verbs) + "\n")  # fmt: skip
    assert record_answers(source, "verb_objects", answers, verbs, objects, version="v2").stored == 3
    grown = [*objects, "ladle"]
    second = pending_direct_requests(source, verbs, grown)
    assert [p["objects"] for p in second] == [["ladle"]] * 3
    answers.write_text("\n".join(json.dumps({"verb": v, "ranking": (
        [{"object": "ladle", "score": 0.8}] if v in ("scoop", "pour") else [])}) for v in verbs) + "\n")  # fmt: skip
    assert record_answers(source, "verb_objects", answers, verbs, grown, version="v2").stored == 3
    assert pending_direct_requests(source, verbs, grown) == []
    (tmp_path / "objects.txt").write_text("\n".join(grown) + "\n")
    config = BuildConfig(
        verbs_file=KB_SMALL / "verbs.txt", objects_file=tmp_path / "objects.txt",
        out=tmp_path / "kb", name="grown", mode="direct", tau=0.0,
        provider="test-fixture", model="fixture-v1", cache_root=cache,
    )  # fmt: skip
    edges = _edges(build(config).out)
    assert edges[("prop:direct: scoop", "obj:spoon")]["weight"] == 0.9
    assert edges[("prop:direct: scoop", "obj:ladle")]["weight"] == 0.8
    assert len(edges[("verb:scoop", "prop:direct: scoop")]["provenance"]) == 2  # type: ignore[arg-type]
