"""One testbed episode end to end: capture → ROIs → grasps → ground → execute → outcome.

The scene is perceived once and every grounding method is scored on that same perception; only
grounding and execution differ between methods. Execution always restarts from one saved physics
state (``p.saveState`` right after the scene settled, the arm teleported home), and a pick is
simulated once per distinct chosen ROI: methods that choose the same region get the same result,
which the determinism of the simulator would give anyway.

Stages and the robot-side choices made in them (all use only what a real robot has: the image,
the depth, the predicted mask, its own kinematics):

1. **ROIs**: ``predicted`` (class-agnostic RGB-D segmentation) or ``oracle`` (the simulator's
   segmentation buffer, one ROI per visible object).
2. **Grasps** per ROI: a grasp network (``grconvnet``, ``ggcnn``, ``ggcnn2``) run once per scene
   over the crop holding every ROI, each ROI taking the peaks of the shared maps on its mask
   (``grasp.predict.predict_grasps_rois``); or the analytic ``antipodal`` sampler restricted to
   the ROI mask, or the ``oracle`` grasp of the body the ROI covers most. Each rectangle becomes
   a top-down pose through the depth and the intrinsics.
3. **Grasp checks** (on by default; ``PipelineConfig.fit_filter`` / ``ik_filter``): best-scoring
   first, keep the first grasp under which the object fits the open fingers (``finger_check``:
   the section of the ROI's depth surface above the finger tips, across a pad-wide strip) and
   whose whole pick (pre-grasp, descent, lift, transport, release) has IK solutions. Its score is
   the ROI's grasp confidence, so ``E_grasp = -log(score)`` is the energy of a grasp the robot
   can execute; an ROI with no such grasp is excluded from grounding, as the paper prescribes.
   When the fingers fit around none of a network's grasps on an ROI (no peak at all on a dice,
   only sections wider than the hand), the antipodal sampler's grasps on the ROI are checked the
   same way (``fallback.py``; ``PipelineConfig.fallback``).
   ``perceive`` checks every ROI (the evaluation reports each one's usable grasp); the robot's
   own path (``sim.choose``) plans IK only for the grasps grounding chooses, with the same result.
4. **Embeddings** of the ROI crops (the ConSE image encoder), then ``Grounder.ground(verb, rois)``
   per method over the scene vocabulary (the plain names of the 74 sim objects).
5. **Execution** of the chosen ROI's grasp with ``execute_pick``, judged from physics.

Metrics, per episode:

* **3D**: the grasp module returned a *viable* grasp on the target: the predicted ROI matching the
  target (box IoU >= 0.5 with the target's ground-truth box; best such ROI) has a raw grasp
  candidate whose centre pixel lies on the target's ground-truth mask, that passes
  ``finger_check`` on the target's ground-truth surface (its true mask, not the ROI's), and whose
  pick is IK-feasible. Method-independent: perception is shared.
* **Detect** (per method): the chosen ROI's box has IoU >= 0.5 with the target's ground-truth box.
* **Grasp Rate** (per method): Detect and the executed pick ends in ``success`` (target lifted,
  carried and at rest in the drop zone). A pick is not executed when Detect fails: the paper
  counts a wrong region as a failure whatever the arm would do next.

Failure classes (root cause first): ``no_target_roi`` (perception produced no region for the
target), ``no_grasp`` (the target's region had no usable grasp, so grounding could not choose
it), ``wrong_object`` (grounding chose another region), then the pick's own outcomes
(``ik_failure``, ``missed``, ``lift_failed``, ``lifted_other_body``, ``slip_during_transport``,
``outside_drop_zone``).

Determinism: physics runs by step counts, torch runs with a fixed thread count, the segmenter and
the antipodal sampler are seeded, and no wall-clock value enters a result.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum
from functools import cache, partial
from typing import Any, Literal, get_args

import numpy as np
import numpy.typing as npt
import pybullet as p

from ..encoders.image import ImageEncoder
from ..grasp.geometry import Grasp2D, TopDownGrasp, pose_to_rect, rect_to_pose
from ..grounding.grounder import Grounder, Grounding, RankedROI
from ..perception.cavity import measure_cavity
from ..perception.colours import measure_colours
from ..perception.extents import measure_extents
from ..perception.observation import Observation
from ..perception.roi import ROI, Region, box_iou
from ..perception.segment import SegmentConfig, segment
from .active_look import ActiveLook, ActiveLookConfig
from .assets import object_catalog
from .clearance import HeightMap, heights_around, heights_excluding
from .env import SimEnv
from .episode import Outcome, PickConfig, PickResult, PlanCache, execute_pick, pick_problems
from .fallback import FallbackConfig, fallback_grasps
from .fingers import FingerGeometry as FingerGeometry
from .fingers import SurfacePoints
from .fingers import finger_check as finger_check
from .oracle import gt_rois, oracle_grasp
from .refine import RefineConfig
from .retry import Attempt, RetryConfig, hand_empty, return_home, same_grasp
from .scene import Scene, SceneSpec
from .stages import timed_stage
from .surface import RaisedPoints, object_centre

FloatArray = npt.NDArray[np.float64]
BoolMask = npt.NDArray[np.bool_]

GraspSource = Literal["grconvnet", "ggcnn", "ggcnn2", "antipodal", "oracle"]
RoiSource = Literal["predicted", "oracle"]
GRASP_SOURCES: tuple[str, ...] = get_args(GraspSource)
NETWORK_SOURCES = ("grconvnet", "ggcnn", "ggcnn2")
ROI_SOURCES: tuple[str, ...] = get_args(RoiSource)


class Failure(StrEnum):
    """Why an episode did not succeed (``success`` when it did); see the module docstring."""

    SUCCESS = "success"
    NO_TARGET_ROI = "no_target_roi"
    NO_GRASP = "no_grasp"
    WRONG_OBJECT = "wrong_object"
    IK_FAILURE = "ik_failure"
    MISSED = "missed"
    LIFT_FAILED = "lift_failed"
    LIFTED_OTHER_BODY = "lifted_other_body"
    SLIP_DURING_TRANSPORT = "slip_during_transport"
    OUTSIDE_DROP_ZONE = "outside_drop_zone"


PICK_FAILURES: dict[Outcome, Failure] = {
    Outcome.SUCCESS: Failure.SUCCESS,
    Outcome.NO_GRASP: Failure.NO_GRASP,
    Outcome.IK_FAILURE: Failure.IK_FAILURE,
    Outcome.MISSED: Failure.MISSED,
    Outcome.LIFT_FAILED: Failure.LIFT_FAILED,
    Outcome.WRONG_OBJECT: Failure.LIFTED_OTHER_BODY,  # physics: the hand lifted another body
    Outcome.SLIP_DURING_TRANSPORT: Failure.SLIP_DURING_TRANSPORT,
    Outcome.OUTSIDE_DROP_ZONE: Failure.OUTSIDE_DROP_ZONE,
}


@dataclass(frozen=True)
class PipelineConfig:
    """Choices of one evaluation run; a frozen value so reports can record it."""

    grasp: GraspSource = "grconvnet"
    rois: RoiSource = "predicted"
    max_grasps: int = 5  # raw candidates per ROI
    min_quality: float = 0.2  # the networks' peak threshold (as in the originals)
    fit_filter: bool = True  # keep only grasps whose object section fits the opening (finger_check)
    ik_filter: bool = True  # keep only grasps whose whole pick is IK-feasible
    detect_iou: float = 0.5
    torch_threads: int = 1  # fixed, for speed on small hosts and bit-identical results
    rgb_scale: int = 2  # crops come from a colour image this many times sharper (docs/recognition.md)
    fingers: FingerGeometry = field(default_factory=FingerGeometry)
    pick: PickConfig = field(default_factory=PickConfig)
    segment: SegmentConfig = field(default_factory=SegmentConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)  # turn / move misfitting grasps (refine.py)
    #: antipodal grasps for a region no network grasp fits (fallback.py; network sources only)
    fallback: FallbackConfig = field(default_factory=FallbackConfig)
    #: a second, closer view of the top candidates before the choice (active_look.py; opt-in)
    active_look: ActiveLookConfig = field(default_factory=ActiveLookConfig)

    def __post_init__(self) -> None:
        if self.grasp not in GRASP_SOURCES:
            raise ValueError(f"grasp source {self.grasp!r}: choose one of {', '.join(GRASP_SOURCES)}")
        if self.rois not in ROI_SOURCES:
            raise ValueError(f"ROI source {self.rois!r}: choose one of {', '.join(ROI_SOURCES)}")

    def to_dict(self) -> dict[str, Any]:
        looked = {"active_look": self.active_look.to_dict()} if self.active_look.enabled else {}
        return {
            "grasp": self.grasp,
            "rois": self.rois,
            "max_grasps": self.max_grasps,
            "min_quality": self.min_quality,
            "fit_filter": self.fit_filter,
            "ik_filter": self.ik_filter,
            "detect_iou": self.detect_iou,
            "torch_threads": self.torch_threads,
            "rgb_scale": self.rgb_scale,
            "refine_grasps": self.refine.enabled,
            "grasp_fallback": self.uses_fallback,
            "fallback_clearance_m": self.fallback.clearance(self.fingers.clearance) if self.uses_fallback else None,
            **looked,  # only when on: the default runs' records stay as published
        }

    @property
    def uses_fallback(self) -> bool:
        """Whether regions no network grasp fits get the antipodal fallback: only a
        grasp network has one (the antipodal and oracle sources are their own), and only with
        the grasp checks on (they decide what "usable" means)."""
        return self.fallback.enabled and self.grasp in NETWORK_SOURCES and self.fit_filter


@cache
def sim_vocabulary() -> tuple[str, ...]:
    """The scene's object vocabulary for ``p(o | r)``: every sim object's plain name, sorted.

    A robot does not know which objects are on its table, only which it might meet; the catalog
    is that set (62 distinct names for 74 assets).
    """
    return tuple(sorted({a.name for a in object_catalog().values()}))


# ---------------------------------------------------------------------------------------------
# perception


@dataclass(frozen=True)
class GraspCandidate:
    """One raw grasp of an ROI: the image rectangle, its world pose, and the robot's checks.

    ``fits``/``reachable`` are None when not checked (checks stop at the first usable grasp).
    """

    rect: Grasp2D
    pose: TopDownGrasp | None  # None: no valid depth under the centre
    fits: bool | None = None
    reachable: bool | None = None
    detail: str = ""
    blocked: str | None = None  # ClearanceConfig.prefer: what the approach of a passing grasp would touch
    fallback: bool = False  # from the antipodal fallback (sim/fallback.py), not the network

    @property
    def quality(self) -> float:
        return float(self.rect.quality)


@dataclass(frozen=True)
class PerceivedROI:
    """An ROI with its grasps, the grasp the robot would use, and its image embedding."""

    roi: Region
    candidates: tuple[GraspCandidate, ...]  # raw, best first
    usable: tuple[GraspCandidate, ...]  # what grounding sees (best first)
    embedding: npt.NDArray[np.float32]
    body: int | None  # the scene body the mask covers most (diagnostics only, never grounding)
    target_iou: float  # box IoU with the target's ground-truth box
    #: box edges from depth, metres, longest first (``perception/extents.py``; the size cue)
    extents_m: tuple[float, float, float] | None = None
    #: colour shares of its raised pixels (``perception/colours.py``; the colour cue)
    colours: tuple[float, ...] | None = None
    #: the classifier's top ImageNet classes on its crop (``encode_with_classes``; the look-alike cue)
    classes: tuple[tuple[int, float], ...] | None = None
    #: how far its inside lies below its rim, metres (``perception/cavity.py``; the cavity cue)
    cavity_m: float | None = None


@dataclass(frozen=True)
class ScenePerception:
    """Everything perceived once per episode and shared by all methods."""

    obs: Observation
    rois: tuple[PerceivedROI, ...]
    target_body: int
    target_box: tuple[int, int, int, int] | None  # None: the target is not visible
    target_roi: int | None  # index of the ROI that is the target (best IoU >= detect_iou)
    three_d: bool
    three_d_detail: str
    #: the frame's raised pixels and world points, made once here: the grasp checks read them,
    #: and the release aims the chosen region's centre (``surface.object_centre``) at the zone
    raised: RaisedPoints


@contextlib.contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run a block with ``n`` torch intra-op threads (restored afterwards)."""
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def raster_order(rois: Sequence[Region]) -> list[Region]:
    """ROIs sorted by their first pixel in raster order, as the segmenter returns them.

    ``gt_rois`` lists the target first (scene order); grounding must not get that hint, not even
    through the stable tie-breaking of its ranking.
    """
    return sorted(rois, key=lambda r: int(np.argmax(r.mask.reshape(-1))))


def majority_body(obs: Observation, mask: BoolMask, bodies: Sequence[int]) -> int | None:
    """The scene body with the most pixels under ``mask`` (None if it covers none)."""
    if obs.seg is None:
        return None
    labels = obs.seg[mask]
    counts = {b: int(np.count_nonzero(labels == b)) for b in bodies}
    best = max(counts, key=lambda b: (counts[b], -b), default=None)
    return best if best is not None and counts[best] > 0 else None


def tip_height(pose: TopDownGrasp, pick: PickConfig, table_z: float) -> float:
    """Height of the finger tips at the grasp, as ``execute_pick`` will place them."""
    from .robot_urdf import FINGERTIP_BELOW_TCP

    tcp = max(float(pose.position[2]) - pick.insertion_depth,
              table_z + FINGERTIP_BELOW_TCP + pick.table_clearance)
    return tcp - FINGERTIP_BELOW_TCP


def _oracle_rect(
    scene: Scene, obs: Observation, body: int, mask: BoolMask
) -> list[tuple[Grasp2D, TopDownGrasp]]:
    """The oracle grasp of ``body`` as a rectangle (quality 1) if its centre lies on ``mask``."""
    pose = oracle_grasp(scene, body)
    if pose is None:
        return []
    rect = pose_to_rect(pose, obs.intrinsics, obs.cam_to_world, quality=1.0)
    h, w = mask.shape
    col = min(max(round(rect.center_xy[0]), 0), w - 1)
    row = min(max(round(rect.center_xy[1]), 0), h - 1)
    return [(rect, pose)] if mask[row, col] else []


def _with_poses(obs: Observation, rects: Sequence[Grasp2D]) -> list[GraspCandidate]:
    """Candidates with their world poses (None where the centre has no valid depth)."""
    out: list[GraspCandidate] = []
    for rect in rects:
        try:
            pose: TopDownGrasp | None = rect_to_pose(rect, obs.depth, obs.intrinsics, obs.cam_to_world)
        except ValueError:
            pose = None
        out.append(GraspCandidate(rect, pose))
    return out


def raw_candidates(
    scene: Scene, obs: Observation, rois: Sequence[Region], bodies: Sequence[int | None],
    config: PipelineConfig, *, fused: bool = False,
) -> list[list[GraspCandidate]]:
    """Grasp candidates of every ROI, best first, with their world poses.

    A grasp network runs once over the crop holding all the ROIs and each ROI takes the peaks
    of the shared maps on its mask (``predict_grasps_rois``; ``fused``: its inference rewrite,
    ``grasp.fused``); the oracle is asked per body.
    """
    if config.grasp == "oracle":
        return [[] if body is None else
                 [GraspCandidate(r, pose) for r, pose in _oracle_rect(scene, obs, body, roi.mask)]
                 for roi, body in zip(rois, bodies, strict=True)]
    from ..grasp.predict import predict_grasps_rois

    rects = predict_grasps_rois(
        config.grasp, obs.rgb, obs.depth, [roi.mask for roi in rois], config.max_grasps,
        intrinsics=obs.intrinsics, min_quality=config.min_quality, fused=fused,
    )
    return [_with_poses(obs, r) for r in rects]


def fallback_candidates(obs: Observation, roi: Region, config: PipelineConfig) -> list[GraspCandidate]:
    """The antipodal fallback's grasps on one region (``sim/fallback.py``), best first; empty when
    the config has no fallback."""
    if not config.uses_fallback:
        return []
    x, y, w, h = roi.box_xywh
    rects = fallback_grasps(obs.depth, roi.mask, (int(x), int(y), int(w), int(h)), obs.intrinsics,
                            max_opening_m=2 * config.fingers.half_opening,
                            min_clearance_m=config.fallback.clearance(config.fingers.clearance),
                            max_grasps=config.max_grasps,
                            config=config.fallback)
    return [replace(c, fallback=True) for c in _with_poses(obs, rects)]


def iter_fallback_fitting(
    obs: Observation, roi: Region, material: FloatArray, table_z: float, config: PipelineConfig,
) -> Iterator[GraspCandidate]:
    """The fallback's grasps on one region that the fingers fit around, with refinements, best
    first (the sampler runs when this is called): the robot's list of a region the fingers fit
    around none of the network's grasps on (``choose.LazyROI.fallback``), as ``fallback_with_refinements``
    continues the evaluation's."""
    return iter_fitting_with_refinements(fallback_candidates(obs, roi, config), material, obs, table_z, config)


def with_refinements(
    candidates: Sequence[GraspCandidate], material: FloatArray, obs: Observation, table_z: float,
    config: PipelineConfig,
) -> list[GraspCandidate]:
    """``candidates`` with, right after each one the fingers do not fit around, its refinement
    (``refine.refine``: turned, or moved onto a wall) if one fits. Both the evaluation's path and
    the robot's (``fitting_with_refinements``) use this one list, so they check the same grasps in
    the same order."""
    return [c for c, _ in _refined(candidates, SurfacePoints(material), obs, table_z, config)]


def fitting_with_refinements(
    candidates: Sequence[GraspCandidate], material: FloatArray, obs: Observation, table_z: float,
    config: PipelineConfig,
) -> list[GraspCandidate]:
    """The grasps of ``with_refinements`` that have a pose and that the fingers fit around
    (every one with a pose when ``config.fit_filter`` is off), in order: the robot's list."""
    return list(iter_fitting_with_refinements(candidates, material, obs, table_z, config))


def iter_fitting_with_refinements(
    candidates: Sequence[GraspCandidate], material: FloatArray, obs: Observation, table_z: float,
    config: PipelineConfig,
) -> Iterator[GraspCandidate]:
    """``fitting_with_refinements`` one grasp at a time: a grasp is checked (and refined) only
    when the one before it has been taken, so the robot, which needs each ROI's first fitting
    grasp, checks one or two grasps per ROI instead of all of them.

    Each grasp is checked once, on one ``SurfacePoints``: a network grasp's check is the one that
    decided whether to refine it, and a refinement fits by construction (``refine`` returns only
    grasps ``finger_check`` accepts at the same tip height)."""
    surface = SurfacePoints(material)

    def fits(c: GraspCandidate, known: bool | None) -> bool:
        if c.pose is None:
            return False
        if not config.fit_filter:
            return True
        if known is not None:
            return known
        return finger_check(surface, c.pose, tip_height(c.pose, config.pick, table_z), config.fingers)[0]

    return (c for c, known in _refined(candidates, surface, obs, table_z, config) if fits(c, known))


def _refined(
    candidates: Sequence[GraspCandidate], surface: SurfacePoints, obs: Observation, table_z: float,
    config: PipelineConfig,
) -> Iterator[tuple[GraspCandidate, bool | None]]:
    """``with_refinements``' grasps in order, each with whether the fingers fit around it, or
    None where that was not checked (refinement off, or no pose); lazily."""
    from .refine import refine

    if not (config.refine.enabled and config.fit_filter):
        yield from ((c, None) for c in candidates)
        return

    def tip_z_of(pose: TopDownGrasp) -> float:
        return tip_height(pose, config.pick, table_z)

    for c in candidates:
        if c.pose is None:
            yield c, None
            continue
        fits = finger_check(surface, c.pose, tip_z_of(c.pose), config.fingers)[0]
        yield c, fits
        if fits:
            continue
        better = refine(c.pose, surface, tip_z_of, config.fingers, config.refine)
        if better is None:
            continue
        try:
            rect = pose_to_rect(better, obs.intrinsics, obs.cam_to_world, quality=c.quality,
                                length_px=c.rect.length_px)
        except ValueError:
            continue
        yield GraspCandidate(rect, better, fallback=c.fallback), True


def fallback_with_refinements(
    obs: Observation, roi: Region, material: FloatArray, table_z: float, config: PipelineConfig,
) -> list[GraspCandidate]:
    """The fallback's grasps of one region with their refinements: the evaluation's list
    continued (and the robot's relocation spots), as ``iter_fallback_fitting`` is the robot's."""
    return with_refinements(fallback_candidates(obs, roi, config), material, obs, table_z, config)


def raised_mask(world: FloatArray, table_z: float, tolerance: float) -> BoolMask:
    """``[H, W]`` pixels whose point lies more than ``tolerance`` above the table (NaN: not),
    from the whole frame's world points (the evaluations that have them; the grasp checks and
    the size cue read ``RaisedPoints``, the same mask made from the heights alone)."""
    out: BoolMask = np.nan_to_num(world[..., 2], nan=table_z) > table_z + tolerance
    return out


def roi_colours(rgb: npt.NDArray[np.uint8], raised: BoolMask, roi: Region) -> tuple[float, ...] | None:
    """The ROI's colour shares (``perception/colours.py``) over the same raised pixels as
    ``RaisedPoints.within`` gives the grasp checks: the object's own surface, not the table
    around it."""
    x, y, w, h = roi.box_xywh
    box = (slice(y, y + h), slice(x, x + w))
    return measure_colours(rgb[box][roi.mask[box] & raised[box]])


def roi_cavity(obs: Observation, raised: BoolMask, roi: Region, table_z: float) -> float | None:
    """The ROI's open cavity (``perception/cavity.py``) over its raised pixels, the object's own
    surface as the grasp checks see it."""
    x, y, w, h = roi.box_xywh
    box = (slice(y, y + h), slice(x, x + w))
    return measure_cavity(obs.world_z()[box] - table_z, roi.mask[box] & raised[box])


@dataclass(frozen=True)
class _Surfaces:
    """Depth points a grasp check needs: one object's surface above the table."""

    material: FloatArray  # [m, 3] world
    table_z: float
    heights: HeightMap | None = None  # the other objects' surfaces, for the clearance check


def _check(
    env: SimEnv, candidate: GraspCandidate, surfaces: _Surfaces, config: PipelineConfig,
    fit: bool, ik: bool, prefer: bool = False,
) -> GraspCandidate:
    """Run the requested checks on one candidate (fingers first: cheap; IK costs ~50 ms). With
    ``prefer`` (``ClearanceConfig.prefer``), a candidate that passes also gets ``blocked``: what
    its approach would touch, from the same plan as its IK check."""
    if candidate.pose is None:
        return replace(candidate, fits=False, reachable=False, detail="no valid depth at the centre", blocked=None)
    fits: bool | None = None
    detail = ""
    if fit:
        tip = tip_height(candidate.pose, config.pick, surfaces.table_z)
        fits, detail = finger_check(surfaces.material, candidate.pose, tip, config.fingers)
        if not fits:
            return replace(candidate, fits=False, reachable=None, detail=detail, blocked=None)
    reachable: bool | None = None
    blocked: str | None = None
    if ik or prefer:
        clear = config.pick.clearance
        obstacles = surfaces.heights if clear.enabled or prefer else None
        unreachable, touched = pick_problems(env, candidate.pose, config.pick, obstacles)
        if ik:
            why = unreachable or (touched if clear.enabled else None)
            reachable = why is None
            detail = why or ""
        if prefer and reachable is not False and touched is not None:
            blocked = touched
            detail = f"passes; not preferred: {touched}"
    return replace(candidate, fits=fits, reachable=reachable, detail=detail, blocked=blocked)


def _usable(
    env: SimEnv, candidates: list[GraspCandidate], surfaces: _Surfaces, config: PipelineConfig,
    exclude: Callable[[TopDownGrasp], bool] | None = None,
    more: Callable[[], list[GraspCandidate]] | None = None,
) -> tuple[list[GraspCandidate], tuple[GraspCandidate, ...]]:
    """(candidates with check results filled in, the grasps grounding may use).

    With checks on, only the best candidate that passes them is usable: the robot would execute
    exactly that one. With checks off, every candidate with a pose is. Candidates ``exclude``
    says yes to (a retry's grasps that already failed) are never usable. ``more`` gives further
    candidates (the fallback's), asked for and listed only when the fingers fit around none of
    ``candidates`` (an excluded one fitted once: it was executed).
    """
    def excluded(c: GraspCandidate) -> bool:
        return exclude is not None and c.pose is not None and exclude(c.pose)

    if not (config.fit_filter or config.ik_filter):
        return candidates, tuple(c for c in candidates if c.pose is not None and not excluded(c))
    prefer = config.pick.clearance.prefer and surfaces.heights is not None
    checked: list[GraspCandidate] = []
    chosen: GraspCandidate | None = None
    first_blocked: GraspCandidate | None = None  # prefer: the first that passes, if none is clear
    fitted = False  # the fingers fit around some candidate

    def check_all(listed: Iterable[GraspCandidate]) -> None:
        nonlocal chosen, first_blocked, fitted
        for c in listed:
            if chosen is not None:
                checked.append(c)
                continue
            if excluded(c):
                fitted = True
                checked.append(GraspCandidate(c.rect, c.pose, detail="tried before and failed", fallback=c.fallback))
                continue
            c = _check(env, c, surfaces, config, config.fit_filter, config.ik_filter, prefer)
            fitted = fitted or c.fits is True
            if c.pose is not None and c.fits is not False and c.reachable is not False:
                if c.blocked is None:
                    chosen = c
                else:
                    first_blocked = first_blocked or c
            checked.append(c)

    check_all(candidates)
    if not fitted and chosen is None and first_blocked is None and more is not None:
        check_all(more())
    chosen = chosen or first_blocked
    return checked, (() if chosen is None else (chosen,))


def _three_d(
    env: SimEnv, obs: Observation, target: PerceivedROI | None, target_body: int,
    surfaces: _Surfaces, config: PipelineConfig,
) -> tuple[bool, str]:
    """The 3D metric (see the module docstring) and why it failed."""
    if target is None:
        return False, "no ROI matches the target"
    if not target.candidates:
        return False, "no grasp candidate on the target's ROI"
    assert obs.seg is not None
    target_mask = obs.seg == target_body
    h, w = target_mask.shape
    reasons: list[str] = []
    for c in target.candidates:
        col = min(max(round(c.rect.center_xy[0]), 0), w - 1)
        row = min(max(round(c.rect.center_xy[1]), 0), h - 1)
        if not target_mask[row, col]:
            reasons.append("centre off the target")
            continue
        known = c.reachable is not None  # IK does not depend on the surfaces: reuse it
        checked = _check(env, c, surfaces, config, fit=True, ik=not known)
        if checked.fits is False:
            reasons.append(checked.detail)
            continue
        if c.reachable if known else checked.reachable:
            return True, ""
        reasons.append(c.detail if known else checked.detail)
    return False, "; ".join(dict.fromkeys(reasons))


ROBOT_STAGES = ("segment", "grasp_net", "encode", "grasp_checks")




def perceive(
    env: SimEnv, encoder: ImageEncoder, config: PipelineConfig, obs: Observation | None = None,
    *, timings: dict[str, float] | None = None, exclude: Callable[[TopDownGrasp], bool] | None = None,
    colours: bool = False, cavity: bool = False,
) -> ScenePerception:
    """Capture (unless ``obs`` is given), find ROIs and grasps, check them, embed the crops.

    ``env`` holds the built scene with the arm at home; nothing here moves it. ``timings``, if
    given, receives the wall time of the robot-side stages (``ROBOT_STAGES``; rendering and the
    simulator's ground truth excluded) for ``benchmarks/bench_perception.py``. ``exclude`` marks
    grasps grounding must not use (``retry``: those that already failed). ``colours``: measure
    each ROI's colour shares (only a grounder with the opt-in colour cue reads them); ``cavity``:
    each ROI's open cavity (the opt-in cavity cue's). Sets this
    process's numpy BLAS to one thread (``runtime/blas.py``: its spinning threads slow torch).
    """
    from ..blas import single_threaded_blas
    from ..encoders.conse import encode_with_classes
    from ..encoders.image import crop_box

    single_threaded_blas()
    scene = env.scene
    obs = obs if obs is not None else env.capture()
    bodies = [o.body_id for o in scene.objects]
    truth = gt_rois(obs, scene)
    target_body = scene.target.body_id
    target_gt = next((r for r in truth if r.label == target_body), None)
    with timed_stage(timings, "segment"):
        rois = raster_order(truth) if config.rois == "oracle" else segment(obs, config.segment).rois
    owners = [roi.label if config.rois == "oracle" else majority_body(obs, roi.mask, bodies)
              for roi in rois]
    k = config.rgb_scale
    sharp = env.capture_rgb(k) if k > 1 else obs.rgb  # a render: simulator work, not timed
    with torch_threads(config.torch_threads):
        with timed_stage(timings, "grasp_net"):
            raw = raw_candidates(scene, obs, rois, owners, config)
        with timed_stage(timings, "encode"):
            crops = [crop_box(sharp, tuple(v * k for v in roi.box_xywh)) for roi in rois]
            embeddings, classes = encode_with_classes(encoder, crops)
    table_z = scene.layout.table_z
    perceived: list[PerceivedROI] = []
    with timed_stage(timings, "grasp_checks"):
        raised = RaisedPoints.of(obs, table_z, config.fingers.height_tolerance)
        clear = config.pick.clearance
        surfaces = [_Surfaces(raised.within(roi.mask), table_z, heights_around(raised, roi.mask, table_z, clear))
                    for roi in rois]
        checked = [_usable(env, with_refinements(raw[i], s.material, obs, table_z, config), s, config, exclude,
                           partial(fallback_with_refinements, obs, rois[i], s.material, table_z, config))
                   for i, s in enumerate(surfaces)]
        extents = [measure_extents(s.material, table_z) for s in surfaces]
        shares = [roi_colours(obs.rgb, raised.mask, roi) if colours else None for roi in rois]
        cavities = [roi_cavity(obs, raised.mask, roi, table_z) if cavity else None for roi in rois]
    for i, (roi, body) in enumerate(zip(rois, owners, strict=True)):
        candidates, usable = checked[i]
        iou = box_iou(roi.box_xywh, target_gt.box_xywh) if target_gt is not None else 0.0
        perceived.append(PerceivedROI(roi, tuple(candidates), usable,
                                      np.asarray(embeddings[i], np.float32), body, iou, extents[i],
                                      shares[i], classes[i], cavities[i]))
    target_roi = None
    if perceived:
        best = max(range(len(perceived)), key=lambda i: (perceived[i].target_iou, -i))
        if perceived[best].target_iou >= config.detect_iou:
            target_roi = best
    assert obs.seg is not None
    target_mask = obs.seg == target_body
    target_surfaces = _Surfaces(raised.within(target_mask), table_z,
                                heights_around(raised, target_mask, table_z, config.pick.clearance))
    three_d, why = _three_d(env, obs, perceived[target_roi] if target_roi is not None else None,
                            target_body, target_surfaces, config)
    return ScenePerception(
        obs=obs,
        rois=tuple(perceived),
        target_body=target_body,
        target_box=target_gt.box_xywh if target_gt is not None else None,
        target_roi=target_roi,
        three_d=three_d,
        three_d_detail=why,
        raised=raised,
    )


def frame_look(
    env: SimEnv, perception: ScenePerception, encoder: ImageEncoder, config: ActiveLookConfig,
    before_render: Callable[[], None] | None = None,
) -> ActiveLook:
    """The active look for ``perception``'s frame: each ROI aimed at by its raised depth points."""
    return ActiveLook(env.client, [perception.raised.within(r.roi.mask) for r in perception.rois],
                      env.scene.layout.table_z, encoder, config, before_render=before_render)


def grounding_rois(perception: ScenePerception) -> list[ROI]:
    """The grounder's view of the scene: boxes, usable grasps with scores, embeddings.

    Labels are ROI numbers, never object names: the grounder must not see the ground truth.
    """
    return [
        ROI(
            box_xywh=(float(r.roi.box_xywh[0]), float(r.roi.box_xywh[1]),
                      float(r.roi.box_xywh[2]), float(r.roi.box_xywh[3])),
            grasp_scores=[c.quality for c in r.usable],
            grasps=list(r.usable),
            image_embedding=r.embedding,
            mask=r.roi.mask,
            label=f"roi{i}",
            extents_m=r.extents_m,
            colours=r.colours,
            classes=r.classes,
            cavity_m=r.cavity_m,
        )
        for i, r in enumerate(perception.rois)
    ]


# ---------------------------------------------------------------------------------------------
# execution from one saved state


class SavedStart:
    """The episode's start state: scene settled, arm at home. Every pick restarts from it."""

    def __init__(self, env: SimEnv) -> None:
        self.env = env
        env.robot.reset_home()
        self.state_id = int(p.saveState(physicsClientId=env.client))

    def restore(self) -> None:
        p.restoreState(stateId=self.state_id, physicsClientId=self.env.client)
        # restoreState brings back positions and velocities, not motor targets: command home again
        self.env.robot.reset_home()

    def release(self) -> None:
        if self.env.client >= 0:
            p.removeState(self.state_id, physicsClientId=self.env.client)


class ChoiceError(StrEnum):
    """Why grounding chose a wrong region (``wrong_object`` episodes only).

    The episode is re-grounded with ``p(o | r)`` set to each ROI's true class (one-hot on the
    plain name of the body its mask covers most; ROIs over no body keep their perceived ``p``),
    everything else unchanged: a wrong choice that this fixes is a *perception* error (the
    object was not recognised). One it does not fix is a *knowledge* error when, with every
    object named right, the KB's E_aff ranks another usable ROI strictly ahead of the target (or
    finds nothing in the scene affordant), and an *energies* error when the KB ranks the target
    first (ties included) but its grasp and alignment energies move another ROI ahead: the
    knowledge was right, the balance of the paper's three energies was not.
    """

    PERCEPTION = "perception"
    KNOWLEDGE = "knowledge"
    ENERGIES = "energies"


@dataclass(frozen=True)
class MethodOutcome:
    """What one method did in one episode."""

    method: str
    grounding: Grounding
    chosen_roi: int | None
    chosen_iou: float
    chosen_body: int | None
    detect: bool
    failure: Failure
    pick: PickResult | None  # None when nothing was executed
    grasp: GraspCandidate | None
    true_class_roi: int | None = None  # the choice with p(o|r) set to the true class
    choice_error: ChoiceError | None = None  # set for wrong_object only
    # With a retry policy (``retry.RetryConfig.retries`` > 0): the attempts after a first pick
    # whose hand ended empty (empty when none was needed); None when the policy is off.
    retries: tuple[Attempt, ...] | None = None
    # With ``ClearanceConfig.relocate``: "" when the chosen grasp's approach was clear, else what
    # blocked it and where it moved (or that it was kept); None when the policy is off or nothing
    # was executed. ``grasp`` is then the grasp executed.
    relocation: str | None = None
    #: with the active look (``active_look.py``): the ROIs it looked at before this choice;
    #: None when the look is off
    looked: tuple[int, ...] | None = None

    @property
    def success(self) -> bool:
        return self.failure is Failure.SUCCESS


@dataclass(frozen=True)
class EpisodeResult:
    """One episode: the shared perception and each method's outcome."""

    spec: SceneSpec
    perception: ScenePerception
    outcomes: dict[str, MethodOutcome]
    body_assets: dict[int, str]


def true_class_probabilities(
    grounder: Grounder, perceived: npt.NDArray[np.float32], perception: ScenePerception,
    body_names: Mapping[int, str],
) -> npt.NDArray[np.float32]:
    """``p(o | r)`` ``[N, O]`` with each ROI's row one-hot on its true class (see
    ``ChoiceError``); rows of ROIs over no scene body, or whose name is not in the grounder's
    vocabulary, stay as perceived."""
    from ...schemas.names import normalize_name

    index = {name: j for j, name in enumerate(grounder.vocabulary)}
    p_true = np.array(perceived, dtype=np.float32, copy=True)
    for n, r in enumerate(perception.rois):
        name = body_names.get(r.body) if r.body is not None else None
        if name is None:
            continue
        try:
            j = index.get(name, index.get(normalize_name(name), -1))
        except ValueError:
            j = -1
        if j >= 0:
            p_true[n] = 0.0
            p_true[n, j] = 1.0
    return p_true


@dataclass(frozen=True)
class TrueClassGrounding:
    """The episode re-grounded with ``p(o | r)`` set to the true classes (``ChoiceError``)."""

    roi: int | None  # the ROI chosen; None if no ROI is usable
    # the usable ROIs whose E_aff alone is the lowest (ties: all); empty when that lowest is 0
    kb_best: tuple[int, ...] = ()


#: E_aff values this close count as a tie (float32 sums of the same weights in another order)
E_AFF_TIE = 1e-6


def true_class_grounding(
    grounder: Grounder, verb: str, perception: ScenePerception, body_names: Mapping[int, str]
) -> TrueClassGrounding:
    """What ``grounder`` chooses when ``p(o | r)`` is the true class, and which ROIs its E_aff
    alone ranks first.

    Follows ``Grounder.ground``: ROIs without a grasp scoring above 0 are excluded, each ROI's
    best grasp gives ``E_grasp``, the lowest total energy wins (stable ties).
    """
    usable = [i for i, r in enumerate(perception.rois)
              if r.usable and max(c.quality for c in r.usable) > 0.0]
    if not usable:
        return TrueClassGrounding(None)
    emb = np.stack([perception.rois[i].embedding for i in usable])  # [N, d]
    gmax = np.array([max(c.quality for c in perception.rois[i].usable) for i in usable], np.float32)
    perceived = grounder.energies(verb, emb, gmax).p_obj  # [N, O]
    subset = ScenePerception(perception.obs, tuple(perception.rois[i] for i in usable),
                             perception.target_body, perception.target_box, None, False, "", perception.raised)
    p_true = true_class_probabilities(grounder, perceived, subset, body_names)
    terms = grounder.energies(verb, emb, gmax, p_obj=p_true)
    e_aff = np.asarray(terms.e_aff, dtype=np.float64)
    low = float(e_aff.min())
    # a KB that finds nothing in the scene affordant (every E_aff 0) ranks no ROI first
    best = tuple(usable[k] for k in np.flatnonzero(e_aff <= low + E_AFF_TIE).tolist()) if low < -E_AFF_TIE else ()
    return TrueClassGrounding(usable[int(np.argsort(terms.total, kind="stable")[0])], best)


def true_class_choice(
    grounder: Grounder, verb: str, perception: ScenePerception, body_names: Mapping[int, str]
) -> int | None:
    """The ROI ``grounder`` chooses when ``p(o | r)`` is the true class; None if none is usable."""
    return true_class_grounding(grounder, verb, perception, body_names).roi


def choice_error(perception: ScenePerception, true_class: TrueClassGrounding, detect_iou: float) -> ChoiceError:
    """Why a ``wrong_object`` choice was wrong (see ``ChoiceError``)."""
    def is_target(i: int) -> bool:
        return perception.target_box is not None and perception.rois[i].target_iou >= detect_iou

    if true_class.roi is not None and is_target(true_class.roi):
        return ChoiceError.PERCEPTION
    return ChoiceError.ENERGIES if any(is_target(i) for i in true_class.kb_best) else ChoiceError.KNOWLEDGE


def chosen_region(
    perception: ScenePerception, chosen: RankedROI, detect_iou: float,
) -> tuple[PerceivedROI, bool, GraspCandidate | None]:
    """The chosen region, whether it is the target (Detect: box IoU >= ``detect_iou``) and the
    grasp grounding chose with it."""
    roi = perception.rois[chosen.index]
    detect = perception.target_box is not None and roi.target_iou >= detect_iou
    return roi, detect, chosen.grasp if isinstance(chosen.grasp, GraspCandidate) else None


def not_detected(perception: ScenePerception) -> Failure:
    """Why the target was not chosen when grounding chose another region or none: no region
    for it, no usable grasp on it, or a wrong choice."""
    if perception.target_roi is None:
        return Failure.NO_TARGET_ROI
    if not perception.rois[perception.target_roi].usable:
        return Failure.NO_GRASP
    return Failure.WRONG_OBJECT


def run_episode(
    env: SimEnv,
    spec: SceneSpec,
    grounders: Mapping[str, Grounder],
    encoder: ImageEncoder,
    config: PipelineConfig | None = None,
    *,
    before_pick: Callable[[str], None] | None = None,
    retry: RetryConfig | None = None,
) -> EpisodeResult:
    """Build ``spec`` in ``env``, perceive once, then ground and execute per method.

    ``before_pick(method)`` is called right before a pick is simulated (e.g. to start recording
    frames); picks already simulated for the same ROI are reused and do not call it. With
    ``retry.retries`` > 0, a pick whose hand ended empty is followed by up to that many attempts
    on fresh frames (``retry_picks``), each method's from the state right after the first
    pick (saved once per pick); the first attempt is unchanged.
    """
    cfg = config or PipelineConfig()
    retrying = retry is not None and retry.retries > 0
    no_retries: tuple[Attempt, ...] | None = () if retrying else None  # an outcome with nothing to retry
    env.reset(spec)
    start = SavedStart(env)
    after_pick: dict[int, int] = {}  # chosen ROI -> physics state right after its first pick
    moved: dict[int, tuple[GraspCandidate, str]] = {}  # chosen ROI -> its relocated grasp, why
    try:
        perception = perceive(env, encoder, cfg, colours=any(g.colour_cue_active for g in grounders.values()),
                              cavity=any(g.cavity_cue_active for g in grounders.values()))
        rois = grounding_rois(perception)
        look = (frame_look(env, perception, encoder, cfg.active_look, before_render=start.restore)
                if cfg.active_look.enabled else None)
        picks: dict[int, PickResult] = {}
        outcomes: dict[str, MethodOutcome] = {}
        body_names = {o.body_id: o.name for o in env.scene.objects}  # diagnostics only
        for name, grounder in grounders.items():
            grounding, looked = look.ground(grounder, spec.verb, rois) if look else (grounder.ground(spec.verb, rois), None)
            chosen = grounding.chosen
            true_class = true_class_grounding(grounder, spec.verb, perception, body_names)
            true_roi = true_class.roi
            if chosen is None:
                outcomes[name] = MethodOutcome(name, grounding, None, 0.0, None, False,
                                               not_detected(perception), None, None, true_roi,
                                               retries=no_retries, looked=looked)
                continue
            roi, detect, grasp = chosen_region(perception, chosen, cfg.detect_iou)
            if not detect:
                failure = not_detected(perception)
                error = None
                if failure is Failure.WRONG_OBJECT:
                    error = choice_error(perception, true_class, cfg.detect_iou)
                outcomes[name] = MethodOutcome(name, grounding, chosen.index, roi.target_iou, roi.body,
                                               False, failure, None, grasp, true_roi, error,
                                               retries=no_retries, looked=looked)
                continue
            relocation: str | None = None
            if cfg.pick.clearance.relocate and grasp is not None and grasp.pose is not None:
                if chosen.index not in moved:
                    start.restore()
                    moved[chosen.index] = relocated_grasp(env, perception.obs, roi, grasp, cfg)
                grasp, relocation = moved[chosen.index]
            if chosen.index not in picks:
                start.restore()
                if before_pick is not None:
                    before_pick(name)
                picks[chosen.index] = execute_pick(
                    env, grasp.pose if grasp is not None else None, perception.target_body, cfg.pick,
                    object_centre(perception.raised, roi.roi.mask),
                )
                if retrying and hand_empty(picks[chosen.index]):
                    after_pick[chosen.index] = int(p.saveState(physicsClientId=env.client))
            pick = picks[chosen.index]
            attempts = no_retries
            if retry is not None and chosen.index in after_pick:
                p.restoreState(stateId=after_pick[chosen.index], physicsClientId=env.client)
                tried = [grasp.pose] if grasp is not None and grasp.pose is not None else []
                attempts = tuple(retry_picks(env, spec.verb, grounder, encoder, cfg, tried, retry))
            outcomes[name] = MethodOutcome(name, grounding, chosen.index, roi.target_iou, roi.body,
                                           True, PICK_FAILURES[pick.outcome], pick, grasp, true_roi,
                                           retries=attempts, relocation=relocation, looked=looked)
        return EpisodeResult(spec, perception, outcomes, dict(env.scene.body_assets))
    finally:
        start.release()
        if env.client >= 0:
            for state in after_pick.values():
                p.removeState(state, physicsClientId=env.client)


def relocated_grasp(
    env: SimEnv, obs: Observation, roi: PerceivedROI, grasp: GraspCandidate, config: PipelineConfig,
) -> tuple[GraspCandidate, str]:
    """The chosen ``grasp`` of ``roi``, moved to a nearby spot of the object when its approach is
    blocked (``sim/relocate.py``), and why ("" when it was clear). The arm must be at home: the
    check plans the pick from the current posture. The moved grasp keeps the network grasp's
    quality, so grounding is unaffected."""
    assert grasp.pose is not None
    raised = RaisedPoints.of(obs, env.scene.layout.table_z, config.fingers.height_tolerance)
    others = [c.pose for c in roi.candidates if c.pose is not None and c.pose is not grasp.pose]
    return relocate_candidate(env, obs, roi.roi.mask, raised, raised.within(roi.roi.mask), grasp, others, config)


def relocate_candidate(
    env: SimEnv, obs: Observation, mask: BoolMask, raised: RaisedPoints, material: FloatArray, grasp: GraspCandidate,
    others: Iterable[TopDownGrasp], config: PipelineConfig, plans: PlanCache | None = None,
) -> tuple[GraspCandidate, str]:
    """What both paths share (``relocated_grasp``, ``choose.relocate_choice``): the search over
    the region's own depth points (``material``) against the height map of everything outside
    its ``mask``, and the moved grasp as a candidate with the network grasp's quality.
    ``raised``: the frame's raised points (the caller has them: made once per frame)."""
    from .relocate import RelocateConfig, relocate_if_blocked

    assert grasp.pose is not None
    table_z = env.scene.layout.table_z
    heights = heights_excluding(raised, mask, table_z, config.pick.clearance)
    result = relocate_if_blocked(
        grasp.pose, others, material, heights,
        lambda g, h: pick_problems(env, g, config.pick, h, plans),
        lambda g: tip_height(g, config.pick, table_z), config.fingers, RelocateConfig(),
        lambda g, h: pick_problems(env, g, config.pick, h, plans, approach_first=True))
    if not result.moved:
        return grasp, result.detail
    try:
        rect = pose_to_rect(result.pose, obs.intrinsics, obs.cam_to_world, quality=grasp.quality,
                            length_px=grasp.rect.length_px)
    except ValueError:
        return grasp, f"{result.detail}; not in the image, kept"
    return (GraspCandidate(rect, result.pose, True, True, f"relocated: {result.detail}", fallback=grasp.fallback),
            result.detail)


def retry_picks(
    env: SimEnv, verb: str, grounder: Grounder, encoder: ImageEncoder, config: PipelineConfig,
    failed: Sequence[TopDownGrasp], cfg: RetryConfig,
) -> list[Attempt]:
    """The retry policy (``retry``): up to ``cfg.retries`` more attempts from ``env``'s current
    state (right after a pick whose hand ended empty), each on a fresh perception; stops at a
    success or a failure the robot cannot sense. ``failed`` are the grasps already tried (world
    poses)."""
    tried = list(failed)
    attempts: list[Attempt] = []
    for _ in range(cfg.retries):
        return_home(env, cfg)
        perception = perceive(env, encoder, config,
                              exclude=lambda pose: any(same_grasp(pose, t, cfg) for t in tried),
                              colours=grounder.colour_cue_active, cavity=grounder.cavity_cue_active)
        rois = grounding_rois(perception)
        if config.active_look.enabled:  # on the fresh frame, as the first attempt's choice had it
            chosen = frame_look(env, perception, encoder, config.active_look).ground(grounder, verb, rois)[0].chosen
        else:
            chosen = grounder.ground(verb, rois).chosen
        if chosen is None:
            attempts.append(Attempt(None, False, not_detected(perception).value))
            break
        roi, detect, grasp = chosen_region(perception, chosen, config.detect_iou)
        if not detect:
            attempts.append(Attempt(chosen.index, False, not_detected(perception).value))
            break
        pose = grasp.pose if grasp is not None else None
        pick = execute_pick(env, pose, perception.target_body, config.pick,
                            object_centre(perception.raised, roi.roi.mask))
        quality = grasp.quality if grasp is not None else None
        attempts.append(Attempt(chosen.index, True, PICK_FAILURES[pick.outcome].value, pick.detail, quality))
        if not hand_empty(pick) or pose is None:
            break
        tried.append(pose)
    return attempts
