"""``craft eval imagenet``: Nguyen et al.'s ImageNet functional-grounding protocol."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .common import (
    AffModeOpt,
    BetaOpt,
    ConseTemperatureOpt,
    EnergyFormOpt,
    GammaOpt,
    JsonOpt,
    KbDirOpt,
    MarkdownOpt,
    NoCacheOpt,
    SenseWeightOpt,
    TemperatureOpt,
    ThreadsOpt,
    fail,
    note,
)
from .imagenet_inputs import CraftKbOpt, EpisodesOpt, LabelsOpt, SeedOpt, protocol_inputs


def eval_imagenet(
    labels: LabelsOpt,
    kb: CraftKbOpt = None,
    episodes: EpisodesOpt = 100,
    seed: SeedOpt = 0,
    json_out: JsonOpt = None,
    markdown: MarkdownOpt = None,
    kb_dir: KbDirOpt = None,
    temperature: TemperatureOpt = None,
    aff_mode: AffModeOpt = "expected",
    beta: BetaOpt = None,
    gamma: GammaOpt = None,
    energy_form: EnergyFormOpt = None,
    no_cache: NoCacheOpt = False,
    threads: ThreadsOpt = None,
    sense_weight: SenseWeightOpt = None,
    conse_temperature: ConseTemperatureOpt = None,
    classes: Annotated[Path | None, typer.Option(help="Only draw episodes from these classes (file, one per line); "
                                                       "they are also the p(o|r) vocabulary.")] = None,
) -> None:
    """Nguyen et al.'s ImageNet functional-grounding protocol: every method on the same episodes."""
    from ..evaluation.imagenet import evaluate_imagenet
    from ..kb.bundle import BundleError
    from .common import emit

    given = protocol_inputs(kb, kb_dir, classes, no_cache, temperature, aff_mode, energy_form,
                            beta, gamma, sense_weight, conse_temperature)
    try:
        report = evaluate_imagenet(labels, methods=given.methods, episodes=episodes, seed=seed, pool=given.pool,
                                   cache_dir=given.cache_dir, settings=given.settings, threads=threads)
    # ValueError: LabelsError and NoMethodToRunError, and what a bundle that loads but cannot ground
    # raises from the Grounder (e.g. a malformed open_world.json), which names the file and the fix
    except (ValueError, FileNotFoundError, BundleError) as exc:
        fail(str(exc))
    emit(report.to_markdown(), report.to_dict(), json_out, markdown, note)
