"""File helpers that the compiler, the runtime and the evaluation all need, written once.

``sha256_file`` identifies weights, dumps and label files by content (streamed: weights are
large); ``fsync_dir`` makes a rename durable (the directory entry reaches the disk, not only the
file); ``current_umask`` reads the process umask so staged folders get the permissions a plain
``mkdir`` would have given them (``mkdtemp`` creates them 0o700).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from pathlib import Path


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


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
