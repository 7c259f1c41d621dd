"""Emit pass: write a bundle into a temporary sibling folder, then swap it into place.

A failed or interrupted build never leaves a half-written ``--out``: either the previous bundle
is still there, or the new one is complete.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

from ..files import current_umask
from ..schemas.v1.bundle import (
    BUILD_INFO_FILE,
    BUNDLE_FILES,
    MANIFEST_FILE,
    MANIFEST_SCHEMA_ID,
    BuildInfo,
    FileDigest,
    Manifest,
)


def file_digest(data: bytes) -> FileDigest:
    return FileDigest(sha256=hashlib.sha256(data).hexdigest(), bytes=len(data))


def model_json(model: Manifest | BuildInfo) -> bytes:
    return (json.dumps(model.model_dump(mode="json"), indent=2, sort_keys=True) + "\n").encode()


class OutPathError(ValueError):
    """``--out`` names something that is not ours to replace; the message says what and why."""


class BundleWriteError(OSError):
    """Writing the bundle at ``--out`` failed (a read-only or full folder, another build racing
    this one): the one ``OSError`` a build may report as an output problem. Any other
    ``OSError`` of a build is about one of its inputs, and must not be blamed on ``--out``."""

    def __init__(self, cause: OSError) -> None:
        if cause.errno is not None and cause.strerror is not None:
            super().__init__(cause.errno, cause.strerror, cause.filename)
        else:
            super().__init__(str(cause))


def _existing_bundle(path: Path) -> tuple[str, list[str]] | None:
    """``(kb name, files that are not bundle files)`` of the bundle at ``path``, or None.

    A folder is a bundle when it holds a regular ``manifest.json`` whose schema id is the bundle
    manifest's. Other files beside it (notes a user put there, a stale file) are reported so the
    build can refuse to delete them without ``--force``.
    """
    manifest_path = path / MANIFEST_FILE
    try:
        if manifest_path.is_symlink() or not manifest_path.is_file():
            return None
        if manifest_path.stat().st_size > 16 * 1024 * 1024:
            return None
        data = json.loads(manifest_path.read_bytes())
        names = sorted(child.name for child in path.iterdir())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("schema_id") != MANIFEST_SCHEMA_ID:
        return None
    name = data.get("kb_name")
    if not isinstance(name, str):
        return None
    allowed = {*BUNDLE_FILES, MANIFEST_FILE, BUILD_INFO_FILE}
    return name, [n for n in names if n not in allowed]


def _check_out_parents(out: Path) -> None:
    """Refuse an ``--out`` below a file (no folder can be made there) or inside a bundle.

    A bundle nested in another would be a stray file of the outer one: its rebuild would refuse
    (or, with ``--force``, delete the inner bundle), and ``craft install`` of it would carry it.
    """
    absolute = Path(os.path.abspath(out))
    for parent in absolute.parents:
        if not os.path.lexists(parent):
            continue
        if not parent.is_dir():
            raise OutPathError(
                f"--out {out}: {parent} is a file, not a folder, so no folder can be made inside "
                "it; choose another path (nothing was written)"
            )
        existing = _existing_bundle(parent)
        if existing is not None:
            raise OutPathError(
                f"--out {out} is inside the bundle {existing[0]!r} at {parent}; a bundle cannot "
                "hold another. Choose a folder outside it (nothing was written)"
            )


def check_out_path(
    out: Path, kb_name: str, *, force: bool = False, inputs: tuple[Path, ...] = ()
) -> None:
    """Refuse an ``--out`` whose replacement would destroy something a user owns.

    Only a missing path, an empty folder, or an existing CRAFT-E bundle may become the bundle.
    A bundle of another kb name, or one with other files beside the bundle's, is replaced only
    with ``force``; a user's folder, a file, a symlink, a mount point, a folder holding an input
    or the working directory never are.
    """
    if os.path.islink(out):
        raise OutPathError(
            f"--out {out} is a symbolic link; give the real folder path (nothing was written)"
        )
    _check_out_parents(out)
    if not out.exists():
        return
    resolved = out.resolve()
    if not resolved.is_dir():
        raise OutPathError(
            f"--out {out} is an existing file, not a bundle folder; choose a new folder path "
            "(nothing was written)"
        )
    if os.path.ismount(resolved):
        raise OutPathError(
            f"--out {out} is a mount point; give a folder inside it (nothing was written)"
        )
    cwd = Path.cwd().resolve()
    for inside in (cwd, *(p.resolve() for p in inputs)):
        if inside == resolved or resolved in inside.parents:
            raise OutPathError(
                f"--out {out} contains {inside}, which the build reads or runs in; choose "
                "another folder (nothing was written)"
            )
    try:
        empty = not any(resolved.iterdir())
    except OSError as exc:
        raise OutPathError(
            f"--out {out}: cannot list it ({exc.strerror}); nothing was written"
        ) from None
    if empty:
        return
    existing = _existing_bundle(resolved)
    if existing is None:
        raise OutPathError(
            f"--out {out} is a folder that is not a CRAFT-E bundle (it has no bundle "
            "manifest.json); a build only replaces a bundle. Choose a new or empty folder "
            "(nothing was written)"
        )
    name, extras = existing
    if force:
        return
    if extras:
        shown = ", ".join(extras[:5]) + (" ..." if len(extras) > 5 else "")
        raise OutPathError(
            f"--out {out} is a bundle with other files in it ({shown}) that a rebuild would "
            "delete; move them out, or pass --force to replace the folder (nothing was written)"
        )
    if name != kb_name:
        raise OutPathError(
            f"--out {out} holds the bundle {name!r}, not {kb_name!r}; pass --force to replace "
            "it (nothing was written)"
        )


def write_bundle(
    out: Path,
    files: dict[str, bytes],
    manifest: Manifest,
    build_info: BuildInfo,
    *,
    force: bool = False,
) -> None:
    """Write ``files`` + manifest + build info to ``out`` atomically (rename of a whole folder).

    The folder gets the modes a user expects (0777/0666 less the umask, e.g. 0755/0644), not
    ``mkdtemp``'s 0700: a robot service running as another user must be able to read it.
    An ``OSError`` while writing is raised as :class:`BundleWriteError`.
    """
    check_out_path(out, manifest.kb_name, force=force)
    try:
        _write_bundle(out, files, manifest, build_info, force=force)
    except BundleWriteError:
        raise
    except OSError as exc:
        raise BundleWriteError(exc) from exc


def _write_bundle(
    out: Path,
    files: dict[str, bytes],
    manifest: Manifest,
    build_info: BuildInfo,
    *,
    force: bool,
) -> None:
    out = out.resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        os.chmod(staging, 0o777 & ~current_umask())
        for name, data in files.items():
            (staging / name).write_bytes(data)
        (staging / MANIFEST_FILE).write_bytes(model_json(manifest))
        (staging / BUILD_INFO_FILE).write_bytes(model_json(build_info))
        for path in staging.iterdir():
            with path.open("rb") as handle:
                os.fsync(handle.fileno())
        if out.exists():
            # Check again right before the swap: the folder may have changed during the build.
            check_out_path(out, manifest.kb_name, force=force)
            retired = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
            retired.rmdir()
            os.replace(out, retired)
            try:
                os.replace(staging, out)
            except BaseException:
                # Put the previous bundle back: --out must never be left empty or half-swapped.
                os.replace(retired, out)
                raise
            shutil.rmtree(retired, ignore_errors=True)
        else:
            os.replace(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
