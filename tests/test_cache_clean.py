"""``craftc cache clean`` and ``craftc cache stats`` on a copy of the fixture cache.

Clean keeps every record a bundle's provenance names (plus same-subject siblings) and, with
``--verbs``, every record a replay build of those inputs reads; it is a dry run unless
``--yes``; deleting keeps ``SHA256SUMS`` consistent, so ``cache verify`` passes and the kept
records still rebuild the bundle.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from conftest import KB_SMALL, MODEL, PROVIDER, FixtureKB, build_config, fixture_source
from typer.testing import CliRunner, Result

from craft_e.compiler.build import build
from craft_e.compiler.cache import INDEX_FILE, RecordCache, cache_in_use, read_index
from craft_e.compiler.cache_clean import build_references, bundle_references
from craft_e.compiler.cli import app
from craft_e.compiler.llm_knowledge import object_call, verb_call
from craft_e.compiler.sources.llm import LLM_SOURCE, PromptCall
from craft_e.schemas.v1.records import Record

FIXTURE_BUILD = ["--verbs", str(KB_SMALL / "verbs.txt"), "--objects", str(KB_SMALL / "objects.txt"),
                 "--prompts", "v1", "--record-provider", PROVIDER, "--model", MODEL]


def craftc(*args: str | Path) -> Result:
    return CliRunner().invoke(app, [str(a) for a in args], env={"COLUMNS": "2000"})


def put_answer(cache_root: Path, call_payload: tuple[PromptCall, dict[str, object]]) -> str:
    """Store one fixture-provider record (an answer no bundle used) and return its key."""
    call, payload = call_payload
    source = fixture_source(cache_root)
    request = source.request_for(call)
    record = Record(key=request.key(), source=LLM_SOURCE, request=request,
                    raw_response=json.dumps(payload), payload=payload, note="test fixture")
    source.cache.put(record)
    return record.key


def cache_with_extras(clone_cache: Callable[[Path], Path], dest: Path) -> tuple[Path, str, str]:
    """The fixture cache plus an unused verb record (stab) and a sibling of knife's record."""
    cache = clone_cache(dest)
    stab = put_answer(cache, (verb_call("stab", version="v1"), {
        "verb": "stab", "properties": [{"name": "pointed tip", "weight": 0.9}]}))
    sibling = put_answer(cache, (object_call("knife", ["is a cutlery item"], version="v1"), {
        "object": "knife", "scores": [{"property": "is a cutlery item", "weight": 0.9}]}))
    return cache, stab, sibling


def llm_keys(cache: Path) -> set[str]:
    return {p.stem for p in (cache / LLM_SOURCE).glob("*.json")}


def test_dry_run_lists_and_keeps_everything(
    kb_a: FixtureKB, clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    cache, stab, sibling = cache_with_extras(clone_cache, tmp_path / "cache")
    before = {p: p.read_bytes() for p in (cache / LLM_SOURCE).iterdir()}
    result = craftc("cache", "clean", "--cache", cache, "--bundles", kb_a.bundle)
    assert result.exit_code == 0, result.output
    assert f"would delete: {stab}.json  {PROVIDER}/{MODEL} verb_properties@v1 subject='stab'" in result.output
    assert sibling not in result.output  # same provider/model/prompt/subject as a named record
    assert "1 bundles read; 8 records referenced; would delete 1" in result.output
    assert "--yes" in result.output
    assert {p: p.read_bytes() for p in (cache / LLM_SOURCE).iterdir()} == before


def test_yes_deletes_keeps_the_index_consistent_and_the_bundle_rebuilds(
    kb_a: FixtureKB, clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    cache, stab, sibling = cache_with_extras(clone_cache, tmp_path / "cache")
    result = craftc("cache", "clean", "--cache", cache, "--bundles", kb_a.bundle, "--yes")
    assert result.exit_code == 0, result.output
    assert f"deleted: {stab}.json" in result.output
    assert stab not in llm_keys(cache) and sibling in llm_keys(cache)
    index = read_index(cache / LLM_SOURCE / INDEX_FILE)
    assert set(index) == {f"{k}.json" for k in llm_keys(cache)}
    assert craftc("cache", "verify", "--cache", cache).exit_code == 0
    rebuilt = build(build_config(cache, tmp_path / "kb"))
    assert (tmp_path / "kb" / "graph.json").read_bytes() == (kb_a.bundle / "graph.json").read_bytes()
    assert rebuilt.manifest.content_sha256
    again = craftc("cache", "clean", "--cache", cache, "--bundles", kb_a.bundle)
    assert "would delete 0" in again.output


def test_verbs_keep_exactly_what_a_replay_build_reads(
    kb_a: FixtureKB, clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    cache, stab, sibling = cache_with_extras(clone_cache, tmp_path / "cache")
    assert {stab, sibling} <= llm_keys(cache)
    empty = tmp_path / "no-bundles"
    empty.mkdir()
    used = build_references(RecordCache(cache), KB_SMALL / "verbs.txt", KB_SMALL / "objects.txt",
                            ["llm"], provider=PROVIDER, model=MODEL, prompt_version="v1")
    assert used == llm_keys(kb_a.cache)  # the 7 records of the fixture build
    provenance, graphs = bundle_references([kb_a.bundle])
    assert graphs == [kb_a.bundle / "graph.json"] and provenance <= used
    result = craftc("cache", "clean", "--cache", cache, "--bundles", empty, *FIXTURE_BUILD, "--yes")
    assert result.exit_code == 0, result.output
    assert llm_keys(cache) == used  # the stab record and the unread sibling are gone
    assert "0 bundles read; 7 records referenced; deleted 2" in result.output
    assert craftc("cache", "verify", "--cache", cache).exit_code == 0


def test_refuses_without_anything_that_references_records(
    clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    cache = clone_cache(tmp_path / "cache")
    empty = tmp_path / "no-bundles"
    empty.mkdir()
    before = llm_keys(cache)
    result = craftc("cache", "clean", "--cache", cache, "--bundles", empty, "--yes")
    assert result.exit_code == 2
    assert "refusing" in result.output
    assert llm_keys(cache) == before


def test_a_build_that_cannot_replay_deletes_nothing(
    clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    cache = clone_cache(tmp_path / "cache")
    empty = tmp_path / "no-bundles"
    empty.mkdir()
    verbs = tmp_path / "verbs.txt"
    verbs.write_text("cut\nscoop\npour\nwhittle\n", encoding="utf-8")
    before = llm_keys(cache)
    args = ["--verbs", verbs, *FIXTURE_BUILD[2:]]
    result = craftc("cache", "clean", "--cache", cache, "--bundles", empty, *args, "--yes")
    assert result.exit_code == 3
    assert "subject='whittle'" in result.output and "nothing deleted" in result.output
    assert llm_keys(cache) == before



def test_a_mistyped_bundles_path_deletes_nothing(
    kb_a: FixtureKB, clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    """A --bundles path that does not exist is an error, not a bundle with no records to keep."""
    cache = clone_cache(tmp_path / "cache")
    before = llm_keys(cache)
    result = craftc("cache", "clean", "--cache", cache, "--bundles", kb_a.bundle,
                    "--bundles", tmp_path / "kb-typo", "--yes")
    assert result.exit_code == 2
    assert "kb-typo: no such bundle folder" in result.output and "nothing deleted" in result.output
    assert llm_keys(cache) == before


def test_perception_records_a_bundle_ships_are_kept(kb_a: FixtureKB, tmp_path: Path) -> None:
    """The size and colour records named in object_sizes.json / object_colours.json are referenced:
    a rebuild looks them up, and without them it would ship fewer sizes, silently."""
    bundle = tmp_path / "kb"
    bundle.mkdir()
    (bundle / "graph.json").write_bytes((kb_a.bundle / "graph.json").read_bytes())
    size_key, colour_key = "a" * 64, "b" * 64
    (bundle / "object_sizes.json").write_text(json.dumps(
        {"objects": {"knife": {"dimensions_cm": [20, 2, 1], "record": size_key}}}))
    (bundle / "object_colours.json").write_text(json.dumps(
        {"objects": {"knife": {"colours": [], "record": colour_key}, "odd": "not an entry"}}))
    keys, graphs = bundle_references([bundle])
    plain, _ = bundle_references([kb_a.bundle])
    assert graphs == [bundle / "graph.json"]
    assert keys == plain | {size_key, colour_key}

def test_stats_per_provider_model_and_prompt_version(kb_a: FixtureKB) -> None:
    stats = craftc("cache", "stats", "--cache", kb_a.cache)
    assert stats.exit_code == 0
    llm = json.loads(stats.stdout)[LLM_SOURCE]
    assert llm[f"{PROVIDER}/{MODEL}/verb_properties@v1"] == 3
    assert llm[f"{PROVIDER}/{MODEL}/object_properties@v1"] == 4
    rows = RecordCache(kb_a.cache).stats_rows()
    assert [(r.source, r.provider, r.model, r.prompt, r.version, r.records) for r in rows] == [
        (LLM_SOURCE, PROVIDER, MODEL, "object_properties", "v1", 4),
        (LLM_SOURCE, PROVIDER, MODEL, "verb_properties", "v1", 3),
    ]
    assert sum(r.bytes for r in rows) == llm["bytes"]
    table = craftc("cache", "stats", "--cache", kb_a.cache, "--table")
    assert table.exit_code == 0
    line = next(x for x in table.stdout.splitlines() if "verb_properties" in x)
    assert PROVIDER in line and MODEL in line and " v1 " in line and " 3 " in line


def test_clean_refuses_while_a_build_or_curation_uses_the_cache(
    kb_a: FixtureKB, clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    """A running build has stored records no bundle names yet: clean --yes must not delete them."""
    cache, stab, _ = cache_with_extras(clone_cache, tmp_path / "cache")
    with cache_in_use(cache):  # what `craftc build` and `craftc curate record` hold
        busy = craftc("cache", "clean", "--cache", cache, "--bundles", kb_a.bundle, "--yes")
        assert busy.exit_code == 2, busy.output
        assert "is using this cache" in " ".join(busy.output.split())
        assert stab in llm_keys(cache)
        dry = craftc("cache", "clean", "--cache", cache, "--bundles", kb_a.bundle)
        assert dry.exit_code == 0 and "would delete 1" in dry.output  # a dry run only reads
    done = craftc("cache", "clean", "--cache", cache, "--bundles", kb_a.bundle, "--yes")
    assert done.exit_code == 0, done.output
    assert stab not in llm_keys(cache)
