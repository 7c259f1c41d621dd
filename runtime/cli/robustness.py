"""``craft eval robustness imagenet``: the ImageNet protocol under perceptual noise.

Thin command over ``runtime/evaluation/robustness.py``; prints the Markdown table, optionally
writes JSON, Markdown and a plot. Exit codes as for ``craft eval imagenet``: 0 ok, 2 bad input
(labels, levels, classes file, missing data).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .common import (
    AffModeOpt,
    BetaOpt,
    EnergyFormOpt,
    GammaOpt,
    JsonOpt,
    KbDirOpt,
    NoCacheOpt,
    TemperatureOpt,
    ThreadsOpt,
    checked_markdown_file,
    checked_plot_file,
    fail,
    note,
)
from .imagenet_inputs import CraftKbOpt, EpisodesOpt, LabelsOpt, SeedOpt, protocol_inputs


def robustness_imagenet(
    labels: LabelsOpt,
    kb: CraftKbOpt = None,
    kb_dir: KbDirOpt = None,
    levels: Annotated[list[str] | None, typer.Option(
        "--levels", help="KIND=L1,L2,... (repeatable; kinds: gaussian sigma, blur radius px, crop fraction cut "
                         "away). Default: gaussian=0,8,16,32,64 blur=0,1,2,4,8 crop=0,0.25,0.5,0.75.")] = None,
    episodes: EpisodesOpt = 100,
    seed: SeedOpt = 0,
    noise_seed: Annotated[int, typer.Option(min=0, help="First seed of the perturbations.")] = 0,
    noise_seeds: Annotated[int, typer.Option(min=1, help="Noise draws per level (seeds noise-seed, +1, ...), averaged.")] = 1,
    json_out: JsonOpt = None,
    plot: Annotated[Path | None, typer.Option(help="Write Top-1/MRR vs noise level (PNG).",
                                                          callback=checked_plot_file)] = None,
    markdown: Annotated[Path | None, typer.Option(help="Write the Markdown tables.", callback=checked_markdown_file)] = None,
    classes: Annotated[Path | None, typer.Option(help="Only draw episodes from these classes (one per line).")] = None,
    no_cache: NoCacheOpt = False,
    threads: ThreadsOpt = None,
    temperature: TemperatureOpt = None,
    aff_mode: AffModeOpt = "expected",
    beta: BetaOpt = None,
    gamma: GammaOpt = None,
    energy_form: EnergyFormOpt = None,
) -> None:
    """Top-1 / MRR of every method as Gaussian noise, blur and ROI crop jitter grow."""
    from ..evaluation.imagenet import LabelsError
    from ..evaluation.robustness import DEFAULT_LEVELS, evaluate_robustness, parse_levels
    from .common import emit

    given = protocol_inputs(kb, kb_dir, classes, no_cache, temperature, aff_mode, energy_form,
                            beta, gamma)
    try:
        chosen = parse_levels(levels) if levels else DEFAULT_LEVELS
    except ValueError as exc:
        fail(str(exc))
    try:
        report = evaluate_robustness(labels, levels=chosen, methods=given.methods, episodes=episodes, seed=seed,
                                     noise_seeds=range(noise_seed, noise_seed + noise_seeds), pool=given.pool,
                                     cache_dir=given.cache_dir, threads=threads, settings=given.settings)
    except (LabelsError, FileNotFoundError, ValueError) as exc:
        fail(str(exc))
    emit(report.to_markdown(), report.to_dict(), json_out, markdown, note)
    if plot is not None:
        report.plot(plot)
        note(f"wrote {plot}")
