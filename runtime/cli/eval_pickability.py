"""``craft eval pickability``: every testbed asset alone on the table, picked by the whole pipeline."""

from __future__ import annotations

from typing import Annotated

import typer

from . import episodes as ep
from .common import fail


def eval_pickability(
    assets: Annotated[list[str] | None, typer.Option(
        "--asset", help="An asset id or plain name of the sim catalogue, e.g. softball or marker (every marker); "
                        "repeatable; default: all 74.")] = None,
    grasp: Annotated[str, typer.Option(help="grconvnet | ggcnn | ggcnn2 | antipodal.")] = "grconvnet",
    layouts: Annotated[int, typer.Option(min=1, help="Seeded poses per asset.")] = 3,
    kb: ep.SceneKbOpt = None,
    kb_dir: ep.SceneKbDirOpt = None,
    json_out: ep.EpisodesJsonOpt = None,
    markdown: ep.TablesOpt = None,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the poses.")] = 0,
    threads: ep.SceneThreadsOpt = 1,
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
) -> None:
    """Each asset alone, picked as `craft eval sim` picks, choosing by E_grasp alone: what the pick loses."""
    from ..evaluation.methods import NoMethodToRunError
    from ..evaluation.pickability import (
        UnknownAssetError,
        check_assets,
        evaluate_pickability,
        pickability_method,
    )

    if grasp == "oracle":
        fail("--grasp oracle uses the simulator's ground truth: pickability measures the robot's own grasps; "
             "choose grconvnet, ggcnn, ggcnn2 or antipodal")
    env_config, config = ep.pick_pipeline(grasp, "predicted", threads, gripper, wrist_look, clearance,
                                          fine_collision, landing_check, relocate, refine_grasps, grasp_fallback,
                                          fallback_thin_centres=fallback_thin_centres)
    try:
        chosen = check_assets(assets or ())
    except UnknownAssetError as exc:
        fail(str(exc))
    method = pickability_method(kb, kb_dir)
    ep.run_with_progress(
        lambda bar: evaluate_pickability(chosen, config=config, layouts=layouts, seed=seed,
                                         env_config=env_config, method=method, progress=bar, jobs=jobs),
        "episodes", "episodes", json_out, markdown,
        (UnknownAssetError, NoMethodToRunError, *ep.scene_errors()))
