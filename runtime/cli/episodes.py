"""What the episode-running commands share (``eval sim``, ``eval static``, ``eval recognition``,
``eval pickability``, ``sim demo``).

A progress bar on stderr, the ``--methods`` list, the pipeline behind the sim options
(``pick_pipeline``), and one runner that times the evaluation, turns its input errors into exit
code 2 and writes the report — written once, not per command.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Protocol

import typer

from .common import ConseTemperatureOpt as ConseTemperatureOpt
from .common import SenseWeightOpt as SenseWeightOpt
from .common import checked_jobs, checked_markdown_file, checked_output_file, err, fail, note

if TYPE_CHECKING:
    from ..evaluation.methods import MethodSpec
    from ..evaluation.sim_eval import SimLabels
    from ..sim.env import EnvConfig
    from ..sim.pipeline import PipelineConfig

LayoutsOpt = Annotated[int, typer.Option(min=1, help="Layouts (scenes) per verb–target pair.")]
MethodsOpt = Annotated[list[str] | None, typer.Option(
    help="Methods to run, comma-separated or repeated (default: CRAFT-E, CRAFT, direct-LLM, alignment-only).")]
SceneKbOpt = Annotated[Path | None, typer.Option(help="CRAFT-E bundle (default <kb-dir>/craft-e-default).")]
SceneKbDirOpt = Annotated[Path | None, typer.Option(
    help="Folder of the bundles (craft-e-default/, conceptnet/, direct-llm/).")]
EpisodesJsonOpt = Annotated[Path | None, typer.Option("--json", help="Write results (with every episode) as JSON.",
                                                      callback=checked_output_file)]
TablesOpt = Annotated[Path | None, typer.Option(help="Write the Markdown tables.", callback=checked_markdown_file)]
MaxPairsOpt = Annotated[int | None, typer.Option(min=1, help="Only the first N verb–target pairs.")]
SceneThreadsOpt = Annotated[int, typer.Option(min=1, help="Torch threads (grasp networks, image encoder).")]
JobsOpt = Annotated[int, typer.Option(min=1, callback=checked_jobs, help=(
    "Worker processes for episodes, at most one per CPU (results byte-identical to --jobs 1)."))]
ClassifierOpt = Annotated[str | None, typer.Option(
    help="ImageNet classifier of the ConSE image encoder: efficientnet-lite1 (default) | efficientnet-lite0 "
         "(reproduces runs from before 2026-12-04).", show_default=False)]


def check_classifier(name: str | None) -> None:
    """Refuse an unknown ``--classifier`` before anything is rendered (exit 2, naming the choices)."""
    from ..encoders.efficientnet import VARIANTS

    if name is not None and name not in VARIANTS:
        fail(f"--classifier {name!r}: choose one of {', '.join(VARIANTS)}")
# the hand and the pick, shared by `craft eval sim` and `craft sim demo`
GripperOpt = Annotated[str, typer.Option(help="Hand on the CR3: panda (Franka hand, default) | robotiq_2f85.")]
WristLookOpt = Annotated[bool, typer.Option(help="Re-centre each grasp from one wrist depth frame at "
                                                 "pre-grasp (closed-loop correction).")]
RefineGraspsOpt = Annotated[bool, typer.Option(help="Turn a network grasp the hand cannot close across, or move "
                                                    "it onto a vessel's wall, when that fits (sim/refine.py).")]
GraspFallbackOpt = Annotated[bool, typer.Option(help="Give a region whose network grasps the fingers fit "
                                                     "around none of the antipodal sampler's grasps, checked "
                                                     "the same way (sim/fallback.py).")]
FallbackThinCentresOpt = Annotated[int, typer.Option(
    min=0, help="Centres the fallback's sampler adds on each region's thin parts, where a handle is "
                "(sim/fallback.py); 0 reproduces runs from before 2026-12-07, session 43.")]
FineCollisionOpt = Annotated[bool, typer.Option(
    "--fine-collision/--shipped-collision",
    help="Objects whose shipped convex hulls fill an opening (a mug's mouth) collide through finer meshes "
         "(sim/collision_meshes.py); --shipped-collision reproduces runs from before.")]
LandingCheckOpt = Annotated[bool, typer.Option(
    help="Reject grasps whose open finger would come down on the object's own surface beside the opening "
         "(a mug's far rim or handle; sim/fingers.py).")]
RetriesOpt = Annotated[int, typer.Option(
    min=0, help="After a pick whose hand ends empty (missed, grip lost), try again on a fresh frame up to this "
                "many times (sim/retry.py); reported beside the single-attempt Grasp Rate, which it never changes.")]
ActiveLookOpt = Annotated[bool, typer.Option(
    help="Before choosing, look again at the two lowest-energy regions from a camera 0.35 m away at 45° "
         "(as an on-arm camera could) and ground with both views (sim/active_look.py; its encoder pass counts "
         "as robot time).")]
InViewOpt = Annotated[bool, typer.Option(
    help="Redraw a scene in which the overhead camera sees some settled object only in part (its pixels "
         "touch the image's edge), as a real testbed is set up in view; --no-in-view reproduces runs from "
         "before 2026-12-06.")]
PreferClearOpt = Annotated[bool, typer.Option(
    help="Use the clearance check as a preference: per region, the first grasp that passes the other checks "
         "with a clear approach, else the first that passes (never drops a region; sim/clearance.py).")]
SizeCueOpt = Annotated[bool | None, typer.Option(
    "--size-cue/--no-size-cue",
    help="Weigh p(o|r) by how well each ROI's extents, measured from depth, fit the objects' typical sizes "
         "(the bundle's object_sizes.json; grounding/size_cue.py). Default: on wherever every vocabulary "
         "object has a size; --size-cue requires it.", show_default=False)]
ColourCueOpt = Annotated[bool | None, typer.Option(
    "--colour-cue/--no-colour-cue",
    help="Weigh p(o|r) by how well each ROI's colours fit the objects' typical colours (the bundle's "
         "object_colours.json; grounding/colour_cue.py). Opt-in (off by default: it lowered Detect on the "
         "dev episodes, docs/recognition.md); --colour-cue requires colours for every vocabulary object.", show_default=False)]
LookalikesOpt = Annotated[bool | None, typer.Option(
    "--lookalikes/--no-lookalikes",
    help="Weigh p(o|r) by how well each ROI's top ImageNet classes fit the classes each object's photos get "
         "(the bundle's object_lookalikes.json; grounding/lookalike_cue.py). Opt-in (off by default: it did not "
         "make CRAFT-E choose better on the dev scenes, docs/recognition.md); --lookalikes requires look-alikes "
         "for every vocabulary object.",
    show_default=False)]
CavityCueOpt = Annotated[bool | None, typer.Option(
    "--cavity-cue/--no-cavity-cue",
    help="Weigh p(o|r) by whether each ROI shows an open hollow in the depth (its inside 2 cm or more below its "
         "rim) against the KB's 'is concave' weights (grounding/cavity_cue.py). Default: on for every bundle whose "
         "graph defines that property (CRAFT-E's; direct-LLM and ConceptNet ground without it); --no-cavity-cue "
         "reproduces runs from before the cue.",
    show_default=False)]
HubnessOpt = Annotated[bool | None, typer.Option(
    "--hubness/--no-hubness",
    help="Read p(o|r) from each cosine less half the object name's hubness, its mean cosine to its 10 nearest "
         "ImageNet class names (CSLS; grounding/hubness.py). Default: on for every bundle in ConSE's MiniLM text "
         "space; --no-hubness reproduces runs from before the correction.",
    show_default=False)]
RelocateOpt = Annotated[bool, typer.Option(
    help="Before a pick, move the chosen grasp a few cm along its object (or turn it) when the overhead depth "
         "shows its approach blocked, keeping it when no nearby spot is clear (sim/relocate.py); "
         "--no-relocate reproduces runs from before.")]
ClearanceOpt = Annotated[bool, typer.Option(help="Reject approaches whose arm or hand would touch another object the "
                                                 "overhead depth shows (sim/clearance.py; off: too strict as a filter).")]


class Report(Protocol):
    """What an evaluation returns: its config (with a count of what it ran) and two renderings."""

    config: dict[str, Any]

    def to_markdown(self) -> str: ...

    def to_dict(self) -> dict[str, Any]: ...


def split_names(values: list[str] | None, option: str = "--methods") -> list[str] | None:
    """``--methods A,B --methods C`` → ``[A, B, C]`` (None when not given); exit 2 on an empty
    name (``--methods ''``, ``CRAFT-E,,``): dropped silently, ``''`` ran the default methods, as
    if the option had not been given."""
    if not values:
        return None
    names = [n.strip() for v in values for n in v.split(",")]
    if not all(names):
        fail(f"{option} {','.join(values)!r}: an empty name (a blank value or a doubled comma); "
             "give each name, comma-separated, or leave the option out for the defaults")
    return names


def check_labels(path: Path) -> SimLabels:
    """The sim labels, or exit 2 on a labels file that does not parse, before any model loads
    or a progress bar is drawn (an evaluation reads it again; it is a few lines)."""
    from ..evaluation.sim_eval import LabelsError, load_sim_labels

    if looks_like_json(path):
        fail(f"{path}: sim labels are a CSV, not JSON (the {{\"verb\": [\"object\", ...]}} JSON is the format of "
             "`craft eval imagenet` and `craft eval kb`): a header line `verb,object`, then one affording pair "
             "per line, e.g. `cut,knife`; the object is a sim asset id or plain name (see "
             "artifacts/labels/sim_dev_labels.csv)")
    try:
        return load_sim_labels(path)
    except LabelsError as exc:
        fail(str(exc))


def looks_like_json(path: Path) -> bool:
    """Is ``path`` a JSON file given where a sim labels CSV belongs (its name ends in ``.json``,
    or its text starts with ``{`` or ``[``)? Read as CSV, it failed on a fragment of its first
    line (``'"sci' is neither a sim asset id...``) that did not say the format was wrong."""
    if path.suffix.lower() == ".json":
        return True
    try:
        with path.open("rb") as handle:
            head = handle.read(4096)
    except OSError:  # missing, a folder, unreadable: the labels reader names the problem
        return False
    return head.lstrip(b"\xef\xbb\xbf \t\r\n")[:1] in (b"{", b"[")


def scene_methods(methods: list[str] | None, kb: Path | None, kb_dir: Path | None,
                  beta: float | None = None, gamma: float | None = None) -> list[MethodSpec]:
    """``--methods``/``--kb``/``--kb-dir``/``--beta``/``--gamma`` as method specs, or exit 2
    naming the bad one."""
    from ...paths import KB_DIR
    from ..evaluation.methods import select_methods
    from .common import check_named_bundles

    check_named_bundles(kb, kb_dir)
    try:
        return select_methods(split_names(methods), kb, kb_dir or KB_DIR, beta=beta, gamma=gamma)
    except ValueError as exc:
        fail(str(exc))


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


def pick_pipeline(
    grasp: str, rois: str, threads: int, gripper: str, wrist_look: bool, clearance: bool, fine_collision: bool,
    landing_check: bool, relocate: bool, refine_grasps: bool, grasp_fallback: bool, *, prefer_clear: bool = False,
    grasp_checks: bool = True, max_grasps: int = 5, active_look: bool = False, in_view: bool = True,
    fallback_thin_centres: int | None = None,
) -> tuple[EnvConfig, PipelineConfig]:
    """The env and pipeline behind the sim commands' shared options (``eval sim``, ``eval
    pickability``, ``sim demo``), built one way; an invalid choice (an unknown gripper, grasp
    source or ROI source) exits 2 with the message. ``fallback_thin_centres`` None: the
    fallback's default."""
    from ..sim.active_look import ActiveLookConfig
    from ..sim.episode import sim_configs
    from ..sim.fallback import FallbackConfig
    from ..sim.pipeline import PipelineConfig
    from ..sim.refine import RefineConfig

    try:
        env_config, pick, fingers = sim_configs(gripper, wrist_look, clearance, fine_collision,
                                                 landing_check, prefer_clear, relocate, in_view)
        config = PipelineConfig(grasp=grasp, rois=rois, fit_filter=grasp_checks,  # type: ignore[arg-type]
                                ik_filter=grasp_checks, torch_threads=threads, max_grasps=max_grasps,
                                pick=pick, fingers=fingers, refine=RefineConfig(enabled=refine_grasps),
                                fallback=FallbackConfig(enabled=grasp_fallback) if fallback_thin_centres is None
                                else FallbackConfig(enabled=grasp_fallback, thin_centres=fallback_thin_centres),
                                active_look=ActiveLookConfig(enabled=active_look))
    except ValueError as exc:
        fail(str(exc))
    return env_config, config


def scene_errors() -> tuple[type[BaseException], ...]:
    """What building a scene raises on bad shared data or an impossible layout: an evaluation
    turns these into exit code 2 with the message (imported here, not at start-up)."""
    from ..sim.assets import SharedAssetsMissingError
    from ..sim.collision_meshes import CollisionMeshError
    from ..sim.masses import AssetMassError
    from ..sim.placement import PlacementError

    return (PlacementError, SharedAssetsMissingError, FileNotFoundError, AssetMassError, CollisionMeshError)


def run_with_progress(
    evaluate: Callable[[ProgressBar], Report], count: str, unit: str, json_out: Path | None,
    markdown: Path | None, errors: tuple[type[BaseException], ...] = (),
) -> Report:
    """Run ``evaluate(progress)`` under a progress bar; ``errors`` become exit code 2. Prints
    ``<config[count]> <unit> in N s`` and writes the Markdown table and JSON where asked."""
    from .common import emit

    start = time.perf_counter()
    try:
        with ProgressBar() as bar:
            report = evaluate(bar)
    except errors as exc:
        fail(str(exc))
    err.print(f"{report.config[count]} {unit} in {time.perf_counter() - start:.0f} s", highlight=False)
    emit(report.to_markdown(), report.to_dict(), json_out, markdown, note)
    return report
