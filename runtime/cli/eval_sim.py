"""``craft eval sim``: 3D, Detect and Grasp Rate of every method on the CR3 testbed."""

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
    grounding_settings,
)


def eval_sim(
    labels: Annotated[Path, typer.Option(help="CSV of affording pairs 'verb,object' (asset ids or plain names).")],
    grasp: Annotated[str, typer.Option(help="grconvnet | ggcnn | ggcnn2 | antipodal | oracle.")] = "grconvnet",
    rois: Annotated[str, typer.Option(help="predicted (RGB-D segmentation) | oracle (simulator masks).")] = "predicted",
    layouts: ep.LayoutsOpt = 3,
    methods: ep.MethodsOpt = None,
    kb: ep.SceneKbOpt = None,
    kb_dir: ep.SceneKbDirOpt = None,
    json_out: ep.EpisodesJsonOpt = None,
    markdown: ep.TablesOpt = None,
    max_pairs: ep.MaxPairsOpt = None,
    seed: Annotated[int, typer.Option(min=0, help="Seed of target/distractor/layout sampling.")] = 0,
    grasp_checks: Annotated[bool, typer.Option(help="Use only grasps whose section fits the opening and whose "
                                                    "pick is IK-feasible (best such grasp per ROI).")] = True,
    max_grasps: Annotated[int, typer.Option(min=1, help="Raw grasp candidates per ROI.")] = 5,
    threads: ep.SceneThreadsOpt = 1,
    energy_form: EnergyFormOpt = None,
    aff_mode: AffModeOpt = "expected",
    aff_norm: AffNormOpt = None,
    beta: BetaOpt = None,
    gamma: GammaOpt = None,
    jobs: ep.JobsOpt = 1,
    gripper: ep.GripperOpt = "panda",
    wrist_look: ep.WristLookOpt = True,
    refine_grasps: ep.RefineGraspsOpt = True,
    grasp_fallback: ep.GraspFallbackOpt = True,
    fallback_thin_centres: ep.FallbackThinCentresOpt = 32,
    clearance: ep.ClearanceOpt = False,
    relocate: ep.RelocateOpt = True,
    fine_collision: ep.FineCollisionOpt = True,
    landing_check: ep.LandingCheckOpt = True,
    retries: ep.RetriesOpt = 0,
    prefer_clear: ep.PreferClearOpt = False,
    active_look: ep.ActiveLookOpt = False,
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
    """The paper's real-world protocol in simulation: 1 target + 4 distractors, 3 layouts per pair."""
    # the settings and the labels first: the pipeline and the classifier check import torch and the
    # simulator, and --kb loads bundles (seconds, more on a cold or busy machine) before a typo was named
    settings = grounding_settings(energy_form=energy_form, aff_mode=aff_mode, aff_norm=aff_norm, size_cue=size_cue,
                                  colour_cue=colour_cue, lookalikes=lookalikes, cavity_cue=cavity_cue, hubness=hubness,
                                  sense_weight=sense_weight, conse_temperature=conse_temperature)
    ep.check_labels(labels)
    env_config, config = ep.pick_pipeline(grasp, rois, threads, gripper, wrist_look, clearance, fine_collision,
                                          landing_check, relocate, refine_grasps, grasp_fallback,
                                          prefer_clear=prefer_clear, grasp_checks=grasp_checks,
                                          max_grasps=max_grasps, active_look=active_look, in_view=in_view,
                                          fallback_thin_centres=fallback_thin_centres)
    specs = ep.scene_methods(methods, kb, kb_dir, beta, gamma)
    ep.check_classifier(classifier)
    from ..evaluation.methods import NoMethodToRunError
    from ..evaluation.sim_eval import LabelsError, evaluate_sim
    from ..grounding.size_cue import CueUnavailableError
    from ..sim.retry import RetryConfig

    ep.run_with_progress(
        lambda bar: evaluate_sim(labels, config=config, layouts=layouts, seed=seed, methods=specs,
                                 max_pairs=max_pairs, settings=settings, progress=bar, jobs=jobs,
                                 env_config=env_config, retry=RetryConfig(retries=retries),
                                 classifier=classifier),
        "episodes", "episodes", json_out, markdown,
        (LabelsError, CueUnavailableError, NoMethodToRunError, *ep.scene_errors()))
