"""File helpers that the compiler, the runtime and the evaluation all need, written once.

``read_json`` reads a user's JSON file with one wording of its errors (missing, a folder,
unreadable, not UTF-8 with the byte offset, not JSON with the line; ``read_text_file`` the same
for any text file); ``sha256_file`` identifies weights, dumps and label files by content (streamed: weights are
large); ``fsync_dir`` makes a rename durable (the directory entry reaches the disk, not only the
file); ``atomic_write_bytes`` writes a file whole or not at all; ``current_umask`` reads the process umask so staged folders get the permissions a plain
``mkdir`` would have given them (``mkdtemp`` creates them 0o700); ``held_flock`` holds an
advisory lock file (the record cache's index and use locks, ``craft install``'s lock);
``output_file_problem`` says why a path cannot be written as a file (both CLIs' and the benchmark
scripts' output options check it before any work).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a same-folder temp file + fsync + rename: a reader (or a
    crash) sees the old file or the whole new one, never a part. The file gets the permissions
    a plain ``open(path, "w")`` would give it (``mkstemp`` makes it 0o600)."""
    import tempfile

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~current_umask())
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def current_umask() -> int:
    """The process umask (reading it means setting it; it is put straight back)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def fsync_dir(folder: Path) -> None:
    """fsync a directory so a rename into it survives a crash; a no-op where unsupported."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def read_text_file(path: Path, what: str, error: type[Exception] = ValueError) -> str:
    """The UTF-8 text of ``path`` (a ``what``, e.g. "labels file"), or ``error`` naming the file
    and the problem: missing, a folder, unreadable (permissions), or not UTF-8 (with the byte
    offset, so the user can find it). Without this, each of these surfaced as a traceback
    (``IsADirectoryError``) or as a codec message that did not name the file."""
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{path}: {what} not found") from None
    except IsADirectoryError:
        raise error(f"{path}: is a folder; give the path of the {what} itself") from None
    except PermissionError:
        raise error(f"{path}: cannot read the {what} (permission denied); check its permissions") from None
    except OSError as exc:
        raise error(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise error(f"{path}: {what} is not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset "
                    f"{exc.start}); re-save it as UTF-8") from None


class _DuplicateKeyError(ValueError):
    """A JSON object names one key twice (``read_json(..., unique_keys=True)``)."""


def _unique_pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``object_pairs_hook`` that refuses a key given twice in one object."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKeyError(key)
        out[key] = value
    return out


def read_json(path: Path, what: str, error: type[Exception] = ValueError, *, unique_keys: bool = False) -> Any:
    """The parsed JSON of ``path`` (a ``what``, e.g. "labels file"); ``error`` (the caller's
    input-error type) names the file and the problem (see ``read_text_file``) and, for bad JSON,
    the line — no traceback for a typo.

    ``unique_keys``: a key given twice in one object is an error too. JSON parsers keep the last
    one, so in a labels file ``{"carry": [...], "carry": [...]}`` the first list would be lost
    without a word."""
    text = read_text_file(path, what, error)
    try:
        return json.loads(text, object_pairs_hook=_unique_pairs if unique_keys else None)
    except _DuplicateKeyError as exc:
        raise error(f"{path}: key {exc.args[0]!r} appears twice in one object (only the last would be read); "
                    "merge the two into one") from None
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not JSON ({exc.msg} at line {exc.lineno})") from None
    except (ValueError, RecursionError) as exc:  # an integer of > 4300 digits; nesting too deep
        raise error(f"{path}: not usable JSON ({exc})") from None


@contextlib.contextmanager
def held_flock(path: Path, *, shared: bool = False, busy: Callable[[], Exception] | None = None) -> Iterator[None]:
    """Hold ``flock`` on ``path`` (created, with its folder) for the block: exclusive, or shared.

    With ``busy``, a lock another process holds raises ``busy()`` at once instead of waiting.
    The kernel releases the lock when the process dies, so a crash never leaves it stuck.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        mode = fcntl.LOCK_SH if shared else fcntl.LOCK_EX
        try:
            fcntl.flock(fd, mode | (fcntl.LOCK_NB if busy is not None else 0))
        except BlockingIOError:
            if busy is None:
                raise
            raise busy() from None
        yield
    finally:
        os.close(fd)


def output_file_problem(path: Path, example_suffix: str = ".json") -> str | None:
    """Why ``path`` cannot be written as a file (None when it can): checked when the option is
    parsed, so a bad ``--json``/``--markdown``/``--plot`` fails before the work, not after it
    with half the outputs written. ``example_suffix``: the kind of file the option writes, for
    the example name offered when ``path`` is a folder."""
    if path.is_dir():
        return f"{path} is a folder; give a file path inside it, e.g. {path / ('out' + (path.suffix or example_suffix))}"
    if path.exists() and not path.is_file():
        return f"{path} exists and is not a regular file"
    return ancestor_problem(path)


def ancestor_problem(path: Path) -> str | None:
    """Why nothing can be created at ``path`` because an existing ancestor is a file (or None)."""
    for ancestor in path.absolute().parents:
        if ancestor.exists():
            return None if ancestor.is_dir() else f"{ancestor} is a file, so {path} cannot be created under it"
    return None
