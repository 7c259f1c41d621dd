"""Content-addressed record cache: ``<root>/<source>/<sha256>.json``.

Writes go to a temporary file in the same folder and are renamed into place, so a reader (or a
second concurrent build) sees either no record or a whole one. Two builds writing the same key
write the same bytes, so the last rename wins harmlessly.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from pydantic import ValidationError

from craft_e.schemas.v1.records import Record


class CacheError(RuntimeError):
    """A record file is unreadable or does not match its key."""


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a same-folder temp file + fsync + rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


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

    @property
    def ok(self) -> bool:
        return not self.corrupt and not self.orphaned


class RecordCache:
    """The record store of one project (default ``artifacts/cache``)."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def path_for(self, source: str, key: str) -> Path:
        return self.root / source / f"{key}.json"

    def get(self, source: str, key: str) -> Record | None:
        """The record for ``key`` or None; a corrupt file is an error, never a silent miss."""
        path = self.path_for(source, key)
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            return None
        return self._parse(path, data, expected_key=key)

    def put(self, record: Record) -> Path:
        if record.request.key() != record.key:
            raise CacheError(f"record key {record.key} does not match its request hash")
        path = self.path_for(record.source, record.key)
        atomic_write_bytes(path, record_bytes(record))
        return path

    def iter_records(self, source: str) -> Iterator[tuple[Path, Record]]:
        """Every record of a source, in key order (deterministic)."""
        folder = self.root / source
        if not folder.is_dir():
            return
        for path in sorted(folder.glob("*.json")):
            yield path, self._parse(path, path.read_bytes(), expected_key=path.stem)

    def sources(self) -> list[str]:
        if not self.root.is_dir():
            return []
        return sorted(p.name for p in self.root.iterdir() if p.is_dir() and p.name != "embeddings")

    def verify(self, referenced: set[str] | None = None) -> VerifyReport:
        """Re-hash every record; list corrupt ones and orphans (temp files, keys not referenced)."""
        report = VerifyReport()
        for source in self.sources():
            folder = self.root / source
            for path in sorted(folder.iterdir()):
                if path.name.startswith(".") and path.name.endswith(".tmp"):
                    report.orphaned.append(path)
                    continue
                if path.suffix != ".json":
                    report.orphaned.append(path)
                    continue
                report.checked += 1
                try:
                    self._parse(path, path.read_bytes(), expected_key=path.stem)
                except CacheError as exc:
                    report.corrupt.append((path, str(exc)))
                    continue
                if referenced is not None and path.stem not in referenced:
                    report.orphaned.append(path)
        return report

    def stats(self) -> dict[str, dict[str, int]]:
        """Per source: record count, bytes, and records per provider/prompt."""
        out: dict[str, dict[str, int]] = {}
        for source in self.sources():
            counter: Counter[str] = Counter()
            for path in (self.root / source).glob("*.json"):
                counter["records"] += 1
                counter["bytes"] += path.stat().st_size
                try:
                    head = json.loads(path.read_bytes())["request"]
                    counter[f"{head['provider']}:{head['prompt']}"] += 1
                except (ValueError, KeyError, TypeError):
                    counter["unreadable"] += 1
            out[source] = dict(sorted(counter.items()))
        return out

    @staticmethod
    def _parse(path: Path, data: bytes, expected_key: str) -> Record:
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
        return record
