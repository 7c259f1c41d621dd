"""Installing packed bundles on a robot with atomic switch-over and one-step rollback.

Layout under ``into`` (relative symlinks, so the folder can be moved or rsynced whole):

.. code-block:: text

    into/versions/<kb_name>-<kb_version>-<hash12>/   one verified bundle folder per version
    into/current  -> versions/<id>                   what the robot loads
    into/previous -> versions/<id>                   what ``rollback`` returns to
    into/.lock                                       serializes install/rollback (flock)
    into/.rollback -> versions/<id>                  only during a rollback: the old current

Why this shape: a robot may lose power at any instant. A version folder appears only by the
rename of a fully verified staging folder (``unpack_package``), and ``current`` changes only by
``os.replace`` of a freshly made temporary symlink, which POSIX makes atomic. So at every
instant ``current`` names a complete, verified version — the old one until the final rename,
the new one after it. Version folders are never modified once named; a crashed install leaves
only hidden staging folders, swept by the next install.

A rollback has to move two links, and no POSIX call moves two atomically. So it first records
the old ``current`` in ``.rollback``, then switches ``current``, then ``previous``, then removes
``.rollback``; a crash anywhere in between is completed by the next ``install`` or ``rollback``
(before the crash-free path would have diverged), so ``current`` and ``previous`` never end up
naming the same version with the old one forgotten.

Versions only go up: installing a lower ``kb_version`` of the installed KB is refused unless
``allow_downgrade`` (``--allow-downgrade``); ``rollback`` is the way back to the previous one.

Load the installed bundle with ``load_bundle(current(into))``: ``current`` resolves the link
once, so a concurrent switch cannot make one load read files of two versions.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ...files import fsync_dir, held_flock
from ...schemas.v1.bundle import Manifest
from .package import (
    DEFAULT_LIMITS,
    Limits,
    TrustedKey,
    unpack_package,
    verify_package,
)
from .verify import BundleError, read_manifest, verify_files

VERSIONS = "versions"
CURRENT = "current"
PREVIOUS = "previous"
LOCK = ".lock"
ROLLBACK_JOURNAL = ".rollback"
_VERSION_NAME = re.compile(r"^[a-z0-9][a-z0-9._-]*-\d+\.\d+\.\d+-[0-9a-f]{12}$")
_VERSION = r"[a-z0-9][a-z0-9._-]*-\d+\.\d+\.\d+-[0-9a-f]{12}"
#: the hidden names install itself gives to work in ``versions/``: unpack staging (mkdtemp's
#: random part), a re-read check, a damaged copy set aside; and its temporary links in ``into``
_STAGING_NAME = re.compile(rf"^\.{_VERSION}\.(?:[A-Za-z0-9_]+\.unpack|[0-9a-f]{{8}}\.(?:check|broken))$")
_TEMP_LINK_NAME = re.compile(r"^\.[a-z.]+\.[0-9a-f]{12}\.tmp$")


class InstallError(BundleError):
    """An install folder is busy, damaged or has nothing to roll back to; says the fix."""


class DamagedVersionError(InstallError):
    """An installed version folder no longer matches its manifest (disk damage, edits)."""


class DowngradeError(InstallError):
    """The package is an older version of the installed KB (``--allow-downgrade`` to force)."""


@dataclass(frozen=True)
class InstallResult:
    version: str
    path: Path
    previous: str | None  # what ``previous`` points to afterwards
    reused: bool  # the version folder was already present and verified


@dataclass(frozen=True)
class InstalledVersion:
    """One folder under ``versions/`` as ``craft installed`` lists it."""

    version: str
    path: Path
    kb_name: str | None
    kb_version: str | None
    content_sha256: str | None
    is_current: bool
    is_previous: bool
    problem: str | None = None


def version_id(manifest: Manifest) -> str:
    """``<kb_name>-<kb_version>-<first 12 hex of content sha256>``: readable and unique."""
    return f"{manifest.kb_name}-{manifest.kb_version}-{manifest.content_sha256[:12]}"


def _locked(into: Path) -> contextlib.AbstractContextManager[None]:
    """Hold ``into/.lock`` exclusively; a second installer fails fast instead of interleaving
    (``flock``: the kernel releases it when a process dies, so a crash never leaves it stuck)."""
    return held_flock(into / LOCK, busy=lambda: InstallError(
        f"{into}: another `craft install` or `craft rollback` is running; wait for it and retry"))


def _link_target(into: Path, name: str) -> str | None:
    """The version a link names, or None if the link does not exist; refuses foreign links."""
    link = into / name
    if not link.is_symlink():
        if link.exists():
            raise InstallError(
                f"{link}: exists but is not a symlink made by `craft install`; move it away"
            )
        return None
    target = os.readlink(link)
    parts = target.split("/")
    if len(parts) != 2 or parts[0] != VERSIONS or not _VERSION_NAME.match(parts[1]):
        raise InstallError(
            f"{link}: points to {target!r}, not to {VERSIONS}/<version>; it was not made by "
            "`craft install` — remove it and install again"
        )
    if not (into / VERSIONS / parts[1]).is_dir():
        raise InstallError(f"{link}: points to missing version {parts[1]}; install a package again")
    return parts[1]


def _point(into: Path, name: str, version: str) -> None:
    """Make ``into/name`` point at ``versions/<version>`` atomically (temp symlink + replace)."""
    tmp = into / f".{name}.{secrets.token_hex(6)}.tmp"
    os.symlink(f"{VERSIONS}/{version}", tmp)
    try:
        os.replace(tmp, into / name)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(into)


def _verified_folder(folder: Path) -> Manifest | None:
    try:
        manifest = read_manifest(folder)
        verify_files(folder, manifest)
    except BundleError:
        return None
    return manifest


def _sweep(into: Path) -> None:
    """Remove leftovers of crashed runs: the hidden staging folders and temp links that install
    and rollback name (``_STAGING_NAME``, ``_TEMP_LINK_NAME``), nothing else: ``versions/`` may
    hold what a person put there, and that is theirs."""
    versions = into / VERSIONS
    if versions.is_dir():
        for entry in versions.iterdir():
            if _STAGING_NAME.match(entry.name):
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry, ignore_errors=True)
                else:
                    entry.unlink(missing_ok=True)
    for entry in into.iterdir():
        if _TEMP_LINK_NAME.match(entry.name) and entry.is_symlink():
            entry.unlink(missing_ok=True)


def _finish_rollback(into: Path) -> None:
    """Complete a rollback that a crash interrupted (``.rollback`` names the old current).

    Before the switch of ``current`` the journal names the version ``current`` still points to:
    nothing happened yet, drop the journal. After it, ``previous`` must become the journal's
    version, exactly what the interrupted rollback would have done next.
    """
    journal = into / ROLLBACK_JOURNAL
    if not journal.is_symlink():
        return
    old = _link_target(into, ROLLBACK_JOURNAL)
    if old is not None and _link_target(into, CURRENT) != old:
        _point(into, PREVIOUS, old)
    journal.unlink()
    fsync_dir(into)


#: the names ``craft install`` and ``craft rollback`` make directly in ``into``
_INSTALL_NAMES = frozenset({VERSIONS, CURRENT, PREVIOUS, LOCK, ROLLBACK_JOURNAL})


def _as_folder(into: Path | str) -> Path:
    """``into`` as a path; an empty one is refused (``Path("")`` would silently mean the working
    directory, so ``--into "$UNSET"`` would install into wherever the command ran)."""
    if not str(into).strip():
        raise InstallError("the install folder (--into) is empty; give a folder path, e.g. "
                           "/opt/craft-e/kb (nothing was written)")
    return Path(into)


def check_install_root(into: Path) -> None:
    """Refuse an ``into`` that ``craft install`` would write into but that is not its own.

    An install folder is one of: a path that does not exist yet (created), an empty folder, a
    folder holding only the names install makes (``versions/``, ``current``, ``previous``,
    ``.lock``, ``.rollback``, its temporary links), or one with install's layout (``versions/``
    beside ``.lock`` or a ``current`` link; a person's notes beside them are left alone). A KB
    bundle folder (``manifest.json``: a rebuild of it would refuse the extra files) and any
    other folder with content are refused; nothing is ever removed to make room.
    """
    if not into.exists():
        if into.is_symlink():
            raise InstallError(f"{into}: is a dangling symbolic link; give a real folder "
                               "(nothing was written)")
        return
    if not into.is_dir():
        raise InstallError(f"{into}: is a file, not an install folder; check --into "
                           "(nothing was written)")
    try:
        names = sorted(entry.name for entry in into.iterdir())
    except OSError as exc:
        raise InstallError(f"{into}: cannot list it ({exc.strerror or exc}); check --into") from None
    if "manifest.json" in names:
        raise InstallError(
            f"{into}: is a KB bundle folder (it has manifest.json), not an install folder; "
            "give --into a new or empty folder, e.g. /opt/craft-e/kb (nothing was written)"
        )
    foreign = [n for n in names if n not in _INSTALL_NAMES and not _TEMP_LINK_NAME.match(n)]
    if not foreign:
        return
    layout = (into / VERSIONS).is_dir() and not (into / VERSIONS).is_symlink() and (
        (into / LOCK).is_file() or (into / CURRENT).is_symlink())
    if layout:
        return
    shown = ", ".join(foreign[:5]) + (" ..." if len(foreign) > 5 else "")
    raise InstallError(
        f"{into}: is a folder with other content ({shown}) and no install made by "
        "`craft install` (versions/, current); give --into a new or empty folder, or an "
        "existing install folder (nothing was written)"
    )


def _semver(text: str) -> tuple[int, ...]:
    return tuple(int(p) for p in text.split("."))


def _prune(into: Path, keep: set[str]) -> list[str]:
    """Remove installed versions other than ``keep``: folders with a version's name that hold a
    bundle manifest (what install made), never another folder or file of ``versions/``."""
    removed: list[str] = []
    for entry in sorted((into / VERSIONS).iterdir()):
        if entry.name in keep or not _VERSION_NAME.match(entry.name):
            continue
        if entry.is_dir() and not entry.is_symlink() and (entry / "manifest.json").is_file():
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry.name)
    return removed


def install(
    package: Path | str,
    into: Path | str,
    trusted_keys: Sequence[TrustedKey] | None,
    *,
    prune: bool = True,
    limits: Limits = DEFAULT_LIMITS,
    allow_downgrade: bool = False,
) -> InstallResult:
    """Verify ``package``, unpack it as a new version, then switch ``current`` to it.

    The old ``current`` becomes ``previous``. With ``prune``, versions that are neither current
    nor previous are removed afterwards (a robot's disk is small). Installing the version that is
    already current changes nothing (the package is still read and checked in full: a damaged
    package is refused even when its version is installed); re-installing a damaged version
    folder replaces it. A lower ``kb_version`` of the current KB is refused (``DowngradeError``)
    unless ``allow_downgrade``.
    """
    package, into = Path(package), _as_folder(into)
    check_install_root(into)
    # before anything is written (not even ``into`` or its lock): a refused package leaves the
    # disk as it was; the unpack below checks the signature again on what it extracts
    verified = verify_package(package, trusted_keys, limits=limits)
    with _locked(into):
        versions = into / VERSIONS
        versions.mkdir(exist_ok=True)
        _sweep(into)
        _finish_rollback(into)
        vid = version_id(verified.manifest)
        target = versions / vid
        old = _link_target(into, CURRENT)
        if old is not None and not allow_downgrade:
            _check_not_downgrade(into / VERSIONS / old, verified.manifest, package)
        reused = False
        if target.is_dir() and _verified_folder(target) == verified.manifest:
            reused = True
            # Read the whole package anyway (extract to a scratch folder, then drop it): a
            # package that would not unpack must not "install" just because its version is here.
            scratch = versions / f".{vid}.{secrets.token_hex(4)}.check"
            try:
                unpack_package(package, trusted_keys, scratch, limits=limits)
            finally:
                shutil.rmtree(scratch, ignore_errors=True)
        else:
            if target.exists() or target.is_symlink():
                # a damaged copy (never the verified current: that would have matched above)
                aside = versions / f".{vid}.{secrets.token_hex(4)}.broken"
                os.replace(target, aside)
                shutil.rmtree(aside, ignore_errors=True)
            unpack_package(package, trusted_keys, target, limits=limits)
        if old != vid:
            if old is not None:
                _point(into, PREVIOUS, old)
            _point(into, CURRENT, vid)
        if prune:
            keep = {vid} | {v for v in (_link_target(into, PREVIOUS),) if v is not None}
            _prune(into, keep)
        return InstallResult(vid, target, _link_target(into, PREVIOUS), reused)


def _check_not_downgrade(current_folder: Path, new: Manifest, package: Path) -> None:
    try:
        installed_manifest = read_manifest(current_folder)
    except BundleError:
        return  # a damaged current is replaced, whatever its version
    if installed_manifest.kb_name != new.kb_name:
        return
    if _semver(new.kb_version) < _semver(installed_manifest.kb_version):
        raise DowngradeError(
            f"{package}: {new.kb_name} {new.kb_version} is older than the installed "
            f"{installed_manifest.kb_version}; use `craft rollback` to return to the previous "
            "version, or pass --allow-downgrade to install it anyway"
        )


def rollback(into: Path | str) -> InstallResult:
    """Switch ``current`` back to ``previous`` (and ``previous`` to the old current).

    Rolling back twice returns to where you started. The previous version is re-verified
    first, so a rollback never switches to a damaged folder.
    """
    into = _as_folder(into)
    if not into.is_dir():
        raise InstallError(f"{into}: no such install folder; run `craft install` first")
    check_install_root(into)
    with _locked(into):
        _finish_rollback(into)
        cur, prev = _link_target(into, CURRENT), _link_target(into, PREVIOUS)
        if prev is None:
            raise InstallError(
                f"{into}: nothing to roll back to (no previous version); install an older "
                "package instead (craft install --allow-downgrade if it has a lower kb_version)"
            )
        if prev == cur:
            raise InstallError(
                f"{into}: current and previous both name {cur}, so a rollback would change "
                "nothing (left by a crash of an older craft); install the version you want"
            )
        folder = into / VERSIONS / prev
        if _verified_folder(folder) is None:
            raise DamagedVersionError(
                f"{folder}: the previous version no longer verifies; re-install its package "
                "instead of rolling back"
            )
        if cur is not None:
            _point(into, ROLLBACK_JOURNAL, cur)  # what previous must become, should we crash
        _point(into, CURRENT, prev)  # the step that matters comes first
        if cur is not None:
            _point(into, PREVIOUS, cur)
            (into / ROLLBACK_JOURNAL).unlink()
            fsync_dir(into)
        return InstallResult(prev, folder, cur, True)


def current(into: Path | str) -> Path | None:
    """The resolved folder of the current version (pass it to ``load_bundle``), or None."""
    into = Path(into)
    if not into.is_dir():
        return None
    vid = _link_target(into, CURRENT)
    return None if vid is None else (into / VERSIONS / vid).resolve()


def installed(into: Path | str, *, verify: bool = False) -> list[InstalledVersion]:
    """Every version folder, newest name last, with its manifest facts and current/previous marks.

    With ``verify`` every file is re-hashed (slower), so ``problem`` reports silent disk damage.
    A folder that does not exist yet lists nothing (``craft installed`` calls an explicitly named
    one that is missing an error); a bundle or other foreign folder is refused.
    """
    into = _as_folder(into)
    versions = into / VERSIONS
    check_install_root(into)
    if not versions.is_dir():
        return []
    cur, prev = _link_target(into, CURRENT), _link_target(into, PREVIOUS)
    out: list[InstalledVersion] = []
    for entry in sorted(versions.iterdir()):
        if entry.name.startswith(".") or not entry.is_dir():
            continue
        problem: str | None = None
        manifest: Manifest | None = None
        try:
            manifest = read_manifest(entry)
            if verify:
                verify_files(entry, manifest)
        except BundleError as exc:
            problem = str(exc)
        out.append(
            InstalledVersion(
                version=entry.name,
                path=entry,
                kb_name=manifest.kb_name if manifest else None,
                kb_version=manifest.kb_version if manifest else None,
                content_sha256=manifest.content_sha256 if manifest else None,
                is_current=entry.name == cur,
                is_previous=entry.name == prev,
                problem=problem,
            )
        )
    return out
