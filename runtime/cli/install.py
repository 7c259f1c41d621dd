"""``craft install`` / ``craft rollback`` / ``craft installed``: thin commands over ``install.py``.

Exit codes: 0 ok; 1 a package or installed version failed verification (untrusted signer,
tampered, damaged); 2 bad usage (missing file, a --trusted-key that is no public key, a missing,
busy or foreign install folder, nothing to roll back to, an older version without
--allow-downgrade). The runtime CLI never imports the compiler.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from .common import EXIT_BAD_INPUT, EXIT_CHECK_FAILED, fail, out


def _folder(text: str) -> Path:
    """``--into``'s parser: an empty value is refused, not read as the working directory (a
    ``--into "$UNSET"`` would otherwise install into wherever the command ran)."""
    if not text.strip():
        raise typer.BadParameter("empty path; give the install folder, e.g. /opt/craft-e/kb")
    return Path(text)


IntoOpt = Annotated[
    Path,
    typer.Option(
        "--into",
        parser=_folder,
        help="Install folder (holds versions/, current, previous): a new or empty folder, or "
        "one `craft install` made; never a bundle folder.",
    ),
]


def install_cmd(
    package: Annotated[Path, typer.Argument(help="Signed package (kb.craft).")],
    into: IntoOpt,
    trusted_key: Annotated[
        list[Path],
        typer.Option(
            "--trusted-key", help="Signer's public key file (craft-signing.pub); repeatable."
        ),
    ],
    keep_all: Annotated[
        bool, typer.Option(help="Keep versions other than current and previous.")
    ] = False,
    allow_downgrade: Annotated[
        bool,
        typer.Option(help="Install an older kb_version of the current KB (refused by default)."),
    ] = False,
) -> None:
    """Verify a signed package and make it the current KB (the old one becomes previous)."""
    from ..kb.install import InstallError, install
    from ..kb.package import DestinationError, PackageError, TrustedKeyError

    try:
        result = install(
            package,
            into,
            [str(p) for p in trusted_key],
            prune=not keep_all,
            allow_downgrade=allow_downgrade,
        )
    except (InstallError, DestinationError, TrustedKeyError) as exc:  # bad --into / --trusted-key
        fail(str(exc), EXIT_BAD_INPUT)
    except PackageError as exc:
        missing = not package.is_file()
        fail(str(exc), EXIT_BAD_INPUT if missing else EXIT_CHECK_FAILED)
    except OSError as exc:
        fail(f"{into}: cannot write the install folder ({exc})", EXIT_BAD_INPUT)
    how = "already present, verified" if result.reused else "unpacked and verified"
    out.print(
        f"installed {result.version} ({how}) -> {into / 'current'}\n"
        f"  previous: {result.previous or '-'}",
        highlight=False,
        markup=False,
        soft_wrap=True,
    )


def rollback_cmd(into: IntoOpt) -> None:
    """Switch current back to the previous version (run again to undo)."""
    from ..kb.install import DamagedVersionError, InstallError, rollback

    try:
        result = rollback(into)
    except DamagedVersionError as exc:
        fail(str(exc), EXIT_CHECK_FAILED)
    except InstallError as exc:
        fail(str(exc), EXIT_BAD_INPUT)
    out.print(
        f"rolled back: current -> {result.version}; previous -> {result.previous or '-'}",
        highlight=False,
        markup=False,
        soft_wrap=True,
    )


def installed_cmd(
    into: IntoOpt,
    verify: Annotated[bool, typer.Option(help="Re-hash every file of every version.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """List installed versions, marking current (*) and previous (-)."""
    from ..kb.install import InstallError, installed

    if not into.exists() and not into.is_symlink():  # a typo, like `rollback` says: not "nothing"
        fail(f"{into}: no such install folder; check --into (or run `craft install` first)",
             EXIT_BAD_INPUT)
    try:
        versions = installed(into, verify=verify)
    except InstallError as exc:
        fail(str(exc), EXIT_BAD_INPUT)
    if as_json:
        rows = [
            {
                "version": v.version,
                "path": str(v.path),
                "kb_name": v.kb_name,
                "kb_version": v.kb_version,
                "content_sha256": v.content_sha256,
                "current": v.is_current,
                "previous": v.is_previous,
                "problem": v.problem,
            }
            for v in versions
        ]
        sys.stdout.write(json.dumps(rows, indent=1) + "\n")
    elif not versions:
        out.print(f"nothing installed in {into}", highlight=False, markup=False)
    for v in [] if as_json else versions:
        mark = "*" if v.is_current else "-" if v.is_previous else " "
        state = f"  [red]{escape(v.problem)}[/]" if v.problem else ""
        out.print(f"{escape(mark)} {escape(v.version)}{state}", highlight=False, soft_wrap=True)
    if any(v.problem for v in versions):
        raise typer.Exit(EXIT_CHECK_FAILED)

