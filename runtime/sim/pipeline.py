"""One testbed episode end to end: capture → ROIs → grasps → ground → execute → outcome.

The scene is perceived once and every grounding method is scored on that same perception; only
grounding and execution differ between methods. Execution always restarts from one saved physics
state (``p.saveState`` right after the scene settled, the arm teleported home), and a pick is
simulated once per distinct chosen ROI: methods that choose the same region get the same result,
which the determinism of the simulator would give anyway.

Stages and the robot-side choices made in them (all use only what a real robot has: the image,
the depth, the predicted mask, its own kinematics; ``perceive.perceive`` runs stages 1-3 and the
embeddings of 4 once per frame):

1. **ROIs**: ``predicted`` (class-agnostic RGB-D segmentation) or ``oracle`` (the simulator's
   segmentation buffer, one ROI per visible object).
2. **Grasps** per ROI (``candidates.raw_candidates``): a grasp network (``grconvnet``,
   ``ggcnn``, ``ggcnn2``) run once per scene over the crop holding every ROI, each ROI taking the
   peaks of the shared maps on its mask (``grasp.predict.predict_grasps_rois``); or the analytic
   ``antipodal`` sampler restricted to the ROI mask, or the ``oracle`` grasp of the body the ROI
   covers most. Each rectangle becomes a top-down pose through the depth and the intrinsics.
3. **Grasp checks** (``grasp_checks.usable_grasps``; on by default; ``PipelineConfig.fit_filter``
   / ``ik_filter``): best-scoring first, keep the first grasp under which the object fits the
   open fingers (``fingers.finger_check``: the section of the ROI's depth surface above the
   finger tips, across a pad-wide strip) and whose whole pick (pre-grasp, descent, lift,
   transport, release) has IK solutions. Its score is the ROI's grasp confidence, so
   ``E_grasp = -log(score)`` is the energy of a grasp the robot can execute; an ROI with no such
   grasp is excluded from grounding, as the paper prescribes. When the fingers fit around none of
   a network's grasps on an ROI (no peak at all on a dice, only sections wider than the hand), the
   antipodal sampler's grasps on the ROI are checked the same way (``fallback.py``,
   ``candidates.fallback_candidates``; ``PipelineConfig.fallback``). ``perceive`` checks every
   ROI (the evaluation reports each one's usable grasp); the robot's own path (``sim.choose``)
   plans IK only for the grasps grounding chooses, with the same result.
4. **Embeddings** of the ROI crops (the ConSE image encoder), then ``Grounder.ground(verb, rois)``
   per method over the scene vocabulary (the plain names of the 74 sim objects).
5. **Execution** of the chosen ROI's grasp with ``execute_pick``, judged from physics.

Metrics, per episode:

* **3D** (``grasp_checks.three_d_metric``): the grasp module returned a *viable* grasp on the
  target: the predicted ROI matching the target (box IoU >= 0.5 with the target's ground-truth
  box; best such ROI) has a raw grasp candidate whose centre pixel lies on the target's
  ground-truth mask, that passes ``finger_check`` on the target's ground-truth surface (its true
  mask, not the ROI's), and whose pick is IK-feasible. Method-independent: perception is shared.
* **Detect** (per method): the chosen ROI's box has IoU >= 0.5 with the target's ground-truth box.
* **Grasp Rate** (per method): Detect and the executed pick ends in ``success`` (target lifted,
  carried and at rest in the drop zone). A pick is not executed when Detect fails: the paper
  counts a wrong region as a failure whatever the arm would do next.

Failure classes (root cause first): ``no_target_roi`` (perception produced no region for the
target), ``no_grasp`` (the target's region had no usable grasp, so grounding could not choose
it), ``wrong_object`` (grounding chose another region), then the pick's own outcomes
(``ik_failure``, ``missed``, ``lift_failed``, ``lifted_other_body``, ``slip_during_transport``,
``outside_drop_zone``). Why a ``wrong_object`` choice was wrong is ``choice_errors.ChoiceError``.

Determinism: physics runs by step counts, torch runs with a fixed thread count, the segmenter and
the antipodal sampler are seeded, and no wall-clock value enters a result.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from functools import cache
from typing import Any, Literal, get_args

import numpy as np
import numpy.typing as npt
import pybullet as p

from ..encoders.image import ImageEncoder
from ..grasp.geometry import TopDownGrasp, pose_to_rect
from ..grounding.grounder import Grounder, Grounding, RankedROI
from ..perception.observation import Observation
from ..perception.segment import SegmentConfig
from .active_look import ActiveLookConfig
from .assets import object_catalog
from .candidates import GraspCandidate, tip_height
from .choice_errors import ChoiceError, choice_error, true_class_grounding
from .clearance import HeightMap, heights_excluding
from .env import SimEnv
from .episode import Outcome, PickConfig, PickResult, PlanCache, execute_pick, pick_problems
from .fallback import FallbackConfig
from .fingers import FingerGeometry
from .perceive import PerceivedROI, ScenePerception, frame_look, grounding_rois, perceive
from .refine import RefineConfig
from .relocate import RelocateConfig, relocate_if_blocked
from .retry import Attempt, RetryConfig, hand_empty, return_home, same_grasp
from .scene import SceneSpec
from .surface import RaisedPoints, object_centre, object_points

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
            "fallback_thin_centres": self.fallback.thin_centres if self.uses_fallback else None,
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


def chosen_region(
    perception: ScenePerception, chosen: RankedROI, detect_iou: float,
) -> tuple[PerceivedROI, bool, GraspCandidate | None]:
    """The chosen region, whether it is the target (Detect: box IoU >= ``detect_iou``) and the
    grasp grounding chose with it."""
    roi = perception.rois[chosen.index]
    detect = perception.target_box is not None and roi.target_iou >= detect_iou
    return roi, detect, chosen.grasp if isinstance(chosen.grasp, GraspCandidate) else None


def longest_edge(roi: PerceivedROI) -> float | None:
    """The region's longest edge as the depth camera measured it (m; ``PickConfig.gentle_below``)."""
    return None if roi.extents_m is None else float(roi.extents_m[0])


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
                    object_centre(perception.raised, roi.roi.mask), longest_edge(roi),
                    object_points(perception.raised, roi.roi.mask),
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
    return relocate_search(
        obs, mask, raised, material, grasp, others, config, env.scene.layout.table_z,
        lambda g, h: pick_problems(env, g, config.pick, h, plans),
        lambda g, h: pick_problems(env, g, config.pick, h, plans, approach_first=True), RelocateConfig())


def relocate_search(
    obs: Observation, mask: BoolMask, raised: RaisedPoints, material: FloatArray, grasp: GraspCandidate,
    others: Iterable[TopDownGrasp], config: PipelineConfig, table_z: float,
    problems: Callable[[TopDownGrasp, HeightMap], tuple[str | None, str | None]],
    spot_problems: Callable[[TopDownGrasp, HeightMap], tuple[str | None, str | None]],
    relocate: RelocateConfig,
) -> tuple[GraspCandidate, str]:
    """``relocate_candidate`` with the pick's check given (``problems``, ``spot_problems``, as
    ``relocate.relocate_if_blocked`` takes them): the testbed's plans the arm's IK, a frame without a
    robot model checks the hand alone (``runtime/frame.py``)."""
    assert grasp.pose is not None
    heights = heights_excluding(raised, mask, table_z, config.pick.clearance)
    result = relocate_if_blocked(grasp.pose, others, material, heights, problems,
                                 lambda g: tip_height(g, config.pick, table_z), config.fingers, relocate,
                                 spot_problems)
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
                            object_centre(perception.raised, roi.roi.mask), longest_edge(roi),
                            object_points(perception.raised, roi.roi.mask))
        quality = grasp.quality if grasp is not None else None
        attempts.append(Attempt(chosen.index, True, PICK_FAILURES[pick.outcome].value, pick.detail, quality))
        if not hand_empty(pick) or pose is None:
            break
        tried.append(pose)
    return attempts
