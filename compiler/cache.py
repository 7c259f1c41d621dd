"""Content-addressed record cache: ``<root>/<source>/<sha256>.json``.

Writes go to a temporary file in the same folder and are renamed into place, so a reader (or a
second concurrent build) sees either no record or a whole one. Two builds writing the same key
write the same bytes, so the last rename wins harmlessly.

Integrity: a record's key covers its *request* only, so each source folder also keeps an index,
``<root>/<source>/SHA256SUMS`` (the format ``sha256sum -c`` reads), with the sha256 of every
record file's bytes — request, raw response and payload. ``put`` updates it (under a lock,
atomically, before the record is renamed into place, so a crash never leaves an unindexed
record); ``get`` and ``verify`` check it, so an answer edited after recording is refused.
Records stored before the index existed are indexed once with ``craftc cache index``, which
only adds entries for files not yet listed and never changes an existing entry. The embedding
cache keeps its own index binding each vector to its phrase (``EmbeddingIndex``).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from ..files import atomic_write_bytes, held_flock
from ..schemas.v1.records import Record

if TYPE_CHECKING:
    from .prompts import PromptTemplate


class CacheError(RuntimeError):
    """A record file is unreadable or does not match its key or its integrity index."""


INDEX_FILE = "SHA256SUMS"
EMBEDDING_INDEX_FILE = "INDEX.tsv"
_LOCK_FILE = ".index.lock"
#: Folders under the cache root that hold no records (embeddings, the runtime's encoder caches,
#: lock files, the state of batch jobs in flight), so ``verify`` never calls their files
#: orphaned records.
NON_RECORD_FOLDERS = frozenset({"embeddings", "encoders", "locks", "batches"})
#: No record is anywhere near this; a bigger file is refused before it is read.
MAX_RECORD_BYTES = 64 * 1024 * 1024


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _index_lock(folder: Path) -> contextlib.AbstractContextManager[None]:
    """Serialize index updates of one folder across threads and processes (flock)."""
    return held_flock(folder / _LOCK_FILE)


#: ``<root>/locks/use.lock``: builds and ``curate record`` hold it shared while they read and
#: write records; ``cache clean --yes`` holds it exclusively, so it never deletes a record a
#: running build has just stored (no bundle names it yet) or is about to read.
USE_LOCK = Path("locks") / "use.lock"


class CacheBusyError(CacheError):
    """``cache clean`` found the cache in use by a build or ``curate record``."""


@contextlib.contextmanager
def cache_in_use(root: Path) -> Iterator[None]:
    """Hold the cache's use lock shared (builds, ``curate record``) for the block; it waits only
    for a running clean, which is short.

    A cache that cannot hold a lock file (a read-only checkout) cannot be cleaned either, so the
    block then runs unlocked.
    """
    with contextlib.ExitStack() as held:
        with contextlib.suppress(OSError):
            held.enter_context(held_flock(root / USE_LOCK, shared=True))
        yield


def cache_for_cleaning(root: Path) -> contextlib.AbstractContextManager[None]:
    """Hold the cache's use lock exclusively, or raise CacheBusyError at once."""
    return held_flock(root / USE_LOCK, busy=lambda: CacheBusyError(
        f"{root}: a build or `craftc curate record` is using this cache; records it has just "
        "stored are not in any bundle yet. Run clean again when it has finished (nothing deleted)"))


def read_index(path: Path) -> dict[str, str]:
    """``SHA256SUMS`` as {file name: sha256}; a missing index is empty."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return {}
    except (OSError, UnicodeDecodeError) as exc:
        raise CacheError(f"{path}: unreadable integrity index ({exc})") from None
    out: dict[str, str] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        digest, sep, name = line.partition("  ")
        if not sep or len(digest) != 64 or not name:
            raise CacheError(f"{path}:{lineno}: not a `<sha256>  <file>` line")
        out[name] = digest
    return out


def _index_bytes(entries: dict[str, str]) -> bytes:
    return "".join(f"{d}  {n}\n" for n, d in sorted(entries.items())).encode()


def record_bytes(record: Record) -> bytes:
    """The committed spelling of a record: indented, sorted keys, trailing newline."""
    return (
        json.dumps(record.model_dump(mode="json"), indent=2, sort_keys=True, ensure_ascii=False)
        + "\n"
    ).encode()


@dataclass
class VerifyReport:
    """What ``craftc cache verify`` found."""

    checked: int = 0
    corrupt: list[tuple[Path, str]] = field(default_factory=list)
    orphaned: list[Path] = field(default_factory=list)
    unindexed: list[Path] = field(default_factory=list)  # records missing from SHA256SUMS
    embeddings_checked: int = 0
    embeddings_unindexed: list[Path] = field(default_factory=list)  # re-embedded on next use

    @property
    def ok(self) -> bool:
        return not self.corrupt and not self.orphaned and not self.unindexed


@dataclass
class StatsRow:
    """``craftc cache stats``: records and bytes of one source/provider/model/prompt version."""

    source: str
    provider: str
    model: str
    prompt: str
    version: str
    records: int = 0
    bytes: int = 0


class RecordCache:
    """The record store of one project (default ``artifacts/cache``)."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self._indexes: dict[str, tuple[tuple[int, int, int], dict[str, str]]] = {}

    def path_for(self, source: str, key: str) -> Path:
        return self.root / source / f"{key}.json"

    def get(self, source: str, key: str) -> Record | None:
        """The record for ``key`` or None; a corrupt file is an error, never a silent miss."""
        path = self.path_for(source, key)
        try:
            data = _read_capped(path)
        except FileNotFoundError:
            return None
        return self._parse(path, data, expected_key=key)

    def put(self, record: Record) -> Path:
        """Store ``record``: its index entry is written first, then the file renamed into place."""
        if record.request.key() != record.key:
            raise CacheError(f"record key {record.key} does not match its request hash")
        path = self.path_for(record.source, record.key)
        data = record_bytes(record)
        with _index_lock(path.parent):
            index_path = path.parent / INDEX_FILE
            entries = read_index(index_path)
            digest = sha256_hex(data)
            if entries.get(path.name) != digest:
                entries[path.name] = digest
                atomic_write_bytes(index_path, _index_bytes(entries))
            atomic_write_bytes(path, data)
        return path

    def index(self, source: str) -> dict[str, str]:
        """The integrity index of one source folder (cached while the file is unchanged)."""
        path = self.root / source / INDEX_FILE
        try:
            info = path.stat()
        except FileNotFoundError:
            return {}
        stamp = (info.st_mtime_ns, info.st_size, info.st_ino)
        cached = self._indexes.get(source)
        if cached is None or cached[0] != stamp:
            cached = (stamp, read_index(path))
            self._indexes[source] = cached
        return cached[1]

    def build_index(self, source: str) -> tuple[list[str], list[str], list[tuple[Path, str]]]:
        """Index records not yet listed (``craftc cache index``); never changes an entry.

        Returns (added names, pruned names of files that are gone, mismatches left as they are).
        Only a record that parses and re-hashes to its key is added.
        """
        folder = self.root / source
        added: list[str] = []
        mismatched: list[tuple[Path, str]] = []
        with _index_lock(folder):
            entries = read_index(folder / INDEX_FILE)
            present = {p.name for p in folder.glob("*.json")}
            pruned = sorted(set(entries) - present)
            for name in pruned:
                del entries[name]
            for path in sorted(folder.glob("*.json")):
                data = _read_capped(path)
                digest = sha256_hex(data)
                if path.name in entries:
                    if entries[path.name] != digest:
                        mismatched.append((path, "content differs from its SHA256SUMS entry"))
                    continue
                try:
                    self._parse(path, data, expected_key=path.stem, check_index=False)
                except CacheError as exc:
                    mismatched.append((path, str(exc)))
                    continue
                entries[path.name] = digest
                added.append(path.name)
            if added or pruned:
                atomic_write_bytes(folder / INDEX_FILE, _index_bytes(entries))
        return added, pruned, mismatched

    def remove(self, source: str, keys: Iterable[str]) -> list[str]:
        """Delete the records ``keys`` of ``source`` and drop their ``SHA256SUMS`` entries.

        Under the folder's index lock, files go first and the index is rewritten after, so a
        crash in between leaves entries without files (``craftc cache index`` prunes them),
        never a record without its entry. Returns the file names deleted.
        """
        folder = self.root / source
        removed: list[str] = []
        with _index_lock(folder):
            for key in sorted(set(keys)):
                path = self.path_for(source, key)
                try:
                    path.unlink()
                except FileNotFoundError:
                    continue
                removed.append(path.name)
            entries = read_index(folder / INDEX_FILE)
            kept = {n: d for n, d in entries.items() if n not in set(removed)}
            if kept != entries:
                atomic_write_bytes(folder / INDEX_FILE, _index_bytes(kept))
        return removed

    def iter_records(self, source: str) -> Iterator[tuple[Path, Record]]:
        """Every record of a source, in key order (deterministic)."""
        folder = self.root / source
        if not folder.is_dir():
            return
        for path in sorted(folder.glob("*.json")):
            yield path, self._parse(path, _read_capped(path), expected_key=path.stem)

    def sources(self) -> list[str]:
        if not self.root.is_dir():
            return []
        return sorted(
            p.name for p in self.root.iterdir() if p.is_dir() and p.name not in NON_RECORD_FOLDERS
        )

    def verify(self, referenced: set[str] | None = None) -> VerifyReport:
        """Re-hash every record; list corrupt ones and orphans (temp files, keys not referenced)."""
        report = VerifyReport()
        for source in self.sources():
            folder = self.root / source
            try:
                entries = self.index(source)
            except CacheError as exc:
                report.corrupt.append((folder / INDEX_FILE, str(exc)))
                entries = {}
            for path in sorted(folder.iterdir()):
                if path.name in (INDEX_FILE, _LOCK_FILE):
                    continue
                if path.name.startswith(".") and path.name.endswith(".tmp"):
                    report.orphaned.append(path)
                    continue
                if path.suffix != ".json":
                    report.orphaned.append(path)
                    continue
                report.checked += 1
                try:
                    record = self._parse(path, _read_capped(path), expected_key=path.stem)
                except CacheError as exc:
                    report.corrupt.append((path, str(exc)))
                    continue
                try:
                    _check_llm_payload(record)
                except CacheError as exc:
                    report.corrupt.append((path, f"{path}: {exc}"))
                    continue
                if path.name not in entries:
                    report.unindexed.append(path)
                    continue
                if referenced is not None and path.stem not in referenced:
                    report.orphaned.append(path)
        verify_embeddings(self.root, report)
        return report

    def stats(self) -> dict[str, dict[str, int]]:
        """Per source: record count, bytes, records per provider:prompt and per
        provider/model/prompt@version."""
        out: dict[str, dict[str, int]] = {}
        for source in self.sources():
            counter: Counter[str] = Counter()
            for path in (self.root / source).glob("*.json"):
                counter["records"] += 1
                counter["bytes"] += path.stat().st_size
                try:
                    head = json.loads(path.read_bytes())["request"]
                    counter[f"{head['provider']}:{head['prompt']}"] += 1
                    counter[f"{head['provider']}/{head['model']}/{head['prompt']}"] += 1
                except (ValueError, KeyError, TypeError):
                    counter["unreadable"] += 1
            out[source] = dict(sorted(counter.items()))
        return out

    def stats_rows(self) -> list[StatsRow]:
        """One row per source, provider, model, prompt id and prompt version (records and
        bytes), sorted; files that are not readable records share one row per source."""
        rows: dict[tuple[str, str, str, str, str], StatsRow] = {}
        for source in self.sources():
            for path in sorted((self.root / source).glob("*.json")):
                size = path.stat().st_size
                try:
                    head = json.loads(path.read_bytes())["request"]
                    prompt_id, _, version = str(head["prompt"]).partition("@")
                    group = (source, str(head["provider"]), str(head["model"]), prompt_id, version)
                except (ValueError, KeyError, TypeError):
                    group = (source, "?", "?", "unreadable", "")
                row = rows.setdefault(group, StatsRow(*group))
                row.records += 1
                row.bytes += size
        return [rows[k] for k in sorted(rows)]

    def _parse(
        self, path: Path, data: bytes, expected_key: str, *, check_index: bool = True
    ) -> Record:
        try:
            record = Record.model_validate_json(data)
        except ValidationError as exc:
            first = exc.errors()[0]
            where = ".".join(str(p) for p in first["loc"])
            raise CacheError(f"{path}: not a valid v1 record ({where}: {first['msg']})") from exc
        if record.key != expected_key:
            raise CacheError(f"{path}: file name does not match the record key {record.key}")
        actual = record.request.key()
        if actual != record.key:
            raise CacheError(
                f"{path}: request hashes to {actual}, not {record.key} (edited after recording?)"
            )
        if check_index:
            want = self.index(path.parent.name).get(path.name)
            if want is not None and sha256_hex(data) != want:
                raise CacheError(
                    f"{path}: content does not match its entry in {path.parent / INDEX_FILE} "
                    "(the answer or the note was edited after recording); restore it with "
                    "`git checkout` or record the prompt again"
                )
        return record


def extract_json(text: str) -> Any:
    """Parse the model's answer as JSON, tolerating a fenced code block around it."""
    stripped = text.strip()
    if stripped.startswith("```"):
        stripped = stripped.split("\n", 1)[1] if "\n" in stripped else ""
        stripped = stripped.rsplit("```", 1)[0]
    return json.loads(stripped)


def check_payload(record: Record, template: PromptTemplate) -> Record:
    """A stored record is used only if its payload is what its raw response says.

    The payload is what builds read; the raw response is what the model (or curator) wrote.
    A payload edited by hand afterwards no longer equals the validated parse of the raw
    response, and is refused (``CacheError``) instead of silently entering a bundle.
    """
    where = f"record {record.key} ({record.request.prompt}, subject={record.request.subject!r})"
    try:
        parsed = extract_json(record.raw_response)
    except ValueError:
        raise CacheError(f"{where}: raw_response is not JSON; the record was edited") from None
    if parsed == record.payload:
        return record
    try:
        validated = template.payload_model.model_validate(parsed).model_dump(mode="json")
    except ValidationError:
        validated = None
    if validated != record.payload:
        raise CacheError(
            f"{where}: payload differs from the validated parse of raw_response (the answer "
            "was edited after recording); restore the record file or record the prompt again"
        )
    return record


def _check_llm_payload(record: Record) -> None:
    """``verify`` also checks an LLM record's payload against its raw response."""
    if record.source != "llm":
        return
    from .prompts import PromptError, load_prompt

    prompt_id, _, version = record.request.prompt.partition("@")
    try:
        template = load_prompt(prompt_id, version)
    except (PromptError, OSError, ValueError):
        return  # a prompt this checkout does not have: the index still covers the record
    check_payload(record, template)


def _read_capped(path: Path, cap: int = MAX_RECORD_BYTES) -> bytes:
    """A regular file's bytes, refusing FIFOs, devices and files over ``cap`` before reading."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        info = os.fstat(fd)
        if not _is_regular(info.st_mode):
            raise CacheError(f"{path}: not a regular file")
        if info.st_size > cap:
            raise CacheError(f"{path}: {info.st_size} bytes, more than a record can be ({cap})")
        with os.fdopen(os.dup(fd), "rb") as handle:
            return handle.read(cap + 1)
    finally:
        os.close(fd)


def _is_regular(mode: int) -> bool:
    import stat

    return stat.S_ISREG(mode)


# --------------------------------------------------------------------------- embeddings


def embedding_digest(phrase: str, npy: bytes) -> str:
    """What the embedding index stores: sha256 over the phrase, a NUL, and the .npy bytes."""
    return sha256_hex(phrase.encode() + b"\0" + npy)


class EmbeddingIndex:
    """``<folder>/INDEX.tsv``: ``<file>\t<digest of phrase + vector>\t<phrase as JSON>`` lines.

    The file name of an embedding is the sha256 of its phrase, which says nothing about the
    vector inside; the index binds both, so two swapped files (knife <-> spoon) are detected.
    """

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.path = folder / EMBEDDING_INDEX_FILE

    def read(self) -> dict[str, tuple[str, str]]:
        """{file name: (digest, phrase)}; a missing index is empty."""
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return {}
        except (OSError, UnicodeDecodeError) as exc:
            raise CacheError(f"{self.path}: unreadable embedding index ({exc})") from None
        out: dict[str, tuple[str, str]] = {}
        for lineno, line in enumerate(text.splitlines(), start=1):
            parts = line.split("\t")
            try:
                name, digest, phrase = parts[0], parts[1], json.loads(parts[2])
            except (IndexError, ValueError):
                raise CacheError(f"{self.path}:{lineno}: not a `<file>\\t<sha256>\\t<phrase>` line") from None
            if not isinstance(phrase, str) or len(parts) != 3:
                raise CacheError(f"{self.path}:{lineno}: not a `<file>\\t<sha256>\\t<phrase>` line")
            out[name] = (digest, phrase)
        return out

    def add(self, items: dict[str, tuple[str, str]]) -> None:
        """Add or replace entries (under the folder's lock, atomically)."""
        if not items:
            return
        with _index_lock(self.folder):
            entries = self.read()
            entries.update(items)
            data = "".join(
                f"{n}\t{d}\t{json.dumps(p, ensure_ascii=False)}\n"
                for n, (d, p) in sorted(entries.items())
            )
            atomic_write_bytes(self.path, data.encode())

    def check(self, path: Path, phrase: str, data: bytes, entry: tuple[str, str] | None) -> bool:
        """True when ``data`` is ``phrase``'s indexed vector; False when unindexed (re-embed).

        A file whose entry names another phrase or another vector is an error: it was replaced
        or edited (e.g. two files swapped), and a build must not use it.
        """
        if entry is None:
            return False
        digest, indexed_phrase = entry
        if indexed_phrase != phrase or embedding_digest(phrase, data) != digest:
            raise CacheError(
                f"{path}: this embedding does not belong to {phrase!r} according to "
                f"{self.path} (the file was replaced, swapped or edited); delete it to re-embed"
            )
        return True


def verify_embeddings(root: Path, report: VerifyReport) -> None:
    """Check every cached embedding against its folder's index (``craftc cache verify``)."""
    base = root / "embeddings"
    if not base.is_dir():
        return
    for folder in sorted(p for p in base.iterdir() if p.is_dir()):
        index = EmbeddingIndex(folder)
        try:
            entries = index.read()
        except CacheError as exc:
            report.corrupt.append((index.path, str(exc)))
            continue
        for path in sorted(folder.iterdir()):
            if path.name in (EMBEDDING_INDEX_FILE, _LOCK_FILE):
                continue
            if path.suffix != ".npy" or path.name.startswith("."):
                report.orphaned.append(path)
                continue
            report.embeddings_checked += 1
            entry = entries.get(path.name)
            if entry is None:
                report.embeddings_unindexed.append(path)
                continue
            if sha256_hex(entry[1].encode()) + ".npy" != path.name:
                report.corrupt.append(
                    (path, f"{path}: its index entry names {entry[1]!r}, whose file this is not")
                )
                continue
            try:
                index.check(path, entry[1], _read_capped(path), entry)
            except (CacheError, OSError) as exc:
                report.corrupt.append((path, str(exc)))
