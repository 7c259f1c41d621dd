"""``craft eval zhu``: average precision of E_aff rankings on the Zhu et al. (2014) dev matrix."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from ...paths import KB_DIR, shared_dir
from .common import checked_markdown_file, checked_output_file, fail

DEFAULT_KBS = [KB_DIR / "craft-e-default", KB_DIR / "conceptnet", KB_DIR / "direct-llm"]


def eval_zhu(
    kb: Annotated[
        list[Path] | None, typer.Option(help="Bundle(s) to score (repeatable).")
    ] = None,
    matrix: Annotated[
        Path | None, typer.Option(help="Zhu CSV (default: shared affordance_dev).")
    ] = None,
    markdown: Annotated[
        Path | None, typer.Option(help="Write the Markdown table here.", callback=checked_markdown_file)
    ] = None,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Write per-affordance AP as JSON.", callback=checked_output_file)
    ] = None,
) -> None:
    """Per affordance, AP of ranking the dev objects by E_aff — every E_aff form per bundle."""
    from ..evaluation.zhu import (
        ZhuMatrixError,
        chance_ap,
        evaluate_bundle,
        markdown_table,
        read_zhu_matrix,
    )
    from ..grounding.energies import ENERGY_FORMS
    from ..kb.bundle import BundleError, load_bundle

    path = matrix or shared_dir() / "data/affordance_dev/zhu2014_affordance_matrix.csv"
    if not path.is_file():
        fail(f"{path}: Zhu matrix not found (set CRAFT_SHARED or pass --matrix)")
    try:
        data = read_zhu_matrix(path)
    except ZhuMatrixError as exc:
        fail(str(exc))
    columns: dict[str, dict[str, float]] = {"chance": chance_ap(data)}
    for folder in kb or DEFAULT_KBS:
        try:
            bundle = load_bundle(folder)
        except BundleError as exc:
            fail(str(exc))
        name = bundle.manifest.kb_name
        if name == "direct-llm":  # one pseudo-property per verb: both forms rank alike
            columns[name] = evaluate_bundle(bundle, data)
            continue
        for form in ENERGY_FORMS:
            columns[f"{name} ({form})"] = evaluate_bundle(bundle, data, form)
    table = markdown_table(columns)
    typer.echo(table)
    if markdown is not None:
        kbs = "".join(f" --kb {folder}" for folder in kb or [])
        outputs = f" --markdown {markdown}" + (f" --json {json_out}" if json_out else "")
        header = (
            "# Zhu et al. 2014 dev set: AP of ranking 62 objects by E_aff\n\n"
            f"Produced by `craft eval zhu{kbs}{outputs}` (columns: bundle and "
            "E_aff form; `chance` = positive rate).\n\n"
        )
        _write(markdown, header + table)
    if json_out is not None:
        _write(json_out, json.dumps(columns, indent=1, sort_keys=True) + "\n")


def _write(path: Path, text: str) -> None:
    """Write an output file, or exit 2 naming it (a read-only mount, a full disk: a traceback before)."""
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        fail(f"{path}: cannot write it ({exc.strerror or exc}); the table above is the whole result — "
             "give another path to keep it as a file")
