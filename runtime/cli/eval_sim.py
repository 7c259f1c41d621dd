"""``craft eval sim``: 3D, Detect and Grasp Rate of every method on the CR3 testbed."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Any

import typer

from .common import AffModeOpt, EnergyFormOpt, err, fail, grounding_settings


def split_names(values: list[str] | None) -> list[str] | None:
    """``--methods A,B --methods C`` → ``[A, B, C]`` (None when not given)."""
    if not values:
        return None
    return [n.strip() for v in values for n in v.split(",") if n.strip()]


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
    gripper: Annotated[str, typer.Option(help="Hand on the CR3: panda (Franka hand, default) | robotiq_2f85.")] = "panda",
    wrist_look: Annotated[bool, typer.Option(help="Re-centre each grasp from one wrist depth frame at "
                                                  "pre-grasp (closed-loop correction).")] = True,
) -> None:
    """The paper's real-world protocol in simulation: 1 target + 4 distractors, 3 layouts per pair."""
    from ...paths import KB_DIR
    from ..evaluation.common import emit_report
    from ..evaluation.methods import select_methods
    from ..evaluation.sim_eval import LabelsError, evaluate_sim
    from ..sim.assets import SharedAssetsMissingError
    from ..sim.episode import sim_configs
    from ..sim.pipeline import PipelineConfig
    from ..sim.placement import PlacementError

    try:
        env_config, pick = sim_configs(gripper, wrist_look)
        config = PipelineConfig(grasp=grasp, rois=rois, fit_filter=grasp_checks,  # type: ignore[arg-type]
                                ik_filter=grasp_checks, torch_threads=threads, max_grasps=max_grasps,
                                pick=pick)
        specs = select_methods(split_names(methods), kb, kb_dir or KB_DIR)
    except ValueError as exc:
        fail(str(exc))
    settings = grounding_settings(energy_form=energy_form, aff_mode=aff_mode)
    start = time.perf_counter()
    try:
        with ProgressBar() as bar:
            report = evaluate_sim(labels, config=config, layouts=layouts, seed=seed, methods=specs,
                                  max_pairs=max_pairs, settings=settings, progress=bar, jobs=jobs,
                                  env_config=env_config)
    except (LabelsError, PlacementError, SharedAssetsMissingError, FileNotFoundError) as exc:
        fail(str(exc))
    err.print(f"{report.config['episodes']} episodes in {time.perf_counter() - start:.0f} s", highlight=False)
    emit_report(report.to_markdown(), report.to_dict(), json_out, markdown,
                lambda msg: err.print(msg, highlight=False))


class ProgressBar:
    """A rich progress bar on stderr, usable as ``progress(done, total, record)``."""

    def __enter__(self) -> ProgressBar:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeRemainingColumn,
        )

        self._bar = Progress(TextColumn("[bold]episodes"), BarColumn(), MofNCompleteColumn(),
                             TimeRemainingColumn(), TextColumn("{task.description}"),
                             console=Console(stderr=True), transient=False)
        self._bar.__enter__()
        self._task = self._bar.add_task("", total=None)
        return self

    def __call__(self, done: int, total: int, record: dict[str, Any]) -> None:
        self._bar.update(self._task, completed=done, total=total, description=record.get("id", ""))

    def __exit__(self, *exc: object) -> None:
        self._bar.__exit__(None, None, None)
