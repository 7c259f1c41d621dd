"""``craft eval imagenet``: Nguyen et al.'s ImageNet functional-grounding protocol."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .common import (
    AffModeOpt,
    EnergyFormOpt,
    JsonOpt,
    KbDirOpt,
    MarkdownOpt,
    NoCacheOpt,
    TemperatureOpt,
    ThreadsOpt,
    fail,
    grounding_settings,
    note,
    read_names,
)


def eval_imagenet(
    labels: Annotated[Path, typer.Option(help='Labels JSON {"verb": ["object", ...]}.')],
    kb: Annotated[Path | None, typer.Option(help="CRAFT-E bundle (default artifacts/kb/craft-e-default).")] = None,
    episodes: Annotated[int, typer.Option(min=1, help="Episodes per verb and setting.")] = 100,
    seed: Annotated[int, typer.Option(help="Seed of the episode sampler.")] = 0,
    json_out: JsonOpt = None,
    markdown: MarkdownOpt = None,
    kb_dir: KbDirOpt = None,
    temperature: TemperatureOpt = None,
    aff_mode: AffModeOpt = "expected",
    energy_form: EnergyFormOpt = None,
    no_cache: NoCacheOpt = False,
    threads: ThreadsOpt = None,
    classes: Annotated[Path | None, typer.Option(help="Only draw episodes from these classes (file, one per line); "
                                                       "they are also the p(o|r) vocabulary.")] = None,
) -> None:
    """Nguyen et al.'s ImageNet functional-grounding protocol: every method on the same episodes."""
    from ...paths import KB_DIR
    from ..encoders.conse import ENCODER_CACHE_DIR
    from ..evaluation.common import emit_report
    from ..evaluation.imagenet import LabelsError, evaluate_imagenet
    from ..evaluation.methods import default_methods

    settings = grounding_settings(temperature=temperature, aff_mode=aff_mode, energy_form=energy_form)
    pool = read_names(classes, "classes file") if classes is not None else None
    try:
        report = evaluate_imagenet(
            labels, methods=default_methods(kb, kb_dir or KB_DIR), episodes=episodes, seed=seed, pool=pool,
            cache_dir=None if no_cache else ENCODER_CACHE_DIR, settings=settings, threads=threads)
    except (LabelsError, FileNotFoundError) as exc:
        fail(str(exc))
    emit_report(report.to_markdown(), report.to_dict(), json_out, markdown, note)
