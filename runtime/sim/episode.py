"""Execute one top-down pick-and-place and judge it from the physics state.

Pre-grasp above the grasp along its approach axis (straight down for a top-down grasp), a look
from the wrist that re-centres the grasp on the object section under the pads (``wrist.py``;
the paper's closed-loop correction, one small depth frame), straight-line descent, close, lift,
a short hold that checks the fingers really hold the target, transport to the drop zone,
release. Every motion is planned (IK, checked by forward kinematics) before the arm moves, so an
unreachable grasp costs no simulation and is reported as ``ik_failure``. Success is read from
where the target body is, not from what the controller believes: it must have been held,
lifted, and come to rest inside the drop zone. One attempt per pick: the headline numbers are
single-attempt.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import numpy.typing as npt
import pybullet as p

from ..grasp.geometry import TopDownGrasp
from .arm_hull import hull_points_world, link_hulls
from .clearance import ClearanceConfig, HeightMap, first_hit, leaned_first_hit
from .env import EnvConfig, PhysicsConfig, SimEnv
from .fingers import FingerGeometry
from .gripper import GripperConfig
from .hands import hand_spec
from .robot import CR3Robot, IKSolution, tool_rotation
from .robot_urdf import FINGERTIP_BELOW_TCP, FLANGE_LINK
from .scene import Scene, TableLayout
from .wrist import WristConfig, look, recentre


class Outcome(StrEnum):
    """How a pick ended. ``wrong_object`` is also what a caller records when the chosen ROI is
    not the target, without running the pick."""

    SUCCESS = "success"
    NO_GRASP = "no_grasp"  # no grasp candidate was given for the chosen ROI
    IK_FAILURE = "ik_failure"  # a planned waypoint is out of reach
    MISSED = "missed"  # the fingers closed on nothing
    LIFT_FAILED = "lift_failed"  # something was pinched but it did not come up with the hand
    WRONG_OBJECT = "wrong_object"  # the hand lifted a body other than the target
    SLIP_DURING_TRANSPORT = "slip_during_transport"  # held after the lift, lost on the way
    OUTSIDE_DROP_ZONE = "outside_drop_zone"  # released but came to rest outside the zone


@dataclass(frozen=True)
class PickConfig:
    """Heights and tolerances of the pick (metres)."""

    approach_height: float = 0.10  # pre-grasp above the grasp pose
    # Tried in turn when the pre-grasp at approach_height is out of the arm's reach: a tall
    # object near the table's far edge (a pitcher's handle 23 cm up, 50 cm out) puts a 10 cm
    # pre-grasp past what the CR3 reaches with the hand pointing down (sim-val's serve/pitcher/2:
    # a 5 cm approach reaches it and the pick succeeds). Only such picks change.
    short_approach_heights: tuple[float, ...] = (0.05,)
    insertion_depth: float = 0.03  # TCP below the grasped surface point
    # finger tips above the table at the lowest. 4 mm left the pads on the rounded top edges of
    # flat objects (a wrench handle is ~1 cm thick), squeezing them down instead of across: of
    # the 16 dev episodes where CRAFT-E chose the wrench, 3 picks succeeded; 14 at 2 mm
    # (docs/results/sim_execution.md)
    table_clearance: float = 0.002
    lift_height: float = 0.15
    lift_inward_steps: int = 5  # if straight up is out of reach, pull the lift point inwards...
    lift_inward_step: float = 0.02  # ...by this much per try
    # The target must rise this much to count as lifted, unless nothing but the robot supports it
    # after the hold: a plate held by its rim hangs tilted and its centre rises less than the lift
    # (before this exception such picks stopped as lift_failed while the plate hung clear of the
    # table; a body still resting on the table or on another object is being dragged, not lifted).
    min_lift_rise: float = 0.10
    slip_tolerance: float = 0.03  # m the held body may shift in the hand before it counts as lost
    release_clearance: float = 0.03  # object bottom above the table when released
    min_transport_gap: float = 0.05  # carry at least this far above the release height
    retreat_height: float = 0.10
    release_settle_steps: int = 120
    # After the lift the arm holds still this long and the target must still be in the hand
    # (pinched, or where it was relative to the TCP): catches objects sliding out slowly.
    hold_steps: int = 48
    # An object nearly as wide as the open hand can stay wedged between the open fingers and rise
    # with the retreat. Seen (the target rose ``unjam_rise`` with the hand), the hand goes back
    # down until the object's bottom is near the zone, turns by ``unjam_turn_deg`` one way, then
    # the other, retreating after each turn (``_unjam``; 0: off, the release before 2026-12-06's
    # session 30).
    unjam_turn_deg: float = 20.0
    unjam_rise: float = 0.02
    # The held object must stay ``carry_margin`` clear of the arm's links on the way to the zone
    # (``_carry_hit``: the object's seen surface, carried with the hand, against the links' hulls).
    # Where the release at yaw 0 would sweep it into the arm, the hand carries it turned as the
    # arm turns about its base (the wrist still), else a quarter turn; if every way touches, the
    # yaw-0 carry, as before. Why: the zone lies beside the base, and at yaw 0 a long object's far
    # end swung into the upper arm (``Link2``), which knocked a 30 cm spatula out of the hand
    # (sim-dev ``stir/spatula/2`` at seed 2). False: every carry at yaw 0 (before session 44).
    carry_check: bool = True
    carry_margin: float = 0.02
    wrist: WristConfig = field(default_factory=WristConfig)
    clearance: ClearanceConfig = field(default_factory=ClearanceConfig)  # robot-side, see plan_pick
    # Lift high enough to carry the object over the tallest surface in the overhead depth
    # frame (plus this margin) when reachable: a low carry swept held objects into tall
    # distractors (cut/knife/0: the hand hit a box on the way to the zone, the knife fell).
    clear_obstacles: bool = True
    obstacle_margin: float = 0.03
    # The hand's gentle grip (``HandSpec.gentle_force``) for an object whose longest edge, as the
    # depth camera saw it, is under this (m): the full force squeezed small light objects (the
    # 6 g sponge, by its rounded ends; a stack of 13 g cups) out from between the pads. None:
    # the full force for every object (every result before 2026-12-07, session 41).
    gentle_below: float | None = 0.15

    def __post_init__(self) -> None:
        if not 0.0 <= self.unjam_turn_deg < 90.0:
            raise ValueError(f"PickConfig.unjam_turn_deg {self.unjam_turn_deg} must be in [0, 90) degrees (0: off)")
        if self.unjam_rise <= 0.0:
            raise ValueError(f"PickConfig.unjam_rise {self.unjam_rise} m must be > 0")
        if self.carry_margin < 0.0:
            raise ValueError(f"PickConfig.carry_margin {self.carry_margin} m must be >= 0")


def in_view_layout(whole_in_view: bool = True) -> TableLayout:
    """The testbed's table with ``PlacementConfig.whole_in_view`` set (``--in-view/--no-in-view``)."""
    layout = TableLayout()
    return dataclasses.replace(layout, placement=dataclasses.replace(layout.placement, whole_in_view=whole_in_view))


def sim_configs(
    gripper: str, wrist_look: bool, clearance: bool = False, fine_collision: bool = True,
    landing_check: bool = True, prefer_clear: bool = False, relocate: bool = True,
    whole_in_view: bool = True,
) -> tuple[EnvConfig, PickConfig, FingerGeometry]:
    """The env and pick settings behind the CLIs' ``--gripper``, ``--wrist-look``, ``--clearance``,
    ``--prefer-clear``, ``--relocate``, ``--fine-collision`` and ``--in-view``, and the hand's finger
    geometry for the grasp checks (``PipelineConfig.fingers``; ``--landing-check``).

    Raises ValueError for an unknown gripper (the message lists the choices).
    """
    spec = hand_spec(gripper)
    pick = PickConfig()
    pick = dataclasses.replace(pick, wrist=dataclasses.replace(pick.wrist, enabled=wrist_look),
                               clearance=dataclasses.replace(pick.clearance, enabled=clearance,
                                                             prefer=prefer_clear, relocate=relocate))
    env = EnvConfig(gripper=GripperConfig(hand=spec.name), physics=PhysicsConfig(fine_collision=fine_collision),
                    layout=in_view_layout(whole_in_view))
    return env, pick, dataclasses.replace(spec.fingers, check_landing=landing_check)


@dataclass(frozen=True)
class PickResult:
    """Outcome plus the physical evidence behind it."""

    outcome: Outcome
    held_body: int | None  # what the fingers held after the lift (None if nothing)
    target_rise: float  # m the target's centre rose by the end of the lift
    target_final_xyz: tuple[float, float, float]
    steps: int  # simulation steps the pick took
    detail: str = ""
    wrist_shift: float = 0.0  # m the wrist look moved the grasp along its closing axis
    wrist_frames: int = 0  # depth frames rendered from the wrist (robot time)
    # Where the descent ended: the TCP's height above its planned lowest point (m; None when the
    # arm never descended), and the other objects the arm or hand touched there. A miss with a
    # large gap is a hand resting on a neighbour, not a bad grasp (``figures.describe`` says so).
    descent_gap: float | None = None
    touching: tuple[str, ...] = ()


@dataclass(frozen=True)
class _Plan:
    pre: IKSolution
    descent: list[IKSolution]
    lift: list[IKSolution]
    transport: list[IKSolution]
    lower: list[IKSolution]
    grasp_z: float
    # the hand's lean at the release (a leaned grasp's, ``tool_quat``, named for the drop yaw's
    # closing axis): the retreat after the release keeps it
    lean: float = 0.0
    # what the carry check did, when it found the yaw-0 carry too close to the arm (else "")
    carry: str = ""


def _all_ok(robot: CR3Robot, solutions: list[IKSolution]) -> bool:
    return all(s.ok(robot.config) for s in solutions)


def release_spots(
    zone_xy: tuple[float, float], grasp_xy: tuple[float, float], grasp_yaw: float, drop_yaw: float,
    object_xy: tuple[float, float] | None,
) -> list[tuple[float, float]]:
    """Where the TCP may stand at release, in the order to try: first where the held object's
    centre comes over the zone's centre, then the zone's centre itself.

    Why: a long object held off-centre (a spatula by its handle, a wrench at one end, a skillet
    lid by its rim) came to rest outside the zone with the TCP over its centre (sim-val: 3 of
    378 CRAFT-E episodes). The object's offset from the grasp (``object_xy`` - ``grasp_xy``, from
    the ROI's depth points: what the robot saw before it moved) turns with the hand, by
    ``drop_yaw`` - ``grasp_yaw``. Without ``object_xy``, or an offset under 1 mm, only the centre.
    """
    spots = [zone_xy]
    if object_xy is None:
        return spots
    dx, dy = object_xy[0] - grasp_xy[0], object_xy[1] - grasp_xy[1]
    if math.hypot(dx, dy) < 1e-3:
        return spots
    turn = drop_yaw - grasp_yaw
    c, s = math.cos(turn), math.sin(turn)
    return [(zone_xy[0] - (c * dx - s * dy), zone_xy[1] - (s * dx + c * dy)), *spots]


@dataclass(frozen=True)
class _Approach:
    """The first stage of a pick's plan: the pre-grasp and the straight descent to the grasp,
    all the approach check (``obstructed``) reads. ``x``, ``y``, ``yaw``: the grasp's spot
    and the closing axis the hand keeps (``CR3Robot.nearest_yaw`` of the arm's posture then);
    ``lean``: the grasp's lean about that axis, kept for the whole pick."""

    pre: IKSolution
    descent: list[IKSolution]
    grasp_z: float
    x: float
    y: float
    yaw: float
    lean: float = 0.0


def _plan(
    robot: CR3Robot, scene: Scene, grasp: TopDownGrasp, cfg: PickConfig, rise: float = 0.0,
    object_xy: tuple[float, float] | None = None, object_points: npt.NDArray[np.float64] | None = None,
) -> _Plan | str:
    """All waypoints of the pick, or a string saying which one is unreachable: the approach
    (``_approach``), then the rest (``_complete``)."""
    approach = _approach(robot, scene, grasp, cfg)
    return approach if isinstance(approach, str) else _complete(robot, scene, approach, cfg, rise, object_xy,
                                                                 object_points)


def _approach(robot: CR3Robot, scene: Scene, grasp: TopDownGrasp, cfg: PickConfig) -> _Approach | str:
    """The pre-grasp and the descent of ``grasp``'s pick, or which one is unreachable.

    A leaned grasp (``grasp.lean``) comes in along its own approach axis, and its TCP stays high
    enough that the lower corners of the leaned finger tips keep the table clearance."""
    table_z = scene.layout.table_z
    x, y = float(grasp.position[0]), float(grasp.position[1])
    lean = float(grasp.lean)
    lowest = table_z + FINGERTIP_BELOW_TCP + cfg.table_clearance
    if lean != 0.0:  # the tips' centre rises, their outer corner comes down
        lowest = (table_z + cfg.table_clearance + FINGERTIP_BELOW_TCP * math.cos(lean)
                  + robot.gripper.hand.fingers.finger_half_width * abs(math.sin(lean)))
    grasp_z = max(float(grasp.position[2]) - cfg.insertion_depth, lowest)
    yaw = robot.nearest_yaw(grasp.yaw, robot.tcp_pose().yaw)
    if lean != 0.0 and _wrapped_by_pi(yaw - grasp.yaw):
        lean = -lean  # the same hand, its closing axis named the other way round
    up = None if lean == 0.0 else -tool_rotation(yaw, lean)[:, 2]  # a leaned hand's approach axis, upwards
    heights = (cfg.approach_height, *cfg.short_approach_heights)
    for height in heights:
        if up is None:
            pre = robot.solve_ik((x, y, grasp_z + height), yaw)
        else:
            pre = robot.solve_ik(tuple(float(v) for v in np.array([x, y, grasp_z]) + height * up), yaw, lean=lean)
        if pre.ok(robot.config):
            break
    else:
        lower = "".join(f", nor {h * 100:.0f} cm above the grasp" for h in heights[1:])
        return f"pre-grasp ({x:.3f}, {y:.3f}, {grasp_z + cfg.approach_height:.3f}) unreachable{lower}"
    descent = robot.plan_linear(pre.q, (x, y, grasp_z), yaw, lean)
    if not _all_ok(robot, descent):
        return f"grasp pose ({x:.3f}, {y:.3f}, {grasp_z:.3f}) unreachable"
    return _Approach(pre, descent, grasp_z, x, y, yaw, lean)


def _wrapped_by_pi(angle: float) -> bool:
    """Whether ``angle`` is nearer a half turn than a whole one (``nearest_yaw`` flipped it)."""
    return abs(math.remainder(angle, 2 * math.pi)) > math.pi / 2


def _complete(
    robot: CR3Robot, scene: Scene, approach: _Approach, cfg: PickConfig, rise: float = 0.0,
    object_xy: tuple[float, float] | None = None, object_points: npt.NDArray[np.float64] | None = None,
) -> _Plan | str:
    """The lift, transport and release after ``approach``, or which one is unreachable.

    The lift rises by ``rise`` (to carry the object over the tallest thing on the table) when
    that is reachable, else by ``cfg.lift_height``; feasibility is that of the plain lift, so
    ``plan_pick`` answers the same with or without ``rise``. With ``object_xy`` (the object's
    centre as seen) the release puts that centre over the zone when reachable
    (``release_spots``), else the TCP over the zone as without it: feasibility is unchanged.
    With ``object_points`` (the object's seen surface, world ``[n, 3]``) and
    ``PickConfig.carry_check``, a yaw-0 carry that would sweep the object into the arm is
    replaced by the first other way (``carry_yaws``) that keeps it clear; feasibility is that of
    the yaw-0 release, so ``plan_pick`` (which has no points) answers as before.
    """
    x, y, yaw, grasp_z, descent = approach.x, approach.y, approach.yaw, approach.grasp_z, approach.descent
    lean = approach.lean
    lift: list[IKSolution] = []
    found = False
    for height in ([rise] if rise > cfg.lift_height else []) + [cfg.lift_height]:
        for i in range(cfg.lift_inward_steps + 1):
            radius = math.hypot(x, y)
            shrink = max(0.0, 1.0 - i * cfg.lift_inward_step / radius) if radius > 0 else 1.0
            lift = robot.plan_linear(descent[-1].q, (x * shrink, y * shrink, grasp_z + height), yaw, lean)
            if _all_ok(robot, lift):
                found = True
                break
        if found:
            break
    if not found:
        return f"no reachable lift of {cfg.lift_height} m above ({x:.3f}, {y:.3f})"
    lift_end = robot.forward(lift[-1].q).position
    release_z = grasp_z + cfg.release_clearance
    held = (None if object_points is None or not cfg.carry_check or not len(object_points)
            else _in_tcp_frame(robot, descent[-1].q, object_points, scene.layout.table_z))
    why = ""
    first: _Plan | None = None
    hit = ""
    for preferred in carry_yaws((x, y), yaw, scene.layout.drop_zone.center,
                                (float(robot.base_position[0]), float(robot.base_position[1])))[: 1 if held is None else None]:
        drop_yaw = robot.nearest_yaw(preferred, yaw)
        drop_lean = lean if not _wrapped_by_pi(drop_yaw - yaw) else -lean
        for drop_x, drop_y in release_spots(scene.layout.drop_zone.center, (x, y), yaw, drop_yaw, object_xy):
            placed = _place(robot, lift, float(lift_end[2]), (drop_x, drop_y), drop_yaw, release_z, cfg, drop_lean)
            if isinstance(placed, str):
                why = placed
                continue
            plan = _Plan(approach.pre, descent, lift, placed[0], placed[1], grasp_z, drop_lean)
            touched = None if held is None else _carry_hit(robot, plan, held, cfg)
            if touched is None:
                if first is None:
                    return plan
                return dataclasses.replace(plan, carry=(
                    f"the carry turned the hand to {math.degrees(math.remainder(drop_yaw, math.pi)):+.0f}°: at 0° "
                    f"the object would come within {100 * cfg.carry_margin:.0f} cm of the arm ({hit})"))
            first, hit = first or plan, hit or touched
            break  # this yaw's carry comes too close to the arm: the next yaw
        if first is None:  # the yaw-0 release is out of reach: no other, as before
            break
    if first is not None:
        return dataclasses.replace(first, carry=f"every carry would bring the object within "
                                                f"{100 * cfg.carry_margin:.0f} cm of the arm ({hit}); carried at 0°")
    return why


def carry_yaws(grasp_xy: tuple[float, float], grasp_yaw: float, zone_xy: tuple[float, float],
               base_xy: tuple[float, float] = (0.0, 0.0)) -> list[float]:
    """The closing axis's yaws to carry an object to the zone with, in the order to try: 0 (the
    release of every run before session 44), then the grasp's yaw turned as far as the arm turns
    about its base from the grasp to the zone (the wrist still: the object keeps its place
    beside the arm, where it was clear of it at the grasp), then a quarter turn."""
    turn = math.atan2(zone_xy[1] - base_xy[1], zone_xy[0] - base_xy[0]) - math.atan2(
        grasp_xy[1] - base_xy[1], grasp_xy[0] - base_xy[0])
    return [0.0, grasp_yaw + turn, math.pi / 2]


def _in_tcp_frame(robot: CR3Robot, q: npt.NDArray[np.float64], points: npt.NDArray[np.float64],
                  table_z: float) -> npt.NDArray[np.float64]:
    """The seen surface ``points`` (world) and their feet on the table, in the frame of the TCP
    at joint angles ``q`` (the grasp): what moves with the hand once the object is held. The
    feet stand for the sides the overhead camera does not see."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    feet = pts.copy()
    feet[:, 2] = table_z
    tcp = robot.forward(q)
    local: npt.NDArray[np.float64] = (np.concatenate([pts, feet]) - tcp.position) @ tcp.rotation
    return local


#: The arm link the hand is mounted on: what the hand holds never moves relative to it, so the
#: carry cannot bring the object closer to it than the grasp did (the check skips it).
RIGID_WITH_HAND = frozenset({FLANGE_LINK})


def _carry_hit(robot: CR3Robot, plan: _Plan, held: npt.NDArray[np.float64], cfg: PickConfig) -> str | None:
    """The first arm link the held object (``held``, TCP frame) comes within
    ``cfg.carry_margin`` of at a waypoint of the carry (transport, then lowering), or None."""
    from scipy.spatial import cKDTree

    links = tuple(link for link in cfg.clearance.arm_links if link not in RIGID_WITH_HAND)
    hulls = link_hulls(robot.urdf_path, links, cfg.clearance.arm_spacing)
    for step in [*plan.transport, *plan.lower]:
        tcp, frames = robot.forward_and_frames(step.q)
        world = held @ tcp.rotation.T + tcp.position
        tree = cKDTree(world)
        for hull, points in zip(hulls, hull_points_world(hulls, frames, robot.base_position), strict=True):
            if tree.query(points, k=1, distance_upper_bound=cfg.carry_margin)[0].min() <= cfg.carry_margin:
                return hull.link
    return None


def _place(
    robot: CR3Robot, lift: list[IKSolution], lift_z: float, drop_xy: tuple[float, float], drop_yaw: float,
    release_z: float, cfg: PickConfig, lean: float = 0.0,
) -> tuple[list[IKSolution], list[IKSolution]] | str:
    """Transport from the lift's end to above ``drop_xy`` and the lowering to ``release_z``, or
    what is unreachable. Carried at the lift height if the spot is reachable there, else lower:
    the arm's reach shrinks with height and the zone lies near its edge."""
    drop_x, drop_y = drop_xy
    heights = np.arange(lift_z, release_z + cfg.min_transport_gap, -0.02)
    transport: list[IKSolution] = []
    for height in heights:
        transport = robot.plan_linear(lift[-1].q, (drop_x, drop_y, float(height)), drop_yaw, lean)
        if _all_ok(robot, transport):
            break
    else:
        return f"drop zone ({drop_x:.3f}, {drop_y:.3f}) unreachable below z={lift_z:.3f}"
    lower = robot.plan_linear(transport[-1].q, (drop_x, drop_y, release_z), drop_yaw, lean)
    if not _all_ok(robot, lower):
        return f"release pose ({drop_x:.3f}, {drop_y:.3f}, {release_z:.3f}) unreachable"
    return transport, lower


def plan_pick(
    env: SimEnv, grasp: TopDownGrasp, config: PickConfig | None = None, obstacles: HeightMap | None = None,
    plans: PlanCache | None = None,
) -> str | None:
    """Check a pick without moving: None if every waypoint is reachable (and, given the
    ``obstacles`` the overhead depth shows, clear of them), else what is wrong.

    The same plan ``execute_pick`` makes, so a robot can skip grasps it could not execute (IK and
    its own depth frame are information a real controller has before it moves).
    """
    cfg = config or PickConfig()
    unreachable, blocked = pick_problems(env, grasp, cfg, obstacles if cfg.clearance.enabled else None, plans)
    return unreachable or blocked


#: plans already made, by grasp and arm posture (``pick_problems``' ``plans``): the whole plan,
#: why it is unreachable, or only its approach when the rest was not needed yet
PlanCache = dict[tuple[bytes, float, float, bytes, int, float], "_Plan | _Approach | str"]


def pick_problems(
    env: SimEnv, grasp: TopDownGrasp, config: PickConfig, obstacles: HeightMap | None,
    plans: PlanCache | None = None, *, approach_first: bool = False,
) -> tuple[str | None, str | None]:
    """(why the pick is unreachable, what its approach would touch among ``obstacles``), from one
    plan; the second is None when the pick is unreachable or no ``obstacles`` are given.
    ``plan_pick`` is the filter; ``ClearanceConfig.prefer`` uses the second answer alone.

    ``plans``: reuse a plan made before for the same grasp from the same arm posture with the
    same settings (the robot's path plans the chosen grasp's IK, then checks its clearance for
    relocation: one plan, not two). The plan is a function of exactly these inputs.

    ``approach_first``: for a caller that only needs to know whether both answers are None (the
    relocation search, ``relocate.relocate_if_blocked``): the approach is planned and checked
    first, and when it is blocked, that is the answer, without planning the lift, transport and
    release (most of a plan's IK waypoints: 86 % of the chosen picks' on sim-dev); the first
    answer is then None even if they are unreachable. Both answers are None exactly when they
    are without it."""
    key = (np.asarray(grasp.position, np.float64).tobytes(), float(grasp.yaw), float(grasp.width_m),
           env.robot.joint_positions().tobytes(), id(config), float(grasp.lean))
    made = plans.get(key) if plans is not None else None
    if made is None:
        made = _approach(env.robot, env.scene, grasp, config)
    blocked: str | None = None
    checked = False  # ``blocked`` holds the approach check's answer
    if isinstance(made, _Approach) and approach_first and obstacles is not None:
        blocked, checked = obstructed(env.robot, made, obstacles, config.clearance, grasp_first=True), True
    if isinstance(made, _Approach) and blocked is None:
        made = _complete(env.robot, env.scene, made, config)
    if plans is not None:
        plans[key] = made  # only the approach when it was blocked
    if isinstance(made, str):
        return made, None
    if checked or obstacles is None:
        return None, blocked
    return None, obstructed(env.robot, made, obstacles, config.clearance)


def obstructed(
    robot: CR3Robot, plan: _Plan | _Approach, obstacles: HeightMap, cfg: ClearanceConfig, *, grasp_first: bool = False,
) -> str | None:
    """Would the approach touch what the depth camera sees? The joint path from the arm's
    current posture to the pre-grasp (arm and hand), then the descent's end (the grasp): the
    first pose, in that order, that would touch, and what.

    ``grasp_first``: for a caller that only asks *whether* the approach is clear (the relocation
    search): the grasp pose is checked alone first (a spot blocked there needs no path check),
    then the path (the same verdict; when the grasp pose is blocked, the message names
    its contact even if the path touched something earlier)."""
    boxes = robot.gripper.hand.clearance_boxes
    hulls = link_hulls(robot.urdf_path, cfg.arm_links, cfg.arm_spacing)
    start, pre = robot.joint_positions(), plan.pre.q
    path = [start + t * (pre - start) for t in np.linspace(0.0, 1.0, cfg.path_samples + 1)[1:]]
    poses = [*path, plan.descent[-1].q]
    parts = [(h.link, len(h.points)) for h in hulls]

    def check(qs: list[npt.NDArray[np.float64]]) -> str | None:
        walked = [robot.forward_and_frames(q) for q in qs]  # one chain walk per pose
        arm = np.array([np.concatenate(hull_points_world(hulls, frames, robot.base_position))
                        for _, frames in walked])
        if plan.lean != 0.0:  # the hand leans: its boxes in 3D, turned with the TCP
            return leaned_first_hit(np.array([t.position for t, _ in walked]),
                                    np.array([t.rotation for t, _ in walked]), arm, parts, boxes, obstacles, cfg)
        # the poses in order, hand before arm: hand_hits / arm_hits pose by pose, in one lookup each
        return first_hit(np.array([t.position for t, _ in walked]), [t.yaw for t, _ in walked], arm,
                         parts, boxes, obstacles, cfg)

    # with grasp_first, the path's first contact when the grasp pose is clear, as without it
    why = (check(poses[-1:]) or check(poses[:-1])) if grasp_first else check(poses)
    return None if why is None else f"approach blocked: {why}"


def _body_z(scene: Scene, body: int) -> float:
    return float(scene.pose(body)[0][2])


class _InHand:
    """Motion monitor: is ``body`` still held?

    Held means pinched between both fingers, or still where it was in the hand when the motion
    started. Either alone misjudges: contact lists flicker from step to step on small objects
    that are held perfectly well, and a long object pinched off-centre may swing about the
    fingers without being lost. A real slip fails both.
    """

    def __init__(self, robot: CR3Robot, scene: Scene, body: int, cfg: PickConfig) -> None:
        self.robot, self.scene, self.body = robot, scene, body
        self.tolerance = cfg.slip_tolerance
        self.ignore = frozenset({scene.table_id})
        self.offset = self._offset()

    def _offset(self) -> npt.NDArray[np.float64]:
        tcp = self.robot.tcp_pose()
        offset: npt.NDArray[np.float64] = tcp.rotation.T @ (
            self.scene.pose(self.body)[0] - tcp.position
        )
        return offset

    def __call__(self) -> bool:
        if float(np.linalg.norm(self._offset() - self.offset)) <= self.tolerance:
            return True
        return self.robot.gripper.check_grasp(self.ignore) == self.body


@dataclass
class _Progress:
    """What a pick has established so far, to build its result from any exit point."""

    env: SimEnv
    target_body: int
    start_steps: int
    start_z: float
    rise: float = 0.0
    wrist_shift: float = 0.0
    wrist_frames: int = 0
    descent_gap: float | None = None
    touching: tuple[str, ...] = ()

    def measure_descent(self, planned_z: float) -> None:
        """Read-only: where the TCP stopped, and which other objects the robot touches."""
        robot, scene = self.env.robot, self.env.scene
        self.descent_gap = float(robot.tcp_pose().position[2]) - planned_z
        bodies = {int(c[2]) for c in p.getContactPoints(bodyA=robot.body_id, physicsClientId=scene.client)}
        names = (scene.object_by_body(b) for b in sorted(bodies - {self.target_body}))
        self.touching = tuple(o.asset_id for o in names if o is not None)

    def measure_rise(self) -> float:
        self.rise = _body_z(self.env.scene, self.target_body) - self.start_z
        return self.rise

    def finish(self, outcome: Outcome, held: int | None, detail: str = "") -> PickResult:
        pos = self.env.scene.pose(self.target_body)[0]
        return PickResult(
            outcome=outcome,
            held_body=held,
            target_rise=self.rise,
            target_final_xyz=(float(pos[0]), float(pos[1]), float(pos[2])),
            steps=self.env.steps - self.start_steps,
            detail=detail,
            wrist_shift=self.wrist_shift,
            wrist_frames=self.wrist_frames,
            descent_gap=self.descent_gap,
            touching=self.touching,
        )


def execute_pick(
    env: SimEnv,
    grasp: TopDownGrasp | None,
    target_body: int,
    config: PickConfig | None = None,
    object_xy: tuple[float, float] | None = None,
    object_size: float | None = None,
    object_points: npt.NDArray[np.float64] | None = None,
) -> PickResult:
    """Run the pick in ``env``'s current scene and classify what happened.

    ``object_xy``: the object's centre on the table as the robot saw it (``object_centre``);
    given, the release puts it, not the TCP, over the drop zone's centre when reachable.
    ``object_size``: the object's longest edge as the robot saw it (m); under
    ``PickConfig.gentle_below``, the hand closes gently (``HandSpec.gentle_force``).
    ``object_points``: the object's surface as the robot saw it (world ``[n, 3]``,
    ``surface.object_points``); given, the carry keeps it clear of the arm
    (``PickConfig.carry_check``)."""
    cfg = config or PickConfig()
    robot, scene = env.robot, env.scene
    progress = _Progress(env, target_body, env.steps, _body_z(scene, target_body))
    ignore = frozenset({scene.table_id})
    if grasp is None:
        return progress.finish(Outcome.NO_GRASP, None, "no grasp candidate")
    rise = _clearing_rise(env, cfg)
    plan = _plan(robot, scene, grasp, cfg, rise, object_xy, object_points)
    if isinstance(plan, str):
        return progress.finish(Outcome.IK_FAILURE, None, plan)

    robot.gripper.open()
    robot.follow([plan.pre.q])
    plan = _look_and_replan(env, grasp, plan, cfg, progress, rise, object_xy, object_points)
    robot.follow([s.q for s in plan.descent])
    progress.measure_descent(plan.grasp_z)
    robot.gripper.close(gentle=cfg.gentle_below is not None and object_size is not None
                        and object_size < cfg.gentle_below)
    pinched = robot.gripper.check_grasp(ignore)
    if pinched is None:
        return progress.finish(Outcome.MISSED, None, "fingers closed on nothing")

    in_hand = _InHand(robot, scene, pinched, cfg)
    lifted = robot.follow([s.q for s in plan.lift], monitor=in_hand)
    if lifted and cfg.hold_steps > 0:  # hold still: does the body stay in the hand?
        env.step(cfg.hold_steps)
        lifted = in_hand()
    rise = progress.measure_rise()
    if not lifted:
        return progress.finish(
            Outcome.LIFT_FAILED, None, f"lost the grip while lifting (target rose {rise:.3f} m)"
        )
    if pinched != target_body:
        return progress.finish(
            Outcome.WRONG_OBJECT, pinched, f"lifted body {pinched}, target is {target_body}"
        )
    if rise < cfg.min_lift_rise:
        support = _supports(scene, target_body, robot.body_id)
        if support:
            return progress.finish(Outcome.LIFT_FAILED, pinched,
                                   f"target rose only {rise:.3f} m and still rests on {support}")

    in_hand = _InHand(robot, scene, target_body, cfg)
    carried = robot.follow([s.q for s in plan.transport], monitor=in_hand)
    if carried:
        carried = robot.follow([s.q for s in plan.lower], monitor=in_hand)
    if not carried:
        return progress.finish(Outcome.SLIP_DURING_TRANSPORT, None,
                               "; ".join(filter(None, ("target lost during transport", plan.carry))))
    robot.gripper.open()
    released_z = _body_z(scene, target_body)
    release = robot.forward(plan.lower[-1].q).position
    retreat = release + np.array([0.0, 0.0, cfg.retreat_height])
    yaw = robot.tcp_pose().yaw
    robot.move_linear(retreat, yaw, plan.lean)
    wedged = ""
    if cfg.unjam_turn_deg > 0.0 and _body_z(scene, target_body) - released_z > cfg.unjam_rise:
        turn = _unjam(robot, scene, target_body, release, yaw, plan.lean, released_z, cfg)
        wedged = ("it stayed wedged between the open fingers, turning the hand did not free it" if turn is None
                  else f"it stayed wedged between the open fingers; set down, the hand turned {turn:+.0f}° and "
                       "let it go")
    env.step(cfg.release_settle_steps)

    in_zone = _in_drop_zone(scene, target_body)
    outside = "target came to rest outside the drop zone"
    detail = wedged if in_zone else (f"{outside} ({wedged})" if wedged else outside)
    return progress.finish(
        Outcome.SUCCESS if in_zone else Outcome.OUTSIDE_DROP_ZONE,
        target_body,
        "; ".join(filter(None, (detail, plan.carry))),
    )


def _unjam(robot: CR3Robot, scene: Scene, body: int, release: npt.NDArray[np.float64], yaw: float, lean: float,
           released_z: float, cfg: PickConfig) -> float | None:
    """The target rose with the open hand (a wrist camera would see it between the fingers; the
    simulation reads its height): set it down near the zone, turn the hand about the vertical so
    the fingers no longer wedge it, and retreat; each way in turn until it stays down. Returns
    the turn (degrees) that freed it, or None.

    Why: an object nearly as wide as the open hand (the sponge, 7.2 cm against the Franka hand's
    8 cm) can end up across the fingers at a slant after the carry and ride back up with them:
    sim-dev's ``wipe/sponge/2`` at ``--seed 1`` came to rest outside the zone that way."""
    low = release - np.array([0.0, 0.0, 0.8 * cfg.release_clearance])  # the object's bottom ~6 mm up
    up = release + np.array([0.0, 0.0, cfg.retreat_height])
    for turn in (cfg.unjam_turn_deg, -cfg.unjam_turn_deg):
        robot.move_linear(low, yaw, lean)
        robot.move_linear(low, yaw + math.radians(turn), lean)
        robot.move_linear(up, yaw + math.radians(turn), lean)
        if _body_z(scene, body) - released_z <= cfg.unjam_rise:
            return turn
    return None


def _supports(scene: Scene, body: int, robot_body: int) -> str:
    """What ``body`` touches besides the robot ("" when only the robot holds it): the table, or
    the names of the other objects it leans on."""
    touched = {int(c[2]) for c in p.getContactPoints(bodyA=body, physicsClientId=scene.client)} - {robot_body}
    if not touched:
        return ""
    names = {o.body_id: o.name for o in scene.objects}
    return ", ".join(sorted("the table" if b == scene.table_id else names.get(b, f"body {b}") for b in touched))


def _clearing_rise(env: SimEnv, cfg: PickConfig) -> float:
    """How far to lift so that the held object's bottom clears every surface in view.

    From the overhead depth frame (the arm is at home, out of view, before a pick starts): the
    highest surface above the table plus ``obstacle_margin``; 0 when disabled.
    """
    if not cfg.clear_obstacles:
        return 0.0
    z = env.capture().points_world()[..., 2]
    z = z[np.isfinite(z)]
    table_z = env.scene.layout.table_z
    top = float(z.max()) if z.size else table_z
    return max(0.0, top - table_z) + cfg.obstacle_margin


def _look_and_replan(
    env: SimEnv, grasp: TopDownGrasp, plan: _Plan, cfg: PickConfig, progress: _Progress,
    rise: float, object_xy: tuple[float, float] | None = None,
    object_points: npt.NDArray[np.float64] | None = None,
) -> _Plan:
    """At pre-grasp: one wrist depth frame, re-centre the grasp, re-plan the rest of the pick.

    Keeps the original plan when the look finds nothing to correct or the corrected pick is not
    reachable (the arm is already at a reachable pre-grasp).
    """
    if not cfg.wrist.enabled or grasp.lean != 0.0:  # the wrist camera's look is top-down only
        return plan
    robot, scene = env.robot, env.scene
    tcp = robot.tcp_pose()
    obs = look(env.client, tcp.position, tcp.yaw, cfg.wrist)
    progress.wrist_frames += 1
    tip_z = plan.grasp_z - FINGERTIP_BELOW_TCP
    correction = recentre(obs, grasp, tip_z, scene.layout.table_z, cfg.wrist)
    if correction.shift == 0.0:
        return plan
    replanned = _plan(robot, scene, correction.grasp, cfg, rise, object_xy, object_points)
    if isinstance(replanned, str):
        return plan
    robot.follow([replanned.pre.q])
    progress.wrist_shift = correction.shift
    return replanned


def _in_drop_zone(scene: Scene, body: int) -> bool:
    """Centre of mass over the zone, and the body in contact with the table (not still held,
    not lying on another object)."""
    position = scene.pose(body)[0]
    dz = scene.layout.drop_zone
    over = dz.x_min <= position[0] <= dz.x_max and dz.y_min <= position[1] <= dz.y_max
    on_table = bool(p.getContactPoints(body, scene.table_id, physicsClientId=scene.client))
    return bool(over and on_table)
