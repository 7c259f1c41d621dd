"""``craft eval static``: the paper's static table (GT/predicted grasps × GT/predicted ROIs)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from . import episodes as ep
from .common import (
    AffModeOpt,
    AffNormOpt,
    BetaOpt,
    EnergyFormOpt,
    GammaOpt,
    fail,
    grounding_settings,
)


def eval_static(
    labels: Annotated[Path | None, typer.Option(help="CSV of affording pairs 'verb,object' "
                                                     "(default: artifacts/labels/sim_dev_labels.csv).")] = None,
    grasp: Annotated[list[str] | None, typer.Option(help="Grasp backend(s) of the Full Pipeline rows, "
                                                         "repeatable: grconvnet | ggcnn | ggcnn2 | antipodal.")] = None,
    layouts: ep.LayoutsOpt = 3,
    methods: ep.MethodsOpt = None,
    kb: ep.SceneKbOpt = None,
    kb_dir: ep.SceneKbDirOpt = None,
    noise: Annotated[list[str] | None, typer.Option(help="Extra noise level, repeatable: grasp=SIGMA and/or "
                                                         "box=FRACTION, e.g. --noise grasp=0.1,box=0.2.")] = None,
    json_out: ep.EpisodesJsonOpt = None,
    markdown: ep.TablesOpt = None,
    max_pairs: ep.MaxPairsOpt = None,
    seed: Annotated[int, typer.Option(min=0, help="Seed of target/distractor/layout sampling and noise.")] = 0,
    threads: ep.SceneThreadsOpt = 1,
    energy_form: EnergyFormOpt = None,
    aff_mode: AffModeOpt = "expected",
    aff_norm: AffNormOpt = None,
    beta: BetaOpt = None,
    gamma: GammaOpt = None,
    jobs: ep.JobsOpt = 1,
    size_cue: ep.SizeCueOpt = None,
    colour_cue: ep.ColourCueOpt = None,
    lookalikes: ep.LookalikesOpt = None,
    cavity_cue: ep.CavityCueOpt = None,
    hubness: ep.HubnessOpt = None,
    sense_weight: ep.SenseWeightOpt = None,
    conse_temperature: ep.ConseTemperatureOpt = None,
    classifier: ep.ClassifierOpt = None,
    in_view: ep.InViewOpt = True,
) -> None:
    """Rendered scenes, no execution: success = right ROI (IoU ≥ 0.5) and a correct grasp (Cornell)."""
    from ...paths import SIM_DEV_LABELS
    from ..evaluation.sim_eval import LabelsError
    from ..evaluation.static_eval import GRASP_BACKENDS, evaluate_static, parse_noise
    from ..sim.assets import SharedAssetsMissingError
    from ..sim.env import EnvConfig
    from ..sim.episode import in_view_layout
    from ..sim.placement import PlacementError

    labels_path = labels or SIM_DEV_LABELS
    try:
        levels = [parse_noise(n) for n in noise or []]
    except ValueError as exc:
        fail(str(exc))
    specs = ep.scene_methods(methods, kb, kb_dir, beta, gamma)
    backends = ep.split_names(grasp, "--grasp") or ["grconvnet"]
    unknown = [b for b in backends if b not in GRASP_BACKENDS]
    if unknown:  # before the scenes are drawn (the evaluation checked it only after ~17 s)
        fail(f"--grasp: unknown grasp backend(s) {', '.join(unknown)}; choose from {', '.join(GRASP_BACKENDS)}")
    ep.check_labels(labels_path)
    ep.check_classifier(classifier)
    settings = grounding_settings(energy_form=energy_form, aff_mode=aff_mode, aff_norm=aff_norm, size_cue=size_cue,
                                  colour_cue=colour_cue, lookalikes=lookalikes, cavity_cue=cavity_cue, hubness=hubness,
                                  sense_weight=sense_weight, conse_temperature=conse_temperature)
    ep.run_with_progress(
        lambda bar: evaluate_static(labels_path, backends=backends,
                                    layouts=layouts, seed=seed, methods=specs, max_pairs=max_pairs,
                                    noise=levels, threads=threads, settings=settings, progress=bar,
                                    jobs=jobs, classifier=classifier,
                                    env_config=EnvConfig(layout=in_view_layout(in_view))),
        "episodes", "scenes", json_out, markdown,
        (LabelsError, PlacementError, SharedAssetsMissingError, FileNotFoundError, ValueError, RuntimeError))
