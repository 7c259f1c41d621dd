"""The robot's own path from one frame to one pick: IK only for the grasps grounding asks about.

``sim.perceive.perceive`` checks every ROI's grasps up front, finger fit and then the whole
pick's IK (~49 IK solutions a pick), because the evaluation reports each ROI's usable grasp.
A robot needs only the grasp it will execute. ``ground_lazily`` grounds with each ROI's best
grasp that fits the fingers (IK not yet known), plans the IK of the chosen ROI's grasp only,
and if that pick is unreachable moves the ROI on to its next fitting grasp (or drops it) and
grounds again.

The choice equals the eager one (``perceive`` + ``Grounder.ground``): an ROI's energy is its own
(``E_grasp = -log(score)`` of its best usable grasp plus terms of its crop alone), candidates are
tried best first, so an unverified ROI's energy can only rise once verified; the winner is
verified, and every other ROI's true energy is at least what it was ranked with. Stable ties
(lowest ROI index) are kept the same way. ``tests/test_choose.py`` checks it against the eager
path.

The grasp fallback (``sim/fallback.py``: the antipodal sampler's grasps, for an ROI the fingers
fit around none of the network's grasps on) is deferred the same way. Such an ROI is ranked as
if it had a perfect grasp (score 1, ``E_grasp = 0``; no fallback grasp scores more), which
cannot make it look worse than it is; only when that ranking chooses it does the sampler run
and the ROI take its first fitting grasp (or drop out), and grounding runs again.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt

from ..grounding.grounder import Grounding
from ..perception.roi import ROI
from .clearance import HeightMap
from .surface import RaisedPoints

if TYPE_CHECKING:
    from ..encoders.image import ImageEncoder
    from ..grasp.geometry import TopDownGrasp
    from ..perception.observation import Observation
    from ..perception.plane import Plane
    from ..perception.roi import Region
    from .candidates import GraspCandidate
    from .env import SimEnv
    from .episode import PlanCache
    from .pipeline import PipelineConfig


class _Grounds(Protocol):
    def ground(self, verb: str, rois: Sequence[ROI]) -> Grounding: ...


@dataclass
class LazyROI:
    """One ROI for lazy grounding: its fitting grasps best first and how far IK ruled them out."""

    box_xywh: tuple[float, float, float, float]
    embedding: npt.NDArray[np.float32]
    fitting: list[object]  # grasps that passed the finger check, best first (opaque here)
    scores: list[float]  # their scores, parallel to ``fitting``
    heights: HeightMap | None = None  # the other objects' surfaces, for the pick's clearance check
    extents_m: tuple[float, float, float] | None = None  # from depth, for the size cue
    colours: tuple[float, ...] | None = None  # colour shares of its pixels, for the colour cue
    classes: tuple[tuple[int, float], ...] | None = None  # top ImageNet classes, for the look-alike cue
    next_index: int = 0  # fitting[next_index] is the best grasp IK has not ruled out
    verified: set[int] = field(default_factory=set)  # indices IK accepted
    #: fitting grasps not checked yet, in order (``candidates.iter_fitting_with_refinements``):
    #: ``fitting`` grows from it only as far as grounding needs, so an ROI whose first grasp fits
    #: costs one finger check
    unchecked: Iterator[Any] | None = None
    #: for relocating a blocked chosen grasp (``relocate_choice``): the region's mask, its depth
    #: points above the table, the frame's raised pixels and their world points (one
    #: ``RaisedPoints`` shared by its ROIs: the height map of the other objects is made from it)
    #: and its raw network grasps (opaque here)
    mask: npt.NDArray[np.bool_] | None = None
    material: npt.NDArray[np.float64] | None = None
    raised: RaisedPoints | None = None
    raw: Sequence[Any] = ()
    region: Region | None = None  # the region itself, for the fallback's grasps (``sim/fallback.py``)
    #: the fallback's fitting grasps, best first, computed when called (``sim/fallback.py``): used
    #: only when no grasp of ``unchecked`` fits; None once called, or with no fallback
    fallback: Callable[[], Iterator[Any]] | None = None
    cavity_m: float | None = None  # how far its inside lies below its rim, for the cavity cue

    @property
    def pending_fallback(self) -> bool:
        """No network grasp fits and the fallback has not run: ranked with an optimistic score."""
        self._checked_through(0)
        return not self.fitting and self.fallback is not None

    def run_fallback(self) -> None:
        """Take the fallback's grasps as this ROI's list (the sampler runs now)."""
        assert self.fallback is not None and not self.fitting
        self.unchecked, self.fallback = self.fallback(), None

    def _checked_through(self, index: int) -> None:
        """Check grasps from ``unchecked`` until ``fitting[index]`` exists or none are left."""
        while len(self.fitting) <= index and self.unchecked is not None:
            grasp = next(self.unchecked, None)
            if grasp is None:
                self.unchecked = None
                break
            self.fitting.append(grasp)
            self.scores.append(float(grasp.quality))

    def as_roi(self, label: str) -> ROI:
        """The grounder's view: the best grasp not ruled out (none left: no grasp), or a perfect
        placeholder score while the fallback is pending."""
        if self.pending_fallback:
            return ROI(box_xywh=self.box_xywh, grasp_scores=[1.0], grasps=[None],
                       image_embedding=self.embedding, label=label, extents_m=self.extents_m,
                       colours=self.colours, classes=self.classes, cavity_m=self.cavity_m)
        self._checked_through(self.next_index)
        rest = self.next_index < len(self.fitting)
        return ROI(box_xywh=self.box_xywh,
                   grasp_scores=[self.scores[self.next_index]] if rest else [],
                   grasps=[self.fitting[self.next_index]] if rest else [],
                   image_embedding=self.embedding, label=label, extents_m=self.extents_m,
                   colours=self.colours, classes=self.classes, cavity_m=self.cavity_m)


@dataclass(frozen=True)
class LazyChoice:
    """The grounding of the last round, the chosen grasp and how many IK plans were made."""

    grounding: Grounding
    grasp: object | None
    plans: int


def ground_lazily(
    grounder: _Grounds, verb: str, rois: Sequence[LazyROI], reachable: Callable[[object], bool],
) -> LazyChoice:
    """Ground ``verb`` over ``rois``, checking ``reachable`` (the pick's IK) for chosen grasps
    only, until the chosen ROI's grasp is reachable or no ROI is left (see the module docstring).

    ``rois`` are advanced in place (their ``next_index``), so a second grounder on the same
    scene reuses what IK already ruled out; ``reachable`` is called once per grasp at most.
    """
    plans = 0
    while True:
        grounding = grounder.ground(verb, [r.as_roi(f"roi{i}") for i, r in enumerate(rois)])
        chosen = grounding.chosen
        if chosen is None:
            return LazyChoice(grounding, None, plans)
        roi = rois[chosen.index]
        if roi.pending_fallback:  # chosen on the placeholder: run the sampler and ground again
            roi.run_fallback()
            continue
        k = roi.next_index
        if k in roi.verified:
            return LazyChoice(grounding, roi.fitting[k], plans)
        plans += 1
        if reachable(roi.fitting[k]):
            roi.verified.add(k)
            return LazyChoice(grounding, roi.fitting[k], plans)
        roi.next_index += 1  # unreachable: its next fitting grasp (or none) and ground again


def perceive_for_pick(
    env: SimEnv, encoder: ImageEncoder, config: PipelineConfig, obs: Observation,
    *, timings: dict[str, float] | None = None, colours: bool = False, cavity: bool = False,
) -> list[LazyROI]:
    """``perceive_frame`` on the testbed's frame: the crops come from the scene camera's colour
    image ``config.rgb_scale`` times sharper (a render: simulator work, not timed) and heights
    are measured from the layout's table."""
    k = config.rgb_scale
    sharp = env.capture_rgb(k) if k > 1 else obs.rgb
    return perceive_frame(obs, sharp, env.scene.layout.table_z, encoder, config, timings=timings,
                          colours=colours, cavity=cavity)


def perceive_frame(
    obs: Observation, sharp: npt.NDArray[np.uint8], table_z: float, encoder: ImageEncoder,
    config: PipelineConfig, *, timings: dict[str, float] | None = None, colours: bool = False,
    cavity: bool = False, keep: npt.NDArray[np.bool_] | None = None, plane: Plane | None = None,
) -> list[LazyROI]:
    """What the robot computes before grounding: ROIs, one grasp-network pass, the crops'
    embeddings, and the finger check of every candidate (cheap, vectorised over the ROI's depth
    points); IK is left to ``ground_lazily``. Predicted ROIs and network grasps only (the
    oracle settings use the simulator's ground truth, which a robot does not have).

    Only the frame is read, never a simulator: ``runtime/frame.py`` runs this on a real camera's
    frames. ``sharp``: the same view's colour image at an integer multiple of the frame's size
    (``obs.rgb`` itself at 1x), which the crops come from; ``table_z``: the table's height in
    the frame's world coordinates.

    Both networks run as their inference rewrites (``grasp.fused``, ``encoders.fused``: the
    same maps and embeddings to float rounding, ~1.5-2x faster on CPU); ``perceive``, the
    evaluation's path, keeps the checkpoints' layer layout so published results reproduce.
    ``colours``: measure each ROI's colour shares (for a grounder with the opt-in colour cue);
    ``cavity``: each ROI's open cavity (the opt-in cavity cue's). ``keep``: the pixels where
    regions may be (``segment``'s; a real robot's workspace, ``frame.frame_keep``). ``plane``: the
    frame's table plane if already fitted (``segment``'s; ``frame.perceive`` fits it to check the frame).
    Sets this process's numpy BLAS to one thread (``runtime/blas.py``: its spinning threads
    slow torch)."""
    from ..blas import single_threaded_blas
    from ..encoders.conse import encode_with_classes
    from ..encoders.image import crop_box, inference_encoder
    from ..perception.extents import measure_extents
    from ..perception.segment import segment
    from .candidates import iter_fallback_fitting, iter_fitting_with_refinements, raw_candidates
    from .clearance import heights_around
    from .perceive import roi_cavity, roi_colours, torch_threads
    from .stages import timed_stage

    if config.grasp == "oracle" or config.rois == "oracle":
        raise ValueError("the robot's path has no oracle: use predicted ROIs and a grasp backend")
    if config.pick.clearance.prefer:
        raise ValueError("the robot's lazy path does not implement the clearance preference yet "
                         "(ClearanceConfig.prefer); use perceive")
    h, w = obs.shape
    k = sharp.shape[0] // h
    if k < 1 or sharp.shape != (k * h, k * w, 3):
        raise ValueError(f"the sharp colour image is {sharp.shape}; it must be the frame's {h}x{w} "
                         "times a whole number, with 3 channels")
    single_threaded_blas()
    with timed_stage(timings, "segment"):
        rois = segment(obs, config.segment, keep, plane).rois
    fast_encoder = inference_encoder(encoder)
    with torch_threads(config.torch_threads):
        with timed_stage(timings, "grasp_net"):
            raw = raw_candidates(None, obs, rois, [None] * len(rois), config, fused=True)
        with timed_stage(timings, "encode"):
            crops = [crop_box(sharp, tuple(v * k for v in roi.box_xywh)) for roi in rois]
            embeddings, classes = encode_with_classes(fast_encoder, crops)
    out: list[LazyROI] = []
    with timed_stage(timings, "finger_checks"):
        raised = RaisedPoints.of(obs, table_z, config.fingers.height_tolerance)
        for i, roi in enumerate(rois):
            material = raised.within(roi.mask)  # [m, 3]
            box = tuple(float(v) for v in roi.box_xywh)
            out.append(LazyROI((box[0], box[1], box[2], box[3]), np.asarray(embeddings[i], np.float32),
                               [], [], heights_around(raised, roi.mask, table_z, config.pick.clearance),
                               measure_extents(material, table_z),
                               roi_colours(obs.rgb, raised.mask, roi) if colours else None, classes[i],
                               unchecked=iter_fitting_with_refinements(raw[i], material, obs, table_z, config),
                               mask=roi.mask, material=material, raised=raised, raw=raw[i], region=roi,
                               fallback=(partial(iter_fallback_fitting, obs, roi, material, table_z, config)
                                         if config.uses_fallback else None),
                               cavity_m=roi_cavity(obs, raised.mask, roi, table_z) if cavity else None))
    return out


def pick_reachable(
    env: SimEnv, config: PipelineConfig, rois: Sequence[LazyROI], plans: PlanCache | None = None,
) -> Callable[[object], bool]:
    """``reachable`` for ``ground_lazily``: the whole pick's IK plan and its clearance from the
    other objects of the grasp's ROI (``plan_pick``), as ``perceive`` checks it (always True
    when ``config.ik_filter`` is off). ``plans`` keeps the plans made, for ``relocate_choice``."""
    from .candidates import GraspCandidate
    from .episode import plan_pick

    def heights_of(grasp: object) -> HeightMap | None:
        """The clearance heights of the ROI that holds ``grasp`` (its fitting list grows lazily)."""
        return next((r.heights for r in rois if any(g is grasp for g in r.fitting)), None)

    def reachable(grasp: object) -> bool:
        assert isinstance(grasp, GraspCandidate) and grasp.pose is not None
        return not config.ik_filter or plan_pick(env, grasp.pose, config.pick, heights_of(grasp), plans) is None

    return reachable


def relocate_choice(
    env: SimEnv, config: PipelineConfig, obs: Observation, roi: LazyROI, grasp: object,
    plans: PlanCache | None = None,
) -> tuple[object, str]:
    """The robot's side of ``pipeline.relocated_grasp``: the chosen ``grasp`` of ``roi``, moved
    along its object when the overhead depth shows its approach blocked (``sim/relocate.py``),
    and why ("" when clear; the grasp itself when the policy is off). The spots are tried in the
    evaluation's order: the network grasps after the chosen one come from the same
    ``with_refinements`` list ``perceive`` checks, so both paths move a grasp to the same spot.
    Costs one clearance check of the chosen pick when its approach is clear (and no IK plan,
    given the ``plans`` ``pick_reachable`` made)."""
    from .pipeline import relocate_candidate

    def search(mask: npt.NDArray[np.bool_], raised: RaisedPoints, material: npt.NDArray[np.float64],
               chosen: GraspCandidate, others: Iterator[TopDownGrasp]) -> tuple[GraspCandidate, str]:
        return relocate_candidate(env, obs, mask, raised, material, chosen, others, config, plans)

    return relocate_lazily(config, obs, env.scene.layout.table_z, roi, grasp, search)


def relocate_lazily(
    config: PipelineConfig, obs: Observation, table_z: float, roi: LazyROI, grasp: object,
    search: Callable[[npt.NDArray[np.bool_], RaisedPoints, npt.NDArray[np.float64], GraspCandidate,
                      Iterator[TopDownGrasp]], tuple[GraspCandidate, str]],
) -> tuple[object, str]:
    """``relocate_choice`` with the search given (``search(mask, raised, material, grasp,
    others)``, ``pipeline.relocate_search`` bound to a pick check): the testbed's plans the arm,
    a frame without a robot model checks the hand alone (``runtime/frame.py``). The region's
    other grasps are listed only when the search asks for them."""
    from .candidates import GraspCandidate, fallback_with_refinements, with_refinements

    assert isinstance(grasp, GraspCandidate) and grasp.pose is not None
    if not config.pick.clearance.relocate or roi.mask is None or roi.material is None or roi.raised is None:
        return grasp, ""
    chosen = grasp.pose

    def is_chosen(pose: TopDownGrasp) -> bool:  # the chosen grasp, as the evaluation's list holds it
        return bool(np.array_equal(pose.position, chosen.position)) and (pose.yaw, pose.width_m) == (
            chosen.yaw, chosen.width_m)

    def others() -> Iterator[TopDownGrasp]:  # only when the chosen grasp's own spots are all blocked
        assert roi.material is not None
        listed = with_refinements(list(roi.raw), roi.material, obs, table_z, config)
        if grasp.fallback and roi.region is not None:  # the evaluation listed the fallback's grasps too
            listed += fallback_with_refinements(obs, roi.region, roi.material, table_z, config)
        yield from (c.pose for c in listed if c.pose is not None and not is_chosen(c.pose))

    return search(roi.mask, roi.raised, roi.material, grasp, others())
