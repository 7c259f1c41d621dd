"""Pass 3's store, the record cache: atomic writes, and corruption that is named, never skipped.

The cache *is* the knowledge of a replay build, so a damaged or hand-edited record must be
reported with its file name (a silent miss would quietly change the KB), and an interrupted
write must leave either the old record or none.
"""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import pytest

from craft_e.compiler.cache import (
    INDEX_FILE,
    CacheError,
    RecordCache,
    read_index,
    record_bytes,
    sha256_hex,
)
from craft_e.compiler.llm_knowledge import verb_call
from craft_e.compiler.sources.llm import LLM_SOURCE, LLMSource, MissingRecordError
from craft_e.files import atomic_write_bytes
from craft_e.schemas.v1.records import Record

PAYLOAD = {"verb": "cut", "properties": [{"name": "sharp edge", "weight": 0.9}]}


def _record(cache: RecordCache, verb: str = "cut", note: str = "test fixture") -> Record:
    source = LLMSource(cache, provider="test-fixture", model="fixture-v1")
    request = source.request_for(verb_call(verb, version="v1"))
    payload = {**PAYLOAD, "verb": verb}
    return Record(
        key=request.key(),
        source=LLM_SOURCE,
        request=request,
        raw_response=json.dumps(payload),
        payload=payload,
        note=note,
    )


@pytest.fixture
def cache(tmp_path: Path) -> RecordCache:
    return RecordCache(tmp_path / "cache")


def test_put_then_get_round_trips(cache: RecordCache) -> None:
    record = _record(cache)
    path = cache.put(record)
    assert path == cache.path_for(LLM_SOURCE, record.key)
    assert path.read_bytes() == record_bytes(record)
    assert cache.get(LLM_SOURCE, record.key) == record
    assert cache.get(LLM_SOURCE, "0" * 64) is None  # a miss is None, not an error
    left = sorted(p.name for p in path.parent.iterdir())
    assert left == sorted([path.name, INDEX_FILE, ".index.lock"]), "no temp files left behind"


def test_record_bytes_are_canonical(cache: RecordCache) -> None:
    data = record_bytes(_record(cache))
    assert data.endswith(b"\n")
    assert (
        json.dumps(json.loads(data), indent=2, sort_keys=True, ensure_ascii=False).encode() + b"\n"
        == data
    )


def test_put_refuses_a_key_that_is_not_the_request_hash(cache: RecordCache) -> None:
    record = _record(cache).model_copy(update={"key": "f" * 64})
    with pytest.raises(CacheError, match="does not match its request hash"):
        cache.put(record)
    assert not (cache.root / LLM_SOURCE).exists()


def test_interrupted_write_keeps_the_old_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "llm" / "x.json"
    atomic_write_bytes(target, b"old")

    def boom(src: str, dst: str) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_bytes(target, b"new")
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in target.parent.iterdir()) == ["x.json"], "temp file removed"


def test_concurrent_puts_of_one_key_leave_one_whole_record(cache: RecordCache) -> None:
    record = _record(cache)
    threads = [threading.Thread(target=cache.put, args=(record,)) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert cache.get(LLM_SOURCE, record.key) == record
    assert len(list((cache.root / LLM_SOURCE).glob("*.json"))) == 1
    assert read_index(cache.root / LLM_SOURCE / INDEX_FILE) == {
        f"{record.key}.json": sha256_hex(record_bytes(record))
    }


def test_corrupt_record_is_an_error_naming_the_file(cache: RecordCache) -> None:
    path = cache.put(_record(cache))
    path.write_bytes(path.read_bytes()[:-40])  # truncated
    with pytest.raises(CacheError) as info:
        cache.get(LLM_SOURCE, path.stem)
    assert str(info.value).startswith(f"{path}: not a valid v1 record")
    report = cache.verify()
    assert not report.ok
    assert report.checked == 1
    assert [p for p, _ in report.corrupt] == [path]
    assert str(path) in report.corrupt[0][1]


def test_edited_record_is_detected(cache: RecordCache) -> None:
    path = cache.put(_record(cache))
    data = json.loads(path.read_bytes())
    data["request"]["model"] = "another-model"  # edited after recording
    path.write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(CacheError, match="edited after recording"):
        cache.get(LLM_SOURCE, path.stem)
    assert [p for p, _ in cache.verify().corrupt] == [path]


def test_record_under_the_wrong_file_name_is_a_key_mismatch(cache: RecordCache) -> None:
    good = cache.put(_record(cache, "cut"))
    other = _record(cache, "scoop")
    wrong = cache.path_for(LLM_SOURCE, other.key)
    wrong.write_bytes(good.read_bytes())  # cut's record stored under scoop's key
    with pytest.raises(CacheError, match="file name does not match the record key"):
        cache.get(LLM_SOURCE, other.key)
    report = cache.verify()
    assert report.checked == 2
    assert [p for p, _ in report.corrupt] == [wrong]
    assert f"{wrong}: file name does not match" in report.corrupt[0][1]


def test_orphaned_temp_files_are_reported(cache: RecordCache) -> None:
    path = cache.put(_record(cache))
    tmp = path.parent / f".{path.name}.abc123.tmp"  # what a killed writer leaves behind
    tmp.write_bytes(b"{")
    stray = path.parent / "notes.txt"
    stray.write_text("not a record", encoding="utf-8")
    report = cache.verify()
    assert report.corrupt == []
    assert report.orphaned == [tmp, stray]
    assert not report.ok


def test_unreferenced_records_are_orphans_when_a_reference_set_is_given(cache: RecordCache) -> None:
    a = cache.put(_record(cache, "cut"))
    b = cache.put(_record(cache, "scoop"))
    assert cache.verify().ok
    report = cache.verify(referenced={a.stem})
    assert report.orphaned == [b]


def test_embeddings_folder_is_not_a_record_source(cache: RecordCache) -> None:
    cache.put(_record(cache))
    (cache.root / "embeddings" / "minilm-l6-v2").mkdir(parents=True)
    (cache.root / "embeddings" / "minilm-l6-v2" / "x.npy").write_bytes(b"")
    assert cache.sources() == [LLM_SOURCE]
    assert cache.verify().ok


def test_stats_count_records_per_provider_and_prompt(cache: RecordCache) -> None:
    cache.put(_record(cache, "cut"))
    cache.put(_record(cache, "scoop"))
    stats = cache.stats()[LLM_SOURCE]
    assert stats["records"] == 2
    assert stats["test-fixture:verb_properties@v1"] == 2
    assert stats["bytes"] > 0


def test_replay_miss_names_the_subject_and_the_expected_path(cache: RecordCache) -> None:
    source = LLMSource(cache, provider="test-fixture", model="fixture-v1")
    call = verb_call("whisk", version="v1")
    expected = cache.path_for(LLM_SOURCE, source.request_for(call).key())
    with pytest.raises(MissingRecordError) as info:
        source.fetch(call)
    message = str(info.value)
    assert "verb_properties@v1 subject='whisk'" in message
    assert str(expected) in message
    assert "craftc curate" in message  # says how to fix it
