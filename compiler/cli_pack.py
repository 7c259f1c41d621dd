"""``craftc pack`` and ``craftc keygen``: thin commands over :mod:`craft_e.compiler.pack`.

Kept out of ``cli.py`` so the packaging commands can be registered (``register(app)``) without
the main CLI importing PyNaCl at start-up. Exit codes follow ``craftc``: 1 when the bundle does
not verify, 2 for bad input (missing or malformed key, existing key on keygen).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from ..runtime.cli.common import EXIT_CHECK_FAILED, err, fail
from ..runtime.cli.common import out as console


def _given_path(text: str) -> Path:
    """``--out``'s parser: an empty value is refused, not read as the working directory (a
    ``--out "$UNSET"`` would otherwise write keys or a package wherever the command ran)."""
    if not text.strip():
        raise typer.BadParameter("empty path; give a path (nothing was written)")
    return Path(text)


def pack(
    bundle: Annotated[Path, typer.Argument(help="Bundle folder (built by craftc build).")],
    key: Annotated[Path, typer.Option("--key", help="Signing key (craft-signing.key).")],
    out: Annotated[
        Path, typer.Option("--out", "-o", parser=_given_path, help="Output file, e.g. kb.craft.")
    ],
    compression: Annotated[str, typer.Option(help="gzip (default) | none.")] = "gzip",
) -> None:
    """Pack a bundle folder into one signed .craft file for shipping to robots."""
    from .pack import PackError, UnverifiedBundleError, pack_bundle

    if compression not in ("gzip", "none"):
        fail(f"unknown compression {compression!r}; use gzip or none")
    try:
        result = pack_bundle(
            bundle, key, out, compression="gzip" if compression == "gzip" else "none"
        )
    except UnverifiedBundleError as exc:
        fail(str(exc), EXIT_CHECK_FAILED)
    except PackError as exc:
        fail(str(exc))
    for note in result.notes:
        err.print(f"[yellow]warning:[/] {escape(note)}", highlight=False, soft_wrap=True)
    s = result.statement
    console.print(
        f"packed [bold]{escape(s.kb_name)}[/] {s.kb_version} -> {escape(str(result.out))} ({result.bytes} bytes)\n"
        f"  content sha256 {s.content_sha256}\n"
        f"  signed by key {result.key_id}",
        highlight=False,
        soft_wrap=True,
    )


def keygen(
    out: Annotated[
        Path, typer.Option("--out", parser=_given_path, help="Folder for craft-signing.key/.pub.")
    ],
) -> None:
    """Create an Ed25519 signing key pair (private key mode 0600; never commit it)."""
    from .pack import PackError
    from .pack import keygen as make_keys

    try:
        pair = make_keys(out)
    except PackError as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"{out}: cannot write keys ({exc})")
    console.print(
        f"wrote {pair.private_key} (private: keep it secret, mode 0600)\n"
        f"wrote {pair.public_key} (public: copy to robots, pass as --trusted-key)\n"
        f"  key id {pair.key_id}",
        highlight=False,
        markup=False,
        soft_wrap=True,
    )


def register(app: typer.Typer) -> None:
    """Add ``pack`` and ``keygen`` to the ``craftc`` app."""
    app.command("pack")(pack)
    app.command("keygen")(keygen)
