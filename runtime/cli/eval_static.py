"""``craft eval static``: the paper's static table (GT/predicted grasps × GT/predicted ROIs)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .common import AffModeOpt, EnergyFormOpt, fail, grounding_settings
from .episodes import run_with_progress, split_names


def eval_static(
    labels: Annotated[Path | None, typer.Option(help="CSV of affording pairs 'verb,object' "
                                                     "(default: artifacts/labels/sim_dev_labels.csv).")] = None,
    grasp: Annotated[list[str] | None, typer.Option(help="Grasp backend(s) of the Full Pipeline rows, "
                                                         "repeatable: grconvnet | ggcnn | ggcnn2 | antipodal.")] = None,
    layouts: Annotated[int, typer.Option(min=1, help="Layouts (scenes) per verb–target pair.")] = 3,
    methods: Annotated[list[str] | None, typer.Option(help="Methods, comma-separated or repeated "
                                                            "(default: CRAFT-E, CRAFT, direct-LLM, alignment-only).")] = None,
    kb: Annotated[Path | None, typer.Option(help="CRAFT-E bundle (default <kb-dir>/craft-e-default).")] = None,
    kb_dir: Annotated[Path | None, typer.Option(help="Folder of the bundles.")] = None,
    noise: Annotated[list[str] | None, typer.Option(help="Extra noise level, repeatable: grasp=SIGMA and/or "
                                                         "box=FRACTION, e.g. --noise grasp=0.1,box=0.2.")] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write results (with every episode) as JSON.")] = None,
    markdown: Annotated[Path | None, typer.Option(help="Write the Markdown table.")] = None,
    max_pairs: Annotated[int | None, typer.Option(min=1, help="Only the first N verb–target pairs.")] = None,
    seed: Annotated[int, typer.Option(help="Seed of target/distractor/layout sampling and noise.")] = 0,
    threads: Annotated[int, typer.Option(min=1, help="Torch threads (grasp networks, image encoder).")] = 1,
    energy_form: EnergyFormOpt = None,
    aff_mode: AffModeOpt = "expected",
    jobs: Annotated[int, typer.Option(min=1, help="Worker processes for episodes (results byte-identical "
                                                  "to --jobs 1).")] = 1,
) -> None:
    """Rendered scenes, no execution: success = right ROI (IoU ≥ 0.5) and a correct grasp (Cornell)."""
    from craft_e.paths import KB_DIR, SIM_DEV_LABELS
    from craft_e.runtime.evaluation.methods import select_methods
    from craft_e.runtime.evaluation.sim_eval import LabelsError
    from craft_e.runtime.evaluation.static_eval import evaluate_static, parse_noise
    from craft_e.runtime.sim.assets import SharedAssetsMissingError
    from craft_e.runtime.sim.placement import PlacementError

    labels_path = labels or SIM_DEV_LABELS
    try:
        levels = [parse_noise(n) for n in noise or []]
        specs = select_methods(split_names(methods), kb, kb_dir or KB_DIR)
    except ValueError as exc:
        fail(str(exc))
    settings = grounding_settings(energy_form=energy_form, aff_mode=aff_mode)
    run_with_progress(
        lambda bar: evaluate_static(labels_path, backends=split_names(grasp) or ["grconvnet"],
                                    layouts=layouts, seed=seed, methods=specs, max_pairs=max_pairs,
                                    noise=levels, threads=threads, settings=settings, progress=bar,
                                    jobs=jobs),
        "episodes", "scenes", json_out, markdown,
        (LabelsError, PlacementError, SharedAssetsMissingError, FileNotFoundError, ValueError, RuntimeError))
