"""Reading a bundle folder safely: the manifest and every listed file, each checked against its
sha256 and size before use, then against each other (``content``). Shared by the loader
(``bundle``), packages (``package``), installs (``install``) and ``craftc pack``, so a bundle that
does not verify here is neither loaded, signed nor installed.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from pathlib import Path

from pydantic import ValidationError

from ...paths import artifacts_hint
from ...schemas.v1.bundle import (
    BUNDLE_FILES,
    MANIFEST_FILE,
    Manifest,
    content_hash,
    listed_files_ok,
)
from .errors import BundleError

__all__ = ["MAX_FILE_BYTES", "MAX_MANIFEST_BYTES", "SUPPORTED_SCHEMA_VERSIONS", "BundleError",
           "read_manifest", "read_regular_file", "verify_digests", "verify_files"]

SUPPORTED_SCHEMA_VERSIONS = (1,)
#: Ceilings checked *before* reading: a manifest is kilobytes, a bundle file megabytes. A link to
#: /dev/zero or a multi-GB file is refused by its size or type, never read until memory runs out.
MAX_MANIFEST_BYTES = 16 << 20
MAX_FILE_BYTES = 1 << 30


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def read_regular_file(path: Path, cap: int, expected: int | None = None) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``cap`` (or exactly ``expected``)
    bytes; a folder, FIFO, device, socket or oversized file is a ``BundleError`` before any read.

    ``O_NONBLOCK`` makes opening a FIFO return at once (a plain open would wait for a writer
    forever); the type and size come from ``fstat`` of the opened descriptor, so a file swapped
    between the check and the read cannot slip through. A folder opens too (``O_RDONLY`` on a
    directory succeeds on Linux and macOS), so it is told apart by its type, not by the open.
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise BundleError(
                f"{path}: is a folder, not a file; a bundle holds only regular files — rebuild "
                "or re-install it"
            )
        if not stat.S_ISREG(info.st_mode):
            raise BundleError(
                f"{path}: not a regular file (a device, FIFO or socket); a bundle holds only "
                "regular files — rebuild or re-install it"
            )
        if expected is not None and info.st_size != expected:
            raise BundleError(
                f"{path}: content does not match the manifest ({info.st_size} bytes, expected "
                f"{expected}); the file was modified or truncated — rebuild or re-install the bundle"
            )
        if info.st_size > cap:
            raise BundleError(
                f"{path}: {info.st_size} bytes, more than {cap}; not a bundle file — rebuild or "
                "re-install the bundle"
            )
        chunks: list[bytes] = []
        left = info.st_size
        with os.fdopen(os.dup(fd), "rb") as handle:
            while left > 0:
                # the whole rest at once: a regular file comes in one chunk, which ``join`` then
                # returns as it is (1 MB chunks made it copy every file once more: 0.13 s of a
                # 220 MB bundle's load)
                chunk = handle.read(left)
                if not chunk:
                    break
                chunks.append(chunk)
                left -= len(chunk)
        return b"".join(chunks)
    finally:
        os.close(fd)


def read_manifest(folder: Path) -> Manifest:
    path = folder / MANIFEST_FILE
    if not folder.is_dir():
        raise BundleError(f"{folder}: not a bundle folder (build one with `craftc build`)"
                          + ("" if folder.exists() else artifacts_hint(folder)))
    try:
        raw = json.loads(read_regular_file(path, MAX_MANIFEST_BYTES))
    except FileNotFoundError:
        raise BundleError(f"{path}: missing; this folder is not a CRAFT-E bundle") from None
    except PermissionError:
        raise BundleError(f"{path}: not readable by this user; fix the bundle's permissions") from None
    except (ValueError, RecursionError) as exc:
        raise BundleError(f"{path}: not valid JSON ({exc}); rebuild the bundle") from None
    if not isinstance(raw, dict):
        raise BundleError(
            f"{path}: not a JSON object (the document is {_json_kind(raw)}); a manifest is an "
            "object with schema_version, files, verbs, ... — rebuild the bundle"
        )
    version = raw.get("schema_version")
    if version not in SUPPORTED_SCHEMA_VERSIONS:
        raise BundleError(
            f"{path}: schema_version {version!r} is not supported by this runtime "
            f"(supports {SUPPORTED_SCHEMA_VERSIONS}); rebuild with a matching craftc"
        )
    try:
        return Manifest.model_validate(raw)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise BundleError(f"{path}: {'.'.join(map(str, first['loc']))}: {first['msg']}") from None


def _json_kind(value: object) -> str:
    """What a JSON document is, in words ("a list", "null"), for a message."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    return {list: "a list", str: "a string", int: "a number", float: "a number"}.get(
        type(value), type(value).__name__
    )


def verify_files(folder: Path, manifest: Manifest) -> dict[str, bytes]:
    """Every listed file's bytes, checked as ``verify_digests`` does and then against each other
    and the manifest (``content.read_content``: graph, E_aff, embeddings, open-world model, ...).

    ``craft install`` and ``unpack_package`` call this (``craftc pack`` the same checks, through
    ``bundle.bundle_from_files`` on the bytes it signs): hashes alone prove only
    that the files are the ones the manifest lists, and a bundle whose graph names a node that
    does not exist or whose E_aff is +7 must be refused before it is signed or installed, not
    when the robot grounds with it.
    """
    from .content import read_content  # content imports what a bundle's files need (numpy, ...)

    data = verify_digests(folder, manifest)
    read_content(folder, manifest, data)
    return data


def verify_digests(folder: Path, manifest: Manifest) -> dict[str, bytes]:
    """Read every listed file and check its size and sha256, and the content hash (no parsing:
    ``load_bundle`` parses once and checks the content itself)."""
    if not listed_files_ok(set(manifest.files)):
        raise BundleError(
            f"{folder / MANIFEST_FILE}: lists {sorted(manifest.files)}, expected {sorted(BUNDLE_FILES)}"
        )
    data: dict[str, bytes] = {}
    for name, digest in sorted(manifest.files.items()):
        path = folder / name
        if digest.bytes > MAX_FILE_BYTES:
            raise BundleError(
                f"{folder / MANIFEST_FILE}: {name} is declared as {digest.bytes} bytes, more than "
                f"a bundle file may be ({MAX_FILE_BYTES}); rebuild the bundle"
            )
        try:
            blob = read_regular_file(path, MAX_FILE_BYTES, expected=digest.bytes)
        except FileNotFoundError:
            raise BundleError(
                f"{path}: missing from the bundle; rebuild or re-install it"
            ) from None
        except PermissionError:
            raise BundleError(f"{path}: not readable by this user; fix the bundle's permissions") from None
        if len(blob) != digest.bytes or _sha256(blob) != digest.sha256:
            raise BundleError(
                f"{path}: content does not match the manifest (sha256 {_sha256(blob)[:16]}..., "
                f"expected {digest.sha256[:16]}...); the file was modified or truncated — rebuild "
                "or re-install the bundle"
            )
        data[name] = blob
    if content_hash(manifest) != manifest.content_sha256:
        raise BundleError(
            f"{folder / MANIFEST_FILE}: content_sha256 does not match the manifest (a field was "
            "edited after the build); rebuild or re-install the bundle"
        )
    return data


