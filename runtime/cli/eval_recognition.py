"""``craft eval recognition``: how well the image encoder recognises the rendered sim assets."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .common import checked_markdown_file, checked_output_file
from .episodes import run_with_progress, scene_errors


def eval_recognition(
    views: Annotated[int, typer.Option(min=1, help="Renders per asset (seeded pose on the table).")] = 3,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the poses.")] = 0,
    threads: Annotated[int, typer.Option(min=1, help="Torch threads of the image encoder.")] = 1,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the table (and per-asset hits) as JSON.",
                                                                     callback=checked_output_file)] = None,
    markdown: Annotated[Path | None, typer.Option(help="Write the Markdown table.", callback=checked_markdown_file)] = None,
) -> None:
    """Recognition top-1/top-5 of the 74 rendered sim assets under each perception setting."""
    from ..evaluation.recognition import evaluate_recognition
    from ..kb.bundle import BundleError

    run_with_progress(lambda bar: evaluate_recognition(
        views, seed, threads=threads, progress=lambda d, t: bar(d, t, {"id": "rendering"})),
        "images", "images", json_out, markdown, (BundleError, *scene_errors()))
