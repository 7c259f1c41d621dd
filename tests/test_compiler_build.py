"""The whole pipeline: determinism, concurrency, replay misses, atomic emit, incremental embeddings.

These are the promises the design card makes about ``craftc build``: the same inputs give a
byte-identical bundle; two builds may share one cache; a replay miss stops the build *before*
``--out`` is touched; and changing one verb re-embeds only that verb's texts.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import (
    KB_SMALL,
    MODEL,
    PROVIDER,
    FixtureKB,
    build_config,
    bundle_bytes,
    fixture_source,
    record_fixture,
)

from craft_e.compiler.build import VERB_TEMPLATE, build
from craft_e.compiler.embed import EmbeddingCache
from craft_e.compiler.llm_knowledge import verb_call
from craft_e.compiler.sources.llm import LLM_SOURCE, MissingRecordError
from craft_e.runtime.encoders.text import MINILM_ID
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.schemas.v1.bundle import BUILD_INFO_FILE, BUNDLE_FILES, MANIFEST_FILE

ALL_FILES = {*BUNDLE_FILES, MANIFEST_FILE, BUILD_INFO_FILE}
CloneCache = Callable[[Path], Path]


def _assert_identical(a: Path, b: Path) -> None:
    files_a, files_b = bundle_bytes(a), bundle_bytes(b)
    assert set(files_a) == set(files_b) == ALL_FILES
    # build_info.json holds time, host and duration on purpose: outside the content hash.
    differing = [n for n in sorted(ALL_FILES - {BUILD_INFO_FILE}) if files_a[n] != files_b[n]]
    assert not differing, f"files differ between two builds of the same inputs: {differing}"


def test_base_bundle_is_valid_and_knows_the_fixture(kb_a: FixtureKB) -> None:
    kb = load_bundle(kb_a.bundle)
    assert kb.manifest.verbs == ["cut", "scoop", "pour"]
    assert kb.manifest.objects == ["knife", "spoon", "bowl", "cup"]
    assert kb.manifest.sources[0].provider == PROVIDER
    best = {v: kb.manifest.objects[int(kb.energy[i].argmin())] for v, i in kb.verb_index.items()}
    assert best == {"cut": "knife", "scoop": "spoon", "pour": "cup"}
    assert kb.energy[kb.verb_index["cut"], kb.object_index["bowl"]] == 0.0  # no path: no energy
    # weights below tau (knife "thin" 0.3) are edges in the graph but not paths
    assert not [p for p in kb.paths("cut", "knife") if p.prop == "thin"]
    assert kb.report.counts["verbs"] == 3 and kb.report.counts["verb_property_edges"] == 30


def test_report_counts_every_pass(kb_a: FixtureKB) -> None:
    report = json.loads((kb_a.bundle / "report.json").read_text("utf-8"))
    counts = report["pass_counts"]
    assert counts["read_vocabulary"] == {"normalization notes": 0, "objects": 4, "verbs": 3}
    assert counts["stage1_verb_properties"] == {"edges kept": 30, "records read": 3}
    assert counts["stage2_object_properties"]["records read"] == 4
    assert report["coverage"]["objects_unreachable_from_any_verb"] == []


def test_two_builds_are_byte_identical(kb_a: FixtureKB, tmp_path: Path) -> None:
    second = build(build_config(kb_a.cache, tmp_path / "again"))
    assert second.embedding_misses == 0
    _assert_identical(kb_a.bundle, tmp_path / "again")


def test_recomputed_embeddings_give_the_same_bytes(
    kb_a: FixtureKB, tmp_path: Path, clone_cache: CloneCache
) -> None:
    """Texts re-encoded now give the same bytes as the cached ones (encoder is deterministic).

    Only the verb texts are dropped from the cache, to keep the test fast on 2 cores.
    """
    cache = clone_cache(tmp_path / "cache")
    folder = EmbeddingCache(cache / "embeddings", MINILM_ID).folder
    verbs = ["cut", "scoop", "pour"]
    texts = verbs + [VERB_TEMPLATE.format(verb=v) for v in verbs]
    for text in texts:
        (folder / f"{hashlib.sha256(text.encode()).hexdigest()}.npy").unlink()
    result = build(build_config(cache, tmp_path / "cold"))
    assert result.embedding_misses == len(texts)
    _assert_identical(kb_a.bundle, tmp_path / "cold")


# A "live provider" in a child process: answers from the fixture files, so two processes fetch
# and write the same records into one cache at the same time, then build.
_CONCURRENT_BUILD = """
import json, sys
from pathlib import Path
from craft_e.compiler.build import BuildConfig, build

fixtures, cache, out = (Path(a) for a in sys.argv[1:4])
answers = {}
for name, key in (("verb_properties.jsonl", "verb"), ("object_properties.jsonl", "object")):
    for line in (fixtures / name).read_text(encoding="utf-8").splitlines():
        if line.strip() and not line.startswith("//"):
            row = json.loads(line)
            answers[row[key]] = row

class FixtureTransport:
    provider = "test-fixture"
    model = "fixture-v1"

    def complete(self, request):
        row = answers[request.subject]
        if request.prompt.startswith("object_properties"):
            named = set(request.variables["properties"])
            row = {"object": row["object"],
                   "scores": [s for s in row["scores"] if s["property"] in named]}
        return json.dumps(row)

config = BuildConfig(verbs_file=fixtures / "verbs.txt", objects_file=fixtures / "objects.txt",
                     out=out, name="fixture-kb", provider="test-fixture", model="fixture-v1",
                     cache_root=cache, prompt_version="v1")
print(build(config, transport=FixtureTransport()).manifest.content_sha256)
"""


def test_two_concurrent_builds_on_one_cache_agree(kb_a: FixtureKB, tmp_path: Path) -> None:
    """Two processes record the same answers into one empty record cache and build at once."""
    import shutil

    from craft_e.compiler.cache import RecordCache

    cache = tmp_path / "cache"
    shutil.copytree(kb_a.cache / "embeddings", cache / "embeddings")  # skip the encoder load
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                "-c",
                _CONCURRENT_BUILD,
                str(KB_SMALL),
                str(cache),
                str(tmp_path / f"out{i}"),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        for i in range(2)
    ]
    outputs = [p.communicate(timeout=240) for p in procs]
    for proc, (_, errors) in zip(procs, outputs, strict=True):
        assert proc.returncode == 0, errors
    hashes = [out.strip().splitlines()[-1] for out, _ in outputs]
    assert hashes[0] == hashes[1]
    # the records they wrote are whole and are exactly the replayed fixture's knowledge
    report = RecordCache(cache).verify()
    assert report.ok and report.checked == 7
    _assert_identical(tmp_path / "out0", tmp_path / "out1")
    assert hashes[0] == load_bundle(kb_a.bundle).manifest.content_sha256


def test_replay_miss_fails_before_out_is_touched(kb_a: FixtureKB, tmp_path: Path) -> None:
    out = tmp_path / "bundle"
    with pytest.raises(MissingRecordError) as info:
        build(build_config(kb_a.cache, out, verbs="verbs_stir.txt"))
    key = fixture_source(kb_a.cache).request_for(verb_call("stir", version="v1")).key()
    assert "subject='stir'" in str(info.value)
    assert str(kb_a.cache / LLM_SOURCE / f"{key}.json") in str(info.value)
    assert not out.exists()
    assert list(tmp_path.iterdir()) == [], "no staging folder left behind"


def test_failed_emit_keeps_the_previous_bundle(
    kb_a: FixtureKB, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An error while writing (here: in the final swap) leaves the old bundle whole at --out."""
    import shutil

    out = tmp_path / "bundle"
    shutil.copytree(kb_a.bundle, out)
    before = bundle_bytes(out)
    real_replace = os.replace

    def failing_swap(src: str | Path, dst: str | Path) -> None:
        if Path(dst) == out.resolve() and ".tmp" in Path(src).name:
            raise OSError("simulated crash while swapping the new bundle in")
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", failing_swap)  # the os module emit.write_bundle uses
    with pytest.raises(OSError, match="simulated crash"):
        build(build_config(kb_a.cache, out))
    assert bundle_bytes(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["bundle"], "staging and retired folders cleaned"


def test_emit_replaces_an_existing_bundle_atomically(kb_a: FixtureKB, tmp_path: Path) -> None:
    import shutil

    out = tmp_path / "bundle"
    shutil.copytree(kb_a.bundle, out)
    (out / "stale.txt").write_text("from an older build", encoding="utf-8")
    build(build_config(kb_a.cache, out).model_copy(update={"force": True}))
    assert set(bundle_bytes(out)) == ALL_FILES, "the new bundle replaces the folder, not merges"
    assert [p.name for p in tmp_path.iterdir()] == ["bundle"]


def test_changing_one_verb_re_embeds_only_its_texts(
    kb_a: FixtureKB, tmp_path: Path, clone_cache: CloneCache
) -> None:
    """Replace "pour" by "stir": only "stir", its query text and its one new property are new."""
    cache = clone_cache(tmp_path / "cache")
    record_fixture(cache, "verb_properties", "stir.verb_properties.jsonl", "verbs_stir.txt")
    record_fixture(cache, "object_properties", "stir.object_properties.jsonl", "verbs_stir.txt")
    folder = EmbeddingCache(cache / "embeddings", MINILM_ID).folder
    before = {p.name for p in folder.iterdir()}

    result = build(build_config(cache, tmp_path / "bundle", verbs="verbs_stir.txt"))

    new_texts = ["stir", VERB_TEMPLATE.format(verb="stir"), "long handle"]
    assert result.embedding_misses == len(new_texts)
    added = {p.name for p in folder.iterdir()} - before
    assert added == {hashlib.sha256(t.encode()).hexdigest() + ".npy" for t in new_texts}
    kb = load_bundle(tmp_path / "bundle")
    assert kb.manifest.verbs == ["cut", "scoop", "stir"]
    assert "long handle" in kb.manifest.properties
    # the unchanged verbs' rows are the same vectors as in the base bundle
    base = load_bundle(kb_a.bundle)
    assert (kb.embeddings["verb"][:2] == base.embeddings["verb"][:2]).all()


def test_changing_a_verbs_answer_re_embeds_nothing(kb_scoop_v2: FixtureKB) -> None:
    """A revised answer that names only known properties needs no new embeddings."""
    assert kb_scoop_v2.embedding_misses == 0


def test_record_provider_and_model_are_part_of_replay(kb_a: FixtureKB, tmp_path: Path) -> None:
    """Replaying another provider's records is a miss, never a silent substitution."""
    config = build_config(kb_a.cache, tmp_path / "bundle").model_copy(
        update={"provider": "curated"}
    )
    with pytest.raises(MissingRecordError, match="provider=curated"):
        build(config)
    config = build_config(kb_a.cache, tmp_path / "bundle").model_copy(update={"model": "other"})
    with pytest.raises(MissingRecordError, match=f"provider={PROVIDER}, model=other"):
        build(config)
    assert MODEL != "other"
