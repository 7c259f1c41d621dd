"""Signed single-file bundles (``kb.craft``): verify before use, extract defensively.

A robot receives a bundle as one file over an untrusted path (USB stick, fleet sync, scp). The
runtime must be able to tell, before writing a single byte to disk, that the file was made by a
key it trusts and that it holds exactly the bundle the signer meant. Hence the container:

.. code-block:: text

    offset 0   8 bytes   magic b"CRAFTPK1"  (format version 1)
    offset 8   4 bytes   N, big-endian uint32, 1 <= N <= 64 KiB
    offset 12  N bytes   header: canonical JSON (sorted keys, no spaces, UTF-8)
                           {"format": "craft-package/1",
                            "statement": {"type": "craft-package/1", "kb_name", "kb_version",
                                          "content_sha256", "manifest_sha256",
                                          "payload_sha256", "payload_bytes", "compression"},
                            "signature": {"alg": "ed25519", "key_id", "value"}}
    offset 12+N          payload: a ustar archive (gzip-compressed if compression == "gzip")
                           member 1: manifest.json; then the manifest's files; optionally
                           build_info.json. Flat names, regular files only.

The Ed25519 signature covers the canonical JSON of ``statement`` (``key_id`` = first 16 hex of
sha256 of the raw 32-byte public key). ``payload_sha256``/``payload_bytes`` bind the whole
archive, so :func:`verify_package` authenticates every payload byte by hashing the file — without
parsing any archive structure — and only then reads the first member (``manifest.json``, checked
against the signed ``manifest_sha256``). :func:`unpack_package` then extracts member by member
with an allow-list of names, exact sizes from the manifest, and caps on member count and
decompressed bytes (defence in depth should a trusted signer ever ship a hostile archive), into
a private staging folder that is renamed into place only after every file verified.

Every failure is a :class:`PackageError` (a :class:`BundleError`) naming the file, the reason and
the fix. The runtime imports neither the compiler, httpx nor rdflib.
"""

from __future__ import annotations

import base64
import binascii
import contextlib
import gzip
import hashlib
import json
import os
import shutil
import stat
import struct
import tarfile
import tempfile
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ...files import current_umask, fsync_dir
from ...schemas.v1.bundle import (
    BUILD_INFO_FILE,
    BUNDLE_FILES,
    MANIFEST_FILE,
    Manifest,
    content_hash,
    listed_files_ok,
)
from ...schemas.v1.records import canonical_json
from .verify import BundleError, read_manifest, verify_files

PACKAGE_MAGIC = b"CRAFTPK1"
PACKAGE_FORMAT = "craft-package/1"
PACKAGE_SUFFIX = ".craft"
_PREFIX = struct.Struct(">8sI")
_CHUNK = 1 << 16

#: What a caller may pass as a trusted key: raw 32 bytes, hex or base64 text, or a .pub file.
TrustedKey = bytes | str | os.PathLike[str]


class PackageError(BundleError):
    """A packed bundle is unsigned, untrusted, damaged or unsafe; the message says which and the fix."""


class DestinationError(PackageError):
    """The package is fine but the destination cannot be written (disk full, permissions)."""


class TrustedKeyError(PackageError):
    """A trusted key given to check a package is unusable (no such file, a private key, not a
    key at all): bad input (``craft install`` exit 2), not a package that failed its check."""


@dataclass(frozen=True)
class Limits:
    """Ceilings on what unpacking may consume; they stop decompression bombs and member floods.

    The defaults leave room for bundles far larger than the shipped vocabularies (a few MiB).
    The effective cap on decompressed bytes is also tightened to what the signed manifest
    declares, so an archive cannot expand beyond the files it claims to hold.
    """

    max_header_bytes: int = 64 * 1024
    max_members: int = 16
    max_member_bytes: int = 1 << 30
    max_total_bytes: int = 2 << 30
    max_manifest_bytes: int = 16 << 20
    max_build_info_bytes: int = 1 << 20


DEFAULT_LIMITS = Limits()


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class PackageStatement(_Frozen):
    """What the signer vouches for. Its canonical JSON is the signed message."""

    type: Literal["craft-package/1"] = "craft-package/1"
    kb_name: str = Field(pattern=r"^[a-z0-9][a-z0-9._-]*$")
    kb_version: str = Field(pattern=r"^\d+\.\d+\.\d+$")
    content_sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    manifest_sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    payload_sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    payload_bytes: int = Field(ge=0)
    compression: Literal["gzip", "none"]

    def message(self) -> bytes:
        """The exact bytes signed: canonical JSON of the statement."""
        return canonical_json(self.model_dump(mode="json")).encode()


class PackageSignature(_Frozen):
    alg: Literal["ed25519"] = "ed25519"
    key_id: str = Field(pattern=r"^[0-9a-f]{16}$")
    value: str = Field(pattern=r"^[0-9a-f]{128}$", description="hex of the 64-byte signature")


class PackageHeader(_Frozen):
    format: Literal["craft-package/1"] = "craft-package/1"
    statement: PackageStatement
    signature: PackageSignature | None = None

    def to_bytes(self) -> bytes:
        return canonical_json(self.model_dump(mode="json", exclude_none=True)).encode()


@dataclass(frozen=True)
class VerifiedPackage:
    """A package whose signature, payload hash and manifest checked out."""

    path: Path
    statement: PackageStatement
    key_id: str
    manifest: Manifest
    manifest_bytes: bytes
    payload_offset: int


# --------------------------------------------------------------------------- keys


def key_id(public_key: bytes) -> str:
    """Short, stable name of a public key: first 16 hex of sha256 of its 32 raw bytes."""
    return hashlib.sha256(public_key).hexdigest()[:16]


def _decode_key_text(text: str) -> bytes | None:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    if len(lines) != 1:
        return None
    token = lines[0]
    if len(token) == 64:
        try:
            return bytes.fromhex(token)
        except ValueError:
            pass
    try:
        raw = base64.b64decode(token, validate=True)
    except (binascii.Error, ValueError):
        return None
    return raw if len(raw) == 32 else None


def _public_key_file(path: Path) -> bytes | None:
    """The key in the public key file ``path``; None when no such file (the value may be a key
    spelled out). A folder, an unreadable file, a private key or any other file is an error that
    says which: each has its own fix."""
    try:
        if path.is_dir():
            raise TrustedKeyError(f"{path}: is a folder; pass the craft-signing.pub file in it "
                                  "(written by `craftc keygen`)")
        if not path.is_file():
            return None
        data = path.read_bytes()[:64 * 1024]
    except OSError as exc:
        raise TrustedKeyError(
            f"{path}: cannot read the trusted key ({exc.strerror or exc}); check the file"
        ) from None
    text = data.decode("ascii", errors="replace")
    raw = _decode_key_text(text)
    if raw is not None:
        return raw
    if any(line.strip().startswith("seed:") for line in text.splitlines()):
        raise TrustedKeyError(
            f"{path}: is a private signing key (craft-signing.key); pass its public half, "
            "craft-signing.pub, written beside it by `craftc keygen` (and keep the private key "
            "off robots)"
        )
    raise TrustedKeyError(
        f"{path}: not an Ed25519 public key file (expected one line of 64 hex characters, "
        "as `craftc keygen` writes craft-signing.pub); pass the signer's craft-signing.pub"
    )


def parse_public_key(value: TrustedKey) -> bytes:
    """The raw 32-byte Ed25519 public key from any accepted spelling.

    Accepts raw bytes, hex (64 chars) or base64 text, or the path of a ``craft-signing.pub``
    file, so both the CLI (a file) and embedding code (a constant) can name keys naturally.
    """
    if isinstance(value, bytes) and len(value) == 32:
        return value
    text: str | None = None
    if isinstance(value, bytes):
        try:
            text = value.decode("ascii")
        except UnicodeDecodeError:
            text = None
    elif isinstance(value, str):
        text = value
    if text is not None:
        raw = _decode_key_text(text)
        if raw is not None:
            return raw
    if isinstance(value, str | os.PathLike):
        raw = _public_key_file(Path(value))
        if raw is not None:
            return raw
    looks_like_path = isinstance(value, os.PathLike) or (
        isinstance(value, str) and ("/" in value or value.endswith(".pub")))
    if looks_like_path and not Path(value).exists():  # type: ignore[arg-type]
        raise TrustedKeyError(f"trusted key {str(value)[:200]}: no such file; pass the craft-signing.pub "
                              "written by `craftc keygen` (or its 64 hex characters)")
    shown = repr(value)[:40]
    raise TrustedKeyError(
        f"trusted key {shown}: not an Ed25519 public key (expected 32 raw bytes, 64 hex "
        "characters, base64, or a craft-signing.pub file written by `craftc keygen`)"
    )


def _trusted_table(trusted_keys: Sequence[TrustedKey] | None) -> dict[str, bytes]:
    if not trusted_keys:
        raise TrustedKeyError(
            "no trusted keys given: a packed bundle is only used when its signer is trusted; "
            "pass the signer's craft-signing.pub (--trusted-key, or trusted_keys=[...])"
        )
    if isinstance(trusted_keys, str | bytes):
        trusted_keys = [trusted_keys]
    return {key_id(raw): raw for raw in map(parse_public_key, trusted_keys)}


# --------------------------------------------------------------------------- reading


def _fail(path: Path, reason: str, fix: str) -> PackageError:
    return PackageError(f"{path}: {reason}; {fix}")


_REPACK = "re-copy the file from the build machine, or re-pack it with `craftc pack`"


def _strict_object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"duplicate key {key!r}")
        out[key] = value
    return out


def _reject_constant(name: str) -> Any:
    raise ValueError(f"non-standard JSON constant {name}")


def _read_prefix(path: Path, handle: IO[bytes], limits: Limits) -> tuple[PackageHeader, int]:
    head = handle.read(_PREFIX.size)
    if len(head) < _PREFIX.size or not head.startswith(PACKAGE_MAGIC):
        if head[:2] == b"\x1f\x8b" or head[:5] == b"ustar" or _looks_like_tar(handle):
            raise _fail(
                path,
                "an unsigned archive, not a CRAFT-E package",
                "sign it with `craftc pack BUNDLE --key craft-signing.key -o kb.craft`",
            )
        raise _fail(
            path,
            f"not a CRAFT-E package (starts with {head[:8]!r}, expected {PACKAGE_MAGIC!r})",
            "pass a .craft file written by `craftc pack`",
        )
    _, length = _PREFIX.unpack(head)
    if not 0 < length <= limits.max_header_bytes:
        raise _fail(
            path,
            f"header length {length} is outside 1..{limits.max_header_bytes}",
            f"the file is damaged or not a package; {_REPACK}",
        )
    raw = handle.read(length)
    if len(raw) != length:
        raise _fail(path, "truncated inside the header", _REPACK)
    try:
        value = json.loads(
            raw.decode("utf-8"), object_pairs_hook=_strict_object, parse_constant=_reject_constant
        )
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise _fail(path, f"header is not valid JSON ({exc})", _REPACK) from None
    if not isinstance(value, dict):
        raise _fail(path, "header is not a JSON object", _REPACK)
    if "signature" not in value or value["signature"] is None:
        raise _fail(
            path,
            "unsigned package (the header carries no signature)",
            "re-pack it with `craftc pack --key craft-signing.key`; the runtime never loads "
            "unsigned bundles",
        )
    try:
        header = PackageHeader.model_validate(value)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(map(str, first["loc"]))
        raise _fail(path, f"header field {where}: {first['msg']}", _REPACK) from None
    if header.to_bytes() != raw:
        raise _fail(path, "header is not in canonical form (it was edited)", _REPACK)
    return header, _PREFIX.size + length


def _looks_like_tar(handle: IO[bytes]) -> bool:
    try:
        handle.seek(257)
        return handle.read(5) == b"ustar"
    except OSError:
        return False


def _check_signature(path: Path, header: PackageHeader, trusted: dict[str, bytes]) -> str:
    from nacl.exceptions import BadSignatureError
    from nacl.signing import VerifyKey

    sig = header.signature
    assert sig is not None  # checked while reading
    if sig.key_id not in trusted:
        known = ", ".join(sorted(trusted))
        raise _fail(
            path,
            f"signed by key {sig.key_id}, which is not trusted (trusted: {known})",
            "pass the signer's craft-signing.pub with --trusted-key, or re-pack with a key this "
            "robot trusts",
        )
    try:
        VerifyKey(trusted[sig.key_id]).verify(header.statement.message(), bytes.fromhex(sig.value))
    except BadSignatureError:
        raise _fail(
            path,
            f"signature does not verify with key {sig.key_id} (the header was modified)",
            _REPACK,
        ) from None
    return sig.key_id


class _Slice:
    """Reads at most ``length`` bytes from ``handle`` and hashes what it returns.

    Extraction re-hashes the payload as it streams it, so a file swapped or modified after
    :func:`verify_package` ran still fails before anything is renamed into place.
    """

    def __init__(self, handle: IO[bytes], length: int) -> None:
        self.handle = handle
        self.left = length
        self.digest = hashlib.sha256()

    def read(self, size: int = -1) -> bytes:
        if size is None or size < 0 or size > self.left:
            size = self.left
        data = self.handle.read(size)
        self.left -= len(data)
        self.digest.update(data)
        return data

    def seek(self, offset: int, whence: int = 0) -> int:
        """Streams only: gzip never rewinds during a single forward read."""
        raise OSError("the package payload is read as a stream and cannot seek")

    def drain(self) -> None:
        while self.read(_CHUNK):
            pass


class _Capped:
    """A reader that raises once more than ``cap`` bytes came out (decompression-bomb guard)."""

    def __init__(self, inner: Any, cap: int, path: Path) -> None:
        self.inner = inner
        self.cap = cap
        self.seen = 0
        self.path = path

    def read(self, size: int = -1) -> bytes:
        if size is None or size < 0:
            size = self.cap - self.seen + 1
        data: bytes = self.inner.read(min(size, self.cap - self.seen + 1))
        self.seen += len(data)
        if self.seen > self.cap:
            raise _fail(
                self.path,
                f"archive expands beyond {self.cap} bytes (more than its manifest declares)",
                f"refusing a possible decompression bomb; {_REPACK}",
            )
        return data


def _archive_reader(
    path: Path, handle: IO[bytes], statement: PackageStatement, offset: int, cap: int
) -> tuple[_Slice, _Capped]:
    handle.seek(offset)
    raw = _Slice(handle, statement.payload_bytes)
    inner: Any = raw
    if statement.compression == "gzip":
        inner = gzip.GzipFile(fileobj=raw, mode="rb")
    return raw, _Capped(inner, cap, path)


_ARCHIVE_ERRORS = (tarfile.TarError, EOFError, zlib.error, OSError, ValueError, struct.error)


def _member_problem(member: tarfile.TarInfo, allowed: set[str]) -> str | None:
    name = member.name
    if name.startswith("/") or name.startswith("\\") or (len(name) > 1 and name[1] == ":"):
        return f"member {name!r} has an absolute path"
    parts = name.replace("\\", "/").split("/")
    if ".." in parts:
        return f"member {name!r} escapes the bundle folder (path traversal)"
    if member.issym() or member.islnk():
        return f"member {name!r} is a {'symlink' if member.issym() else 'hardlink'} to {member.linkname!r}"
    if member.ischr() or member.isblk() or member.isfifo():
        return f"member {name!r} is a device or FIFO"
    if member.isdir():
        return f"member {name!r} is a directory"
    if member.type not in (tarfile.REGTYPE, tarfile.AREGTYPE):
        return f"member {name!r} has unsupported type {member.type!r}"
    if name not in allowed:
        return f"unexpected member {name!r} (a bundle holds only {', '.join(sorted(allowed))})"
    return None


def _read_member(
    path: Path, archive: tarfile.TarFile, member: tarfile.TarInfo, limit: int
) -> Iterator[bytes]:
    if member.size > limit:
        raise _fail(path, f"member {member.name!r} is {member.size} bytes (limit {limit})", _REPACK)
    source = archive.extractfile(member)
    if source is None:  # pragma: no cover - regular files always have data
        raise _fail(path, f"member {member.name!r} has no data", _REPACK)
    left = member.size
    while left:
        chunk = source.read(min(_CHUNK, left))
        if not chunk:
            raise _fail(path, f"member {member.name!r} is truncated", _REPACK)
        left -= len(chunk)
        yield chunk


def _first_member(
    path: Path, handle: IO[bytes], statement: PackageStatement, offset: int, limits: Limits
) -> bytes:
    """Read only ``manifest.json`` (the first member) into memory."""
    cap = limits.max_manifest_bytes + 4 * tarfile.RECORDSIZE  # tarfile reads ahead by records
    _, reader = _archive_reader(path, handle, statement, offset, cap)
    try:
        with tarfile.open(fileobj=reader, mode="r|") as archive:  # type: ignore[call-overload]
            member = archive.next()
            if member is None:
                raise _fail(path, "the archive is empty", _REPACK)
            problem = _member_problem(member, {MANIFEST_FILE})
            if problem is not None or member.name != MANIFEST_FILE:
                raise _fail(
                    path,
                    f"the first member must be {MANIFEST_FILE} ({problem or member.name!r})",
                    _REPACK,
                )
            return b"".join(_read_member(path, archive, member, limits.max_manifest_bytes))
    except _ARCHIVE_ERRORS as exc:
        raise _fail(path, f"archive is unreadable ({type(exc).__name__}: {exc})", _REPACK) from None


def _parse_manifest(path: Path, data: bytes, statement: PackageStatement) -> Manifest:
    if hashlib.sha256(data).hexdigest() != statement.manifest_sha256:
        raise _fail(path, f"{MANIFEST_FILE} does not match the signed manifest_sha256", _REPACK)
    try:
        manifest = Manifest.model_validate_json(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise _fail(
            path,
            f"{MANIFEST_FILE}: {'.'.join(map(str, first['loc']))}: {first['msg']}",
            "pack it with a craftc that matches this runtime",
        ) from None
    if (manifest.kb_name, manifest.kb_version, manifest.content_sha256) != (
        statement.kb_name,
        statement.kb_version,
        statement.content_sha256,
    ):
        raise _fail(path, f"{MANIFEST_FILE} disagrees with the signed statement", _REPACK)
    if not listed_files_ok(set(manifest.files)):
        raise _fail(
            path,
            f"{MANIFEST_FILE} lists {sorted(manifest.files)}, expected {sorted(BUNDLE_FILES)}",
            _REPACK,
        )
    if content_hash(manifest) != manifest.content_sha256:
        raise _fail(path, f"{MANIFEST_FILE}: content_sha256 does not match the manifest", _REPACK)
    return manifest


@contextlib.contextmanager
def _open_package(path: Path) -> Iterator[tuple[IO[bytes], int]]:
    # O_NONBLOCK: opening a FIFO must not wait for a writer; the type is checked on the opened
    # descriptor right after, and a regular file reads the same with or without the flag.
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        try:
            handle = os.fdopen(fd, "rb")
        except BaseException:
            os.close(fd)
            raise
    except FileNotFoundError:
        raise _fail(path, "no such file", "check the path of the .craft file") from None
    except IsADirectoryError:
        raise _fail(
            path,
            "is a folder, not a packed bundle",
            "pack it with `craftc pack` first (a folder is loaded as is, without trusted_keys)",
        ) from None
    except OSError as exc:
        raise _fail(path, f"cannot be opened ({exc.strerror})", "check its permissions") from None
    with handle:
        info = os.fstat(handle.fileno())
        if not stat.S_ISREG(info.st_mode):
            raise _fail(
                path, "is not a regular file", "pass the .craft file written by craftc pack"
            )
        yield handle, info.st_size


def _verify_open(
    path: Path,
    handle: IO[bytes],
    size: int,
    trusted: dict[str, bytes],
    limits: Limits,
) -> VerifiedPackage:
    header, offset = _read_prefix(path, handle, limits)
    signer = _check_signature(path, header, trusted)
    statement = header.statement
    actual = size - offset
    if actual < statement.payload_bytes:
        raise _fail(
            path,
            f"truncated: payload has {actual} of {statement.payload_bytes} signed bytes",
            _REPACK,
        )
    if actual > statement.payload_bytes:
        raise _fail(
            path, f"{actual - statement.payload_bytes} unexpected bytes after the payload", _REPACK
        )
    digest = hashlib.sha256()
    handle.seek(offset)
    for chunk in iter(lambda: handle.read(_CHUNK), b""):
        digest.update(chunk)
    if digest.hexdigest() != statement.payload_sha256:
        raise _fail(path, "payload does not match its signed sha256 (tampered or corrupt)", _REPACK)
    manifest_bytes = _first_member(path, handle, statement, offset, limits)
    manifest = _parse_manifest(path, manifest_bytes, statement)
    return VerifiedPackage(path, statement, signer, manifest, manifest_bytes, offset)


def verify_package(
    path: Path | str, trusted_keys: Sequence[TrustedKey] | None, *, limits: Limits = DEFAULT_LIMITS
) -> VerifiedPackage:
    """Check signature, payload hash and manifest of a ``.craft`` file; writes nothing.

    Order matters: the header is authenticated before its numbers are believed, the payload is
    hashed before any archive structure is parsed, and only then is ``manifest.json`` read.
    """
    path = Path(path)
    trusted = _trusted_table(trusted_keys)
    with _open_package(path) as (handle, size):
        return _verify_open(path, handle, size, trusted, limits)


def _extract(
    path: Path, handle: IO[bytes], verified: VerifiedPackage, staging: Path, limits: Limits
) -> None:
    manifest = verified.manifest
    expected = {name: d for name, d in manifest.files.items()}
    oversized = sorted(name for name, d in expected.items() if d.bytes > limits.max_member_bytes)
    if oversized:  # before any byte is read: each member is also capped by what it declares
        raise _fail(path, f"member {oversized[0]!r} declares {expected[oversized[0]].bytes} bytes, above "
                    f"the limit of {limits.max_member_bytes} per file", _REPACK)
    allowed = {MANIFEST_FILE, BUILD_INFO_FILE, *expected}
    declared = (
        sum(d.bytes for d in expected.values())
        + len(verified.manifest_bytes)
        + limits.max_build_info_bytes
    )
    cap = min(
        limits.max_total_bytes,
        # per member: a header, a possible long-name/pax header and padding; tar end records
        declared + (len(allowed) + 2) * 3 * tarfile.BLOCKSIZE + 4 * tarfile.RECORDSIZE,
    )
    raw, reader = _archive_reader(path, handle, verified.statement, verified.payload_offset, cap)
    seen: list[str] = []
    with tarfile.open(fileobj=reader, mode="r|") as archive:  # type: ignore[call-overload]
        for member in archive:
            if len(seen) >= limits.max_members:
                raise _fail(path, f"more than {limits.max_members} members", _REPACK)
            problem = _member_problem(member, allowed)
            if problem is not None:
                raise _fail(path, problem, _REPACK)
            if member.name in seen:
                raise _fail(path, f"duplicate member {member.name!r}", _REPACK)
            if not seen and member.name != MANIFEST_FILE:
                raise _fail(path, f"the first member must be {MANIFEST_FILE}", _REPACK)
            seen.append(member.name)
            if member.name in expected:
                want = expected[member.name]
                if member.size != want.bytes:
                    raise _fail(
                        path,
                        f"member {member.name!r} is {member.size} bytes, the manifest says {want.bytes}",
                        _REPACK,
                    )
                limit, want_sha = want.bytes, want.sha256
            elif member.name == MANIFEST_FILE:
                limit, want_sha = len(verified.manifest_bytes), verified.statement.manifest_sha256
            else:
                limit, want_sha = limits.max_build_info_bytes, None
            _write_member(path, archive, member, staging / member.name, limit, want_sha)
    missing = sorted(set(expected) - set(seen))
    if missing:
        raise _fail(path, f"incomplete: members {missing} are missing", _REPACK)
    raw.drain()
    if raw.digest.hexdigest() != verified.statement.payload_sha256:
        raise _fail(path, "the file changed while it was being unpacked", "copy it again and retry")


def _write_member(
    path: Path,
    archive: tarfile.TarFile,
    member: tarfile.TarInfo,
    target: Path,
    limit: int,
    want_sha: str | None,
) -> None:
    """Copy one member into the staging folder, hashing as it goes.

    ``O_EXCL | O_NOFOLLOW`` means a name can never be written twice nor through a link, even if
    the allow-list above were wrong. Write failures (disk full, permissions) are reported as
    :class:`DestinationError`, not as a damaged package: the fix is on the robot, not the file.
    """
    digest = hashlib.sha256()
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(target, flags, 0o666)  # less the umask: 0644 as cp makes it
    except OSError as exc:
        raise _destination_error(target, exc) from None
    with os.fdopen(fd, "wb") as out:
        for chunk in _read_member(path, archive, member, limit):
            digest.update(chunk)
            _write_chunk(out, chunk, target)
        _write_chunk(out, b"", target)
    if want_sha is not None and digest.hexdigest() != want_sha:
        raise _fail(path, f"member {member.name!r} does not match its manifest sha256", _REPACK)


def _write_chunk(out: IO[bytes], chunk: bytes, target: Path) -> None:
    """Write ``chunk``; an empty chunk flushes and fsyncs (the end of a member)."""
    try:
        if chunk:
            out.write(chunk)
        else:
            out.flush()
            os.fsync(out.fileno())
    except OSError as exc:
        raise _destination_error(target, exc) from None


def _destination_error(target: Path, exc: OSError) -> DestinationError:
    return DestinationError(
        f"{target.parent}: cannot write {target.name} ({exc.strerror or exc}); free disk space "
        "or fix the permissions of the destination folder, then retry"
    )


def unpack_package(
    path: Path | str,
    trusted_keys: Sequence[TrustedKey] | None,
    dest: Path | str,
    *,
    limits: Limits = DEFAULT_LIMITS,
    mode: int | None = -1,
) -> VerifiedPackage:
    """Verify ``path`` and extract it to ``dest`` (which must not exist or be an empty folder).

    ``dest`` gets mode 0777 less the umask (``mode=-1``, e.g. 0755) and its files 0666 less the
    umask, as ``mkdir`` and ``cp`` would make them; ``mode=None`` keeps the private 0700.

    Extraction goes to a hidden sibling staging folder; ``dest`` appears (by one rename) only
    after every file matched the manifest, so a failure or a crash never leaves a partial
    ``dest``. A crash can leave ``.<dest>.*.unpack`` behind; :func:`install` sweeps those.
    """
    path, dest = Path(path), Path(dest)
    trusted = _trusted_table(trusted_keys)
    if mode == -1:
        mode = 0o777 & ~current_umask()
    if dest.is_symlink() or (dest.exists() and (not dest.is_dir() or any(dest.iterdir()))):
        raise _fail(dest, "already exists and is not an empty folder", "choose a new destination")
    with _open_package(path) as (handle, size):
        verified = _verify_open(path, handle, size, trusted, limits)
        dest.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", suffix=".unpack", dir=dest.parent))
        try:
            if mode is not None:
                # mkdtemp makes 0700; an installed bundle must be readable by the robot's service
                # user when root installs it (0755 under the usual umask 022).
                os.chmod(staging, mode)
            try:
                _extract(path, handle, verified, staging, limits)
            except _ARCHIVE_ERRORS as exc:
                raise _fail(
                    path, f"archive is unreadable ({type(exc).__name__}: {exc})", _REPACK
                ) from None
            try:
                if read_manifest(staging) != verified.manifest:
                    raise _fail(path, f"{MANIFEST_FILE} changed during unpacking", _REPACK)
                verify_files(staging, verified.manifest)
            except PackageError:
                raise
            except BundleError as exc:
                raise _fail(path, str(exc).replace(str(staging), "<unpacked>"), _REPACK) from None
            fsync_dir(staging)
            os.replace(staging, dest)
            fsync_dir(dest.parent)
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
    return verified


@contextlib.contextmanager
def unpacked(
    path: Path | str, trusted_keys: Sequence[TrustedKey] | None, *, limits: Limits = DEFAULT_LIMITS
) -> Iterator[tuple[Path, VerifiedPackage]]:
    """Unpack into a private temporary folder (mode 0700) that is removed on exit."""
    with tempfile.TemporaryDirectory(prefix="craft-package-") as tmp:
        folder = Path(tmp) / "bundle"
        verified = unpack_package(path, trusted_keys, folder, limits=limits, mode=None)
        yield folder, verified


def read_header(path: Path | str) -> PackageHeader:
    """The header of a package, *unverified* — for display (``craft installed``), never trust."""
    path = Path(path)
    with _open_package(path) as (handle, _):
        header, _ = _read_prefix(path, handle, DEFAULT_LIMITS)
        return header


def statement_for(
    manifest_bytes: bytes, manifest: Manifest, payload: bytes, compression: Literal["gzip", "none"]
) -> PackageStatement:
    """The statement a signer makes for ``payload`` (shared by packer and tests)."""
    return PackageStatement(
        kb_name=manifest.kb_name,
        kb_version=manifest.kb_version,
        content_sha256=manifest.content_sha256,
        manifest_sha256=hashlib.sha256(manifest_bytes).hexdigest(),
        payload_sha256=hashlib.sha256(payload).hexdigest(),
        payload_bytes=len(payload),
        compression=compression,
    )


def container_bytes(header: PackageHeader, payload: bytes) -> bytes:
    """Serialize a package: magic, header length, header, payload."""
    head = header.to_bytes()
    return _PREFIX.pack(PACKAGE_MAGIC, len(head)) + head + payload


__all__ = [
    "DEFAULT_LIMITS",
    "PACKAGE_FORMAT",
    "PACKAGE_MAGIC",
    "PACKAGE_SUFFIX",
    "DestinationError",
    "Limits",
    "PackageError",
    "PackageHeader",
    "PackageSignature",
    "PackageStatement",
    "TrustedKeyError",
    "VerifiedPackage",
    "container_bytes",
    "key_id",
    "parse_public_key",
    "read_header",
    "statement_for",
    "unpack_package",
    "unpacked",
    "verify_package",
]
