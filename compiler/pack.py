"""``craftc pack`` / ``craftc keygen``: turn a bundle folder into one signed ``.craft`` file.

A folder is easy to damage in transit (a missed file, a partial rsync) and carries no statement
of who built it. Packing fixes both: the bundle's files go into a deterministic tar (fixed
order, zero mtimes and owners, gzip with mtime 0), and an Ed25519 signature over a statement
binding kb name, version, content hash, manifest hash and the archive's own sha256 goes in a
header *in front of* the archive, so the robot can authenticate everything before extracting.
The container format is defined (and read) in :mod:`craft_e.runtime.kb.package`; this module only
writes it. The same bundle and key give a byte-identical package (Ed25519 is deterministic).
"""

from __future__ import annotations

import gzip
import io
import os
import stat
import tarfile
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from ..files import current_umask
from ..runtime.kb.package import (
    PACKAGE_MAGIC,
    PackageError,
    PackageHeader,
    PackageSignature,
    PackageStatement,
    container_bytes,
    key_id,
    statement_for,
    verify_package,
)
from ..runtime.kb.verify import BundleError, read_manifest, verify_digests
from ..schemas.v1.bundle import BUILD_INFO_FILE, MANIFEST_FILE, Manifest

SIGNING_KEY_FILE = "craft-signing.key"
PUBLIC_KEY_FILE = "craft-signing.pub"
Compression = Literal["gzip", "none"]
_PRIVATE_BANNER = (
    b"# CRAFT-E Ed25519 signing key: secret, keep mode 0600, never commit or ship it\n"
)


class PackError(RuntimeError):
    """Packing cannot proceed; the message names the file and the fix."""


class UnverifiedBundleError(PackError):
    """The bundle folder itself fails verification (a check failure, not bad usage)."""


@dataclass(frozen=True)
class KeyPair:
    """Where ``keygen`` wrote the keys, and the public key's id (as packages will name it)."""

    private_key: Path
    public_key: Path
    key_id: str


@dataclass(frozen=True)
class PackResult:
    out: Path
    statement: PackageStatement
    key_id: str
    bytes: int
    notes: list[str] = field(default_factory=list)


# --------------------------------------------------------------------------- keys


def _write_new(path: Path, data: bytes, mode: int) -> None:
    """Create ``path`` with ``data`` and ``mode`` atomically, never replacing an existing file.

    The temp file is created 0600 (mkstemp) before any key byte is written, then hard-linked to
    its final name: ``link`` fails if the name exists, so an old key is never clobbered, and
    the final name never shows a partial key.
    """
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.link(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)


def keygen(out_dir: Path | str) -> KeyPair:
    """Write a new Ed25519 key pair: ``craft-signing.key`` (0600, ``seed:<hex>``), ``.pub`` (hex).

    Refuses to overwrite an existing key: losing a signing key means every robot that trusts it
    must be re-provisioned, so replacing one must be a deliberate ``rm``.
    """
    from nacl.signing import SigningKey

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    private, public = out / SIGNING_KEY_FILE, out / PUBLIC_KEY_FILE
    for path in (private, public):
        if path.exists() or path.is_symlink():
            raise PackError(
                f"{path}: already exists; refusing to overwrite a signing key (move it away first "
                "if you really mean to rotate keys — robots trusting it must get the new .pub)"
            )
    key = SigningKey.generate()
    raw_public = bytes(key.verify_key)
    try:
        _write_new(private, _PRIVATE_BANNER + f"seed:{bytes(key).hex()}\n".encode(), 0o600)
        _write_new(public, raw_public.hex().encode() + b"\n", 0o644)
    except FileExistsError as exc:
        raise PackError(f"{exc.filename}: appeared while writing keys; not overwritten") from None
    return KeyPair(private, public, key_id(raw_public))


def load_signing_key(path: Path | str) -> tuple[bytes, list[str]]:
    """The 32-byte Ed25519 seed in ``path`` (``seed:<hex>``, as ``keygen`` writes it) + warnings.

    The ``seed:`` prefix keeps the two key files impossible to confuse: a public key passed
    as ``--key`` would otherwise be accepted as a seed and sign with an unrelated key.
    """
    path = Path(path)
    notes: list[str] = []
    try:
        info = path.stat()
        text = path.read_text(encoding="ascii")
    except FileNotFoundError:
        raise PackError(
            f"{path}: no such key file (create one with `craftc keygen --out DIR`)"
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise PackError(f"{path}: cannot read the signing key ({exc})") from None
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    seed = b""
    if len(lines) == 1 and lines[0].startswith("seed:"):
        try:
            seed = bytes.fromhex(lines[0][5:])
        except ValueError:
            seed = b""
    if len(seed) != 32:
        looks_public = len(lines) == 1 and len(lines[0]) == 64
        raise PackError(
            f"{path}: not a craft signing key (expected a `seed:<64 hex>` line as written by "
            "`craftc keygen`)"
            + ("; this looks like the public key: pass craft-signing.key" if looks_public else "")
        )
    if stat.S_IMODE(info.st_mode) & 0o077:
        notes.append(f"{path}: readable by other users; run `chmod 600 {path}`")
    return seed, notes


# --------------------------------------------------------------------------- archive


def _tar_member(archive: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size = len(data)
    info.mode = 0o644
    info.mtime = 0
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    info.type = tarfile.REGTYPE
    archive.addfile(info, io.BytesIO(data))


def archive_bytes(members: list[tuple[str, bytes]], compression: Compression = "gzip") -> bytes:
    """A deterministic ustar archive of ``members`` in order (gzip with mtime 0 if asked)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.USTAR_FORMAT) as archive:
        for name, data in members:
            _tar_member(archive, name, data)
    tar = buffer.getvalue()
    if compression == "none":
        return tar
    return gzip.compress(tar, compresslevel=9, mtime=0)


def seal(
    payload: bytes,
    manifest_bytes: bytes,
    manifest: Manifest,
    seed: bytes,
    compression: Compression,
) -> bytes:
    """Sign a payload and prefix the header: the whole ``.craft`` file as bytes."""
    from nacl.signing import SigningKey

    key = SigningKey(seed)
    statement = statement_for(manifest_bytes, manifest, payload, compression)
    signature = key.sign(statement.message()).signature
    header = PackageHeader(
        statement=statement,
        signature=PackageSignature(key_id=key_id(bytes(key.verify_key)), value=signature.hex()),
    )
    return container_bytes(header, payload)


def _bundle_members(bundle_dir: Path) -> tuple[list[tuple[str, bytes]], Manifest]:
    from ..runtime.kb.bundle import bundle_from_files
    from .bundle_checks import check_derived_files

    try:
        manifest = read_manifest(bundle_dir)
        data = verify_digests(bundle_dir, manifest)
        # the bytes to sign, read once: checked against each other (as verify_files does), then
        # what validate checks beyond loading: their E_aff and graph.ttl are their graph's
        check_derived_files(bundle_from_files(bundle_dir, manifest, data))
    except BundleError as exc:
        raise UnverifiedBundleError(
            f"refusing to pack a bundle that does not verify: {exc}"
        ) from None
    manifest_bytes = (bundle_dir / MANIFEST_FILE).read_bytes()
    members = [(MANIFEST_FILE, manifest_bytes), *sorted(data.items())]
    build_info = bundle_dir / BUILD_INFO_FILE
    if build_info.is_file():
        members.append((BUILD_INFO_FILE, build_info.read_bytes()))
    return members, manifest


def pack_bundle(
    bundle_dir: Path | str,
    signing_key_path: Path | str,
    out_path: Path | str,
    *,
    compression: Compression = "gzip",
) -> PackResult:
    """Verify ``bundle_dir``, sign it with the key at ``signing_key_path``, write ``out_path``.

    The output is written to a temp file in the target folder, verified with the runtime's own
    reader against the signer's public key, then renamed into place: a crash leaves either the
    old file or the new one, and a package the robot would refuse is never produced.
    """
    from nacl.signing import SigningKey

    bundle_dir, out = Path(bundle_dir), Path(out_path)
    if compression not in ("gzip", "none"):
        raise PackError(f"unknown compression {compression!r}; use gzip or none")
    seed, notes = load_signing_key(signing_key_path)
    members, manifest = _bundle_members(bundle_dir)
    payload = archive_bytes(members, compression)
    blob = seal(payload, members[0][1], manifest, seed, compression)
    public = bytes(SigningKey(seed).verify_key)
    protected = (Path(signing_key_path), bundle_dir)
    _check_out_file(out, protected=protected)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    except OSError as exc:
        raise PackError(f"{out}: cannot write the package ({exc.strerror or exc})") from None
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(blob)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, 0o666 & ~current_umask())
        try:
            verified = verify_package(tmp, [public])
        except PackageError as exc:  # pragma: no cover - would be a packer bug
            raise PackError(f"the package just written does not verify: {exc}") from None
        _check_out_file(out, protected=protected)
        os.replace(tmp, out)
    except OSError as exc:
        raise PackError(
            f"{out}: cannot write the package ({exc.strerror or exc}); free disk space or fix "
            "the folder's permissions"
        ) from None
    finally:
        tmp.unlink(missing_ok=True)
    return PackResult(out, verified.statement, verified.key_id, len(blob), notes)


def _check_out_file(out: Path, *, protected: Sequence[Path] = ()) -> None:
    """``-o`` names a file to create, or a CRAFT-E package to replace: never a folder, a FIFO or
    a device, never a file of another kind (a signing key, a user's document: replacing it would
    lose it for good), and never one of ``protected`` (the key and the bundle being packed)."""
    resolved = out.resolve()
    for path in protected:
        inside = path.resolve()
        if resolved == inside or inside in resolved.parents:
            raise PackError(
                f"{out}: is {'inside ' if resolved != inside else ''}{path}, which this pack reads; "
                "write the package somewhere else, e.g. kb.craft (nothing was written)"
            )
    if out.is_symlink() or not out.exists():
        return
    if out.is_dir():
        raise PackError(
            f"{out}: is a folder; give the package's file path, e.g. {out / 'kb.craft'} "
            "(nothing was written)"
        )
    if not out.is_file():
        raise PackError(f"{out}: exists and is not a regular file (nothing was written)")
    with out.open("rb") as handle:
        head = handle.read(len(PACKAGE_MAGIC))
    if head != PACKAGE_MAGIC:
        raise PackError(
            f"{out}: exists and is not a CRAFT-E package, so it is not replaced; give a new path "
            "or remove the file yourself (nothing was written)"
        )

