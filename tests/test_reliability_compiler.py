"""``craftc`` reliability probes (issue 12, items 5-8): record integrity, exit codes, literal text.

Each test is one probe of ``docs/reliability.md``; it failed on the code before the fix.
"""

from __future__ import annotations

import errno
import json
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import KB_SMALL, FixtureKB
from test_cli_craftc import craftc, flat, replay_args

from craft_e.compiler.cache import INDEX_FILE, RecordCache, read_index
from craft_e.compiler.sources.llm import LLM_SOURCE
from craft_e.paths import CACHE_DIR

# --- item 5: record and embedding integrity ---------------------------------------------------


def _record_of(cache: Path, subject: str) -> Path:
    for path in sorted((cache / LLM_SOURCE).glob("*.json")):
        if json.loads(path.read_bytes())["request"]["subject"] == subject:
            return path
    raise AssertionError(subject)


def _edit_answer(path: Path, *, raw_too: bool) -> None:
    """Lower every weight of a record's answer, as a hand edit would."""
    data = json.loads(path.read_bytes())

    def lower(value: object) -> object:
        if isinstance(value, dict):
            return {k: (0.01 if k.startswith("w") and isinstance(v, float) else lower(v))
                    for k, v in value.items()}
        if isinstance(value, list):
            return [lower(v) for v in value]
        return value

    data["payload"] = lower(data["payload"])
    assert data["payload"] != json.loads(path.read_bytes())["payload"], "nothing edited"
    if raw_too:
        data["raw_response"] = json.dumps(data["payload"], sort_keys=True)
    path.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n", encoding="utf-8")


def test_an_edited_answer_fails_verify_and_the_build(
    clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    cache = clone_cache(tmp_path / "cache")
    victim = _record_of(cache, "knife")
    _edit_answer(victim, raw_too=True)  # consistent edit: request hash and parse still agree
    result = craftc("cache", "verify", "--cache", cache)
    assert result.exit_code == 1, result.output
    assert f"corrupt: {victim}" in flat(result.output)
    assert "edited after recording" in flat(result.output)
    build = craftc(*replay_args(cache, tmp_path / "out"))
    assert build.exit_code == 2, build.output
    assert str(victim) in flat(build.output)
    assert not (tmp_path / "out").exists()


def test_an_edited_payload_is_refused_even_without_an_index_entry(
    clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    cache = clone_cache(tmp_path / "cache")
    victim = _record_of(cache, "cut")
    _edit_answer(victim, raw_too=False)
    index = cache / LLM_SOURCE / INDEX_FILE
    entries = read_index(index)
    del entries[victim.name]
    index.write_text("".join(f"{d}  {n}\n" for n, d in sorted(entries.items())), encoding="utf-8")
    build = craftc(*replay_args(cache, tmp_path / "out"))
    assert build.exit_code == 2, build.output
    assert "payload differs from the validated parse of raw_response" in flat(build.output)
    verify = craftc("cache", "verify", "--cache", cache)
    assert verify.exit_code == 1
    assert f"corrupt: {victim}" in flat(verify.output)
    assert "payload differs" in flat(verify.output)


def test_swapped_embedding_files_fail_verify_and_the_build(
    clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    import hashlib

    cache = clone_cache(tmp_path / "cache")
    folder = cache / "embeddings" / "minilm-l6-v2"
    knife, spoon = (folder / f"{hashlib.sha256(t.encode()).hexdigest()}.npy" for t in ("knife", "spoon"))
    a, b = knife.read_bytes(), spoon.read_bytes()
    knife.write_bytes(b)
    spoon.write_bytes(a)
    verify = craftc("cache", "verify", "--cache", cache)
    assert verify.exit_code == 1, verify.output
    assert str(knife) in flat(verify.output) and str(spoon) in flat(verify.output)
    build = craftc(*replay_args(cache, tmp_path / "out"))
    assert build.exit_code == 2, build.output
    assert "does not belong to" in flat(build.output)


def test_index_command_adds_only_missing_entries(
    clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    cache = clone_cache(tmp_path / "cache")
    index = cache / LLM_SOURCE / INDEX_FILE
    before = read_index(index)
    index.unlink()
    assert craftc("cache", "verify", "--cache", cache).exit_code == 1  # every record unindexed
    result = craftc("cache", "index", "--cache", cache)
    assert result.exit_code == 0, result.output
    assert read_index(index) == before
    victim = _record_of(cache, "spoon")
    _edit_answer(victim, raw_too=True)
    result = craftc("cache", "index", "--cache", cache)
    assert result.exit_code == 1  # an entry is never changed to fit an edited file
    assert read_index(index) == before


# --- item 6: a clean checkout verifies ---------------------------------------------------------


def test_cache_verify_ignores_runtime_caches_and_locks(
    clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    cache = clone_cache(tmp_path / "cache")
    (cache / "encoders").mkdir()
    (cache / "encoders" / "conse-classes.npz").write_bytes(b"runtime cache")
    (cache / "locks").mkdir(exist_ok=True)  # builds hold locks/use.lock
    (cache / "locks" / "build.lock").write_bytes(b"")
    result = craftc("cache", "verify", "--cache", cache)
    assert result.exit_code == 0, result.output
    assert "0 corrupt, 0 orphaned" in result.output


def test_the_committed_record_cache_verifies() -> None:
    """Every committed record is indexed, whole and consistent (what CI and a clone see)."""
    report = RecordCache(CACHE_DIR).verify()
    assert report.checked > 0
    assert (report.corrupt, report.orphaned, report.unindexed) == ([], [], [])


# --- item 7: exit codes where the README promises them ----------------------------------------


def test_a_corrupt_record_during_a_build_is_exit_2(
    clone_cache: Callable[[Path], Path], tmp_path: Path
) -> None:
    cache = clone_cache(tmp_path / "cache")
    victim = _record_of(cache, "bowl")
    victim.write_bytes(victim.read_bytes()[:-50])
    result = craftc(*replay_args(cache, tmp_path / "out"))
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert str(victim) in flat(result.output)


@pytest.mark.parametrize(
    ("code", "where"),
    [(errno.EROFS, "mkdtemp"), (errno.ENOSPC, "write"), (errno.ENOTEMPTY, "replace")],
    ids=["read-only-out", "full-out", "lost-a-race"],
)
def test_unwritable_out_is_exit_2(
    kb_a: FixtureKB, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, code: int, where: str
) -> None:
    import craft_e.compiler.emit as emit

    def boom(*args: object, **kwargs: object) -> None:
        raise OSError(code, errno.errorcode[code])

    if where == "mkdtemp":
        monkeypatch.setattr(emit.tempfile, "mkdtemp", boom)
    elif where == "write":
        monkeypatch.setattr(emit.Path, "write_bytes", boom)
    else:  # another build renamed its bundle into --out first
        monkeypatch.setattr(emit.os, "replace", boom)
    result = craftc(*replay_args(kb_a.cache, tmp_path / "out"))
    assert result.exit_code == 2, (result.output, result.exception)
    assert "cannot write the bundle" in flat(result.output)
    assert not (tmp_path / "out").exists()


def test_a_replay_build_from_a_missing_cache_names_the_cache(tmp_path: Path) -> None:
    result = craftc(*replay_args(tmp_path / "no-such-cache", tmp_path / "out"))
    assert result.exit_code == 2, (result.output, result.exception)
    assert "no such record cache folder (from --cache or CRAFT_CACHE)" in flat(result.output)
    assert not (tmp_path / "out").exists() and not (tmp_path / "no-such-cache").exists()


def test_out_at_a_mount_point_is_exit_2(kb_a: FixtureKB) -> None:
    result = craftc(*replay_args(kb_a.cache, Path("/proc")))
    assert result.exit_code == 2, result.output
    assert "mount point" in flat(result.output)


def test_pack_into_an_existing_folder_is_exit_2(kb_a: FixtureKB, tmp_path: Path) -> None:
    assert craftc("keygen", "--out", tmp_path / "keys").exit_code == 0
    folder = tmp_path / "existing"
    folder.mkdir()
    (folder / "mine.txt").write_text("mine")
    result = craftc("pack", kb_a.bundle, "--key", tmp_path / "keys" / "craft-signing.key", "-o", folder)
    assert result.exit_code == 2, (result.output, result.exception)
    assert "is a folder" in flat(result.output)
    assert [p.name for p in folder.iterdir()] == ["mine.txt"]


def test_a_path_with_markup_is_printed_literally_and_exits_1() -> None:
    result = craftc("validate", "a/[/x]")
    assert result.exit_code == 1, (result.output, result.exception)
    assert "a/[/x]" in flat(result.output)


# --- item 8: error text keeps its brackets ----------------------------------------------------


def test_error_text_keeps_brackets(kb_a: FixtureKB, tmp_path: Path) -> None:
    verbs = tmp_path / "verbs.txt"
    verbs.write_text("cut\nc[u]t!\n", encoding="utf-8")
    args = [a if a != KB_SMALL / "verbs.txt" else verbs for a in replay_args(kb_a.cache, tmp_path / "o")]
    result = craftc(*args)
    assert result.exit_code == 2
    assert "characters outside [a-z0-9 '-./&+]" in flat(result.output)
    assert "'c[u]t!'" in flat(result.output)


def test_craft_cli_prints_user_text_literally(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app as craft_app

    into = tmp_path / "[/x]" / "[bold]kb"
    result = CliRunner().invoke(craft_app, ["rollback", "--into", str(into)], env={"COLUMNS": "2000"})
    assert result.exit_code == 2, (result.output, result.exception)
    assert str(into) in flat(result.output)
