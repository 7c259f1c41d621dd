"""Options that more than one ``craftc`` command module takes (``cli.py``, ``cli_diagnose.py``),
defined once so the commands that read a bundle take a signed package the same way."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..runtime.cli.common import fail

TrustedKeyOpt = Annotated[
    list[Path] | None,
    typer.Option(
        "--trusted-key",
        help="Signer's public key file (craft-signing.pub) when a bundle is a packed .craft file; "
        "repeatable.",
    ),
]


def trusted_keys(keys: list[Path] | None) -> list[str] | None:
    """``--trusted-key`` files for ``load_bundle``: a packed bundle (.craft) is read only when one
    of them signed it. A key that cannot be read or is no public key is bad usage (exit 2), not a
    bundle that failed its check, so each is read here first."""
    from ..runtime.kb.package import PackageError, parse_public_key

    for key in keys or []:
        try:
            parse_public_key(str(key))
        except PackageError as exc:
            fail(f"--trusted-key {key}: {exc}")
    return [str(k) for k in keys] if keys else None
