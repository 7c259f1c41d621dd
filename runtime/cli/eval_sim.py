"""``craft eval sim``: 3D, Detect and Grasp Rate of every method on the CR3 testbed."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .common import AffModeOpt, EnergyFormOpt, fail, grounding_settings
from .episodes import run_with_progress, split_names


def eval_sim(
    labels: Annotated[Path, typer.Option(help="CSV of affording pairs 'verb,object' (asset ids or plain names).")],
    grasp: Annotated[str, typer.Option(help="grconvnet | ggcnn | ggcnn2 | antipodal | oracle.")] = "grconvnet",
    rois: Annotated[str, typer.Option(help="predicted (RGB-D segmentation) | oracle (simulator masks).")] = "predicted",
    layouts: Annotated[int, typer.Option(min=1, help="Layouts (scenes) per verb–target pair.")] = 3,
    methods: Annotated[list[str] | None, typer.Option(help="Methods to run, comma-separated or repeated "
                                                            "(default: CRAFT-E, CRAFT, direct-LLM, alignment-only).")] = None,
    kb: Annotated[Path | None, typer.Option(help="CRAFT-E bundle (default <kb-dir>/craft-e-default).")] = None,
    kb_dir: Annotated[Path | None, typer.Option(help="Folder of the bundles (craft-e-default/, conceptnet/, direct-llm/).")] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write results (with every episode) as JSON.")] = None,
    markdown: Annotated[Path | None, typer.Option(help="Write the Markdown tables.")] = None,
    max_pairs: Annotated[int | None, typer.Option(min=1, help="Only the first N verb–target pairs.")] = None,
    seed: Annotated[int, typer.Option(help="Seed of target/distractor/layout sampling.")] = 0,
    grasp_checks: Annotated[bool, typer.Option(help="Use only grasps whose section fits the opening and whose "
                                                    "pick is IK-feasible (best such grasp per ROI).")] = True,
    max_grasps: Annotated[int, typer.Option(min=1, help="Raw grasp candidates per ROI.")] = 5,
    threads: Annotated[int, typer.Option(min=1, help="Torch threads (grasp networks, image encoder).")] = 1,
    energy_form: EnergyFormOpt = None,
    aff_mode: AffModeOpt = "expected",
    jobs: Annotated[int, typer.Option(min=1, help="Worker processes for episodes (results byte-identical "
                                                  "to --jobs 1).")] = 1,
) -> None:
    """The paper's real-world protocol in simulation: 1 target + 4 distractors, 3 layouts per pair."""
    from craft_e.paths import KB_DIR
    from craft_e.runtime.evaluation.methods import select_methods
    from craft_e.runtime.evaluation.sim_eval import LabelsError, evaluate_sim
    from craft_e.runtime.sim.assets import SharedAssetsMissingError
    from craft_e.runtime.sim.pipeline import PipelineConfig
    from craft_e.runtime.sim.placement import PlacementError

    try:
        config = PipelineConfig(grasp=grasp, rois=rois, fit_filter=grasp_checks,  # type: ignore[arg-type]
                                ik_filter=grasp_checks, torch_threads=threads, max_grasps=max_grasps)
        specs = select_methods(split_names(methods), kb, kb_dir or KB_DIR)
    except ValueError as exc:
        fail(str(exc))
    settings = grounding_settings(energy_form=energy_form, aff_mode=aff_mode)
    run_with_progress(
        lambda bar: evaluate_sim(labels, config=config, layouts=layouts, seed=seed, methods=specs,
                                 max_pairs=max_pairs, settings=settings, progress=bar, jobs=jobs),
        "episodes", "episodes", json_out, markdown,
        (LabelsError, PlacementError, SharedAssetsMissingError, FileNotFoundError))
