"""What ``craft eval imagenet`` and ``craft eval robustness imagenet`` share: the protocol's
options and their resolution into methods, episode pool and embedding cache (written once)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from .common import grounding_settings, read_some_names

if TYPE_CHECKING:
    from ..evaluation.methods import MethodSpec
    from ..grounding.settings import GroundingSettings

LabelsOpt = Annotated[Path, typer.Option(help='Labels JSON {"verb": ["object", ...]}.')]
CraftKbOpt = Annotated[Path | None, typer.Option(help="CRAFT-E bundle (default artifacts/kb/craft-e-default).")]
EpisodesOpt = Annotated[int, typer.Option(min=1, help="Episodes per verb and setting.")]
SeedOpt = Annotated[int, typer.Option(min=0, help="Seed of the episode sampler.")]


@dataclass(frozen=True)
class ProtocolInputs:
    """The resolved options: every method's bundle, the class pool, the cache, the settings."""

    methods: list[MethodSpec]
    pool: list[str] | None
    cache_dir: Path | None
    settings: GroundingSettings


def protocol_inputs(
    kb: Path | None, kb_dir: Path | None, classes: Path | None, no_cache: bool,
    temperature: float | None, aff_mode: str, energy_form: str | None,
    beta: float | None = None, gamma: float | None = None, sense_weight: float | None = None,
    conse_temperature: float | None = None,
) -> ProtocolInputs:
    """Resolve the shared options (a bad value exits 2 naming it)."""
    from ...paths import KB_DIR
    from ..encoders.conse import ENCODER_CACHE_DIR
    from ..evaluation.methods import default_methods
    from .common import check_named_bundles

    # the classes and the settings first: a typo fails at once, not after the bundles (or the images) load
    pool = read_some_names(classes, "classes file", "--classes") if classes is not None else None
    settings = grounding_settings(temperature=temperature, aff_mode=aff_mode, energy_form=energy_form,
                                  sense_weight=sense_weight, conse_temperature=conse_temperature)
    check_named_bundles(kb, kb_dir)
    return ProtocolInputs(default_methods(kb, kb_dir or KB_DIR, beta=beta, gamma=gamma), pool,
                          None if no_cache else ENCODER_CACHE_DIR, settings)
