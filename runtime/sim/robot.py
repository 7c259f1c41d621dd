"""The Dobot CR3 with a parallel gripper (``hands.py``): top-down IK and step-counted motions.

Motions are joint-space paths played back with position control for a number of simulation steps
computed from the path length (never from wall-clock time), so an episode is a pure function of
its seed. IK uses pybullet's ``calculateInverseKinematics`` seeded from the current
configuration, and Newton steps on the chain model for the waypoints of straight-line moves, each
seeded with the previous one (``local_ik``); every answer is checked against a numpy
forward-kinematics model before the arm moves, so an unreachable pose is reported instead of
half-executed.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pybullet as p
from scipy.spatial.transform import Rotation

from .gripper import GripperConfig, ParallelGripper
from .kinematics import Mat4, SerialChain, load_chain
from .local_ik import ChainIK, checked_answer
from .robot_urdf import (
    HAND_JOINT,
    TCP_JOINT,
    TCP_LINK,
    robot_urdf_path,
)
from .transforms import quat_to_matrix, rpy_to_quat

FloatArray = npt.NDArray[np.float64]
Point3 = Sequence[float] | FloatArray

ARM_JOINTS = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6")
# Gripper down with the TCP at (0.15, -0.15, 0.35): clear of the overhead camera's view, and a
# posture from which IK converges over the whole workspace (98% of a test grid, the rest at the
# reach limit).
HOME_Q = np.array([-0.136, 0.384, -1.126, -0.829, 1.5708, 0.912])
#: Decimals (radians) of the joint targets the arm is sent (``CR3Robot.follow``). IK's answers
#: depend on the host's numpy kernels (OpenBLAS picks its matrix kernels per CPU; numpy its own
#: loops), not only in their last bits: Newton and pybullet's solver stop within a tolerance, so
#: a waypoint's joints moved by up to 8e-11 rad under other kernels on the development host (ad
#: hoc, sim-dev's pour/cup/2). The physics amplifies any such difference into another outcome
#: (pinning OpenBLAS to another kernel set changed 2 of 222 pickability outcomes), and a first
#: grid of 1e-9 rad still let one sim-dev pick diverge. Rounded to 1e-5 rad (5 micrometres at
#: the arm's reach, below the CR3's 0.02 mm repeatability) two hosts send the same targets
#: unless a value lies within that difference of a rounding boundary: about 2 values in 10^5.
JOINT_TARGET_DECIMALS = 5


def joint_targets(q: FloatArray) -> FloatArray:
    """``q`` as the arm is sent it: rounded to ``JOINT_TARGET_DECIMALS`` (elementwise IEEE
    operations, so the same bits on every host)."""
    return np.asarray(q, dtype=np.float64).round(JOINT_TARGET_DECIMALS)


def top_down_rotation(yaw: float) -> FloatArray:
    """TCP orientation with the approach axis pointing down and the closing axis at ``yaw``.

    The hand closes along its local y axis; ``Rz(yaw + pi/2) @ Rx(pi)`` sends that axis to
    ``(cos yaw, sin yaw, 0)`` and the approach axis z to world -z. Read-only: the matrix of a
    yaw is made once (``_top_down_rotation``), since a plan asks for the same yaw at every
    waypoint of a line (~50 per pick on the robot's path).
    """
    return _top_down_rotation(float(yaw))


@functools.lru_cache(maxsize=64)
def _top_down_rotation(yaw: float) -> FloatArray:
    rotation = quat_to_matrix(top_down_quat(yaw))
    rotation.flags.writeable = False
    return rotation


def top_down_quat(yaw: float) -> tuple[float, float, float, float]:
    """``top_down_rotation`` as an (x, y, z, w) quaternion."""
    return rpy_to_quat(math.pi, 0.0, yaw + math.pi / 2)


def tool_quat(yaw: float, lean: float = 0.0) -> tuple[float, float, float, float]:
    """The TCP orientation of a grasp with closing axis ``yaw``, leaned by ``lean`` (rad) about
    that axis, as an (x, y, z, w) quaternion: ``top_down_quat(yaw)`` exactly when ``lean`` is 0.

    Why a lean: a top-down grasp fixes the wrist's height above the object, and beside a tall
    object the CR3's wrist links then come down on it (sim-dev's ``cut/knife/1``: no top-down
    spot of the knife is clear). Leaning the hand about its closing axis keeps the pads level and
    closing along the same line, and swings the wrist sideways (``relocate.py``).
    """
    if lean == 0.0:
        return top_down_quat(yaw)
    return _leaned_quat(float(yaw), float(lean))


@functools.lru_cache(maxsize=64)
def _leaned_quat(yaw: float, lean: float) -> tuple[float, float, float, float]:
    c, s = math.cos(lean), math.sin(lean)
    about_closing = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # Ry(lean): the hand's y closes
    x, y, z, w = Rotation.from_matrix(top_down_rotation(yaw) @ about_closing).as_quat()
    return float(x), float(y), float(z), float(w)


def tool_rotation(yaw: float, lean: float = 0.0) -> FloatArray:
    """``tool_quat`` as a read-only matrix: ``top_down_rotation(yaw)`` when ``lean`` is 0."""
    return top_down_rotation(yaw) if lean == 0.0 else quat_to_matrix(_leaned_quat(float(yaw), float(lean)))


def closing_yaw(rotation: FloatArray) -> float:
    """World yaw of the closing axis (the hand's y axis) of a TCP rotation."""
    axis = rotation[:, 1]
    return math.atan2(float(axis[1]), float(axis[0]))


def rotation_angle(a: FloatArray, b: FloatArray) -> float:
    """Angle of the relative rotation between two rotation matrices (rad). The trace is summed
    on Python floats in ``np.trace``'s order (the same additions, without its per-call cost:
    every IK waypoint of a plan checks its angle)."""
    diagonal = np.diagonal(a.T @ b).tolist()
    cos = (diagonal[0] + diagonal[1] + diagonal[2] - 1.0) / 2.0
    return float(math.acos(max(-1.0, min(1.0, cos))))


@dataclass(frozen=True)
class ArmConfig:
    """Motion and IK tolerances. Speeds only set how many steps a motion gets."""

    max_joint_speed: float = 2.0  # rad/s peak along a path (the CR3 is rated 3.14)
    min_steps: int = 24
    settle_steps: int = 24
    monitor_every: int = 10  # steps between checks of a motion's monitor
    force: float = 150.0  # N·m, the effort the fixed URDF declares
    position_gain: float = 0.3
    ik_rounds: int = 8
    ik_null_space: bool = False  # pass joint limits to the solver (see CR3Robot.solve_ik)
    ik_local: bool = True  # Newton steps on the chain model for seeded waypoints (local_ik.py)
    ik_position_tol: float = 0.005  # m, the brief's "within 5 mm"
    ik_angle_tol: float = 0.035  # rad (2 degrees)
    cartesian_step: float = 0.02  # m between IK waypoints on straight-line moves
    # A waypoint of a straight-line move that IK misses is tried again in this many equal
    # sub-steps from the last good one (below 2: never). From a stretched arm (elbow near
    # straight, a singular Jacobian) the first 2 cm back towards the base needs the elbow to bend
    # by ~0.4 rad at once: Newton declines so long a step and pybullet's damped solver stops
    # ~1 cm short, which rejected reachable picks ("drop zone unreachable"); half steps get there.
    ik_split_failed: int = 2
    time_step: float = 1.0 / 240.0


@dataclass(frozen=True)
class IKSolution:
    """An IK answer with its forward-kinematics check."""

    q: FloatArray
    position_error: float
    angle_error: float
    within_limits: bool

    def ok(self, config: ArmConfig) -> bool:
        return (
            self.within_limits
            and self.position_error <= config.ik_position_tol
            and self.angle_error <= config.ik_angle_tol
        )


@dataclass(frozen=True)
class TcpPose:
    """Measured TCP pose in the world frame."""

    position: FloatArray
    rotation: FloatArray

    @property
    def yaw(self) -> float:
        return closing_yaw(self.rotation)

    @property
    def lean(self) -> float:
        """The hand's lean about its closing axis (rad; ``tool_quat``): ~0 for a top-down TCP."""
        relative = top_down_rotation(self.yaw).T @ self.rotation
        return math.atan2(float(relative[0, 2]), float(relative[0, 0]))


class CR3Robot:
    """Loads the composed CR3 URDF into one pybullet client and drives it."""

    def __init__(
        self,
        client: int,
        step: Callable[[int], None],
        base_position: Sequence[float] = (0.0, 0.0, 0.0),
        config: ArmConfig | None = None,
        gripper_config: GripperConfig | None = None,
    ) -> None:
        self.client = client
        self.config = config or ArmConfig()
        self._step = step
        gripper_config = gripper_config or GripperConfig()
        urdf = robot_urdf_path(gripper_config.hand)
        self.base_position = np.asarray(base_position, dtype=np.float64)
        self.urdf_path = urdf  # the composed URDF: its link meshes are the clearance check's arm
        self.body_id = p.loadURDF(
            str(urdf),
            basePosition=list(self.base_position),
            useFixedBase=True,
            physicsClientId=client,
        )
        names = self._joint_names()
        self.arm_joints = [names.index(n) for n in ARM_JOINTS]
        # pybullet link index == index of the joint that has the link as its child
        self.tcp_link = names.index(TCP_JOINT)
        self.hand_link = names.index(HAND_JOINT)
        self.movable_joints = [
            j
            for j in range(len(names))
            if p.getJointInfo(self.body_id, j, physicsClientId=client)[2] != p.JOINT_FIXED
        ]
        self._lower, self._upper = self._limits()
        self._limit_pairs = list(zip(self._lower.tolist(), self._upper.tolist(), strict=True))
        self._arm_slots = [self.movable_joints.index(j) for j in self.arm_joints]  # IK's joint order
        self.chain: SerialChain = load_chain(urdf, TCP_LINK)
        self._local_ik = ChainIK(self.chain)
        self.gripper = ParallelGripper(
            client, self.body_id, {n: i for i, n in enumerate(names)}, step, gripper_config
        )
        self.reset_home()

    # ----------------------------------------------------------------- state
    def _joint_names(self) -> list[str]:
        n = p.getNumJoints(self.body_id, physicsClientId=self.client)
        return [
            p.getJointInfo(self.body_id, j, physicsClientId=self.client)[1].decode()
            for j in range(n)
        ]

    def _limits(self) -> tuple[FloatArray, FloatArray]:
        infos = [
            p.getJointInfo(self.body_id, j, physicsClientId=self.client) for j in self.arm_joints
        ]
        return np.array([i[8] for i in infos]), np.array([i[9] for i in infos])

    def joint_positions(self) -> FloatArray:
        states = p.getJointStates(self.body_id, self.arm_joints, physicsClientId=self.client)
        return np.array([s[0] for s in states], dtype=np.float64)

    def tcp_pose(self) -> TcpPose:
        """The TCP as pybullet currently has it (the physical truth, not the model)."""
        state = p.getLinkState(
            self.body_id, self.tcp_link, computeForwardKinematics=True, physicsClientId=self.client
        )
        rotation = quat_to_matrix(state[5])
        return TcpPose(np.array(state[4], dtype=np.float64), rotation)

    def forward(self, q: FloatArray) -> TcpPose:
        """Model TCP pose for arm configuration ``q`` (no simulation state is touched): the
        chain's compiled walk (``local_ik``; ``SerialChain.forward``'s pose to float rounding,
        ~15x faster: every pybullet IK answer and every straight line of a plan is checked
        with it)."""
        rotation, position = self._local_ik.pose(q)
        return TcpPose(position + self.base_position, rotation)

    def forward_and_frames(self, q: FloatArray) -> tuple[TcpPose, dict[str, Mat4]]:
        """``forward(q)`` and every joint's child frame (4x4, the chain's root frame: add
        ``base_position`` for the world) from one walk of the model chain."""
        end, frames = self._local_ik.walk(q)
        return TcpPose(end[:3, 3] + self.base_position, end[:3, :3]), self._local_ik.joint_frames(frames)

    def reset_home(self) -> None:
        """Teleport to the home configuration (setup only) and hold it."""
        for joint, value in zip(self.arm_joints, HOME_Q, strict=True):
            p.resetJointState(self.body_id, joint, float(value), physicsClientId=self.client)
        self.gripper.reset_open()
        self._command(HOME_Q)

    # -------------------------------------------------------------------- IK
    def nearest_yaw(self, yaw: float, reference: float) -> float:
        """``yaw`` or ``yaw + pi`` (the same parallel grasp), whichever is closer to reference.

        Keeps the wrist from spinning half a turn between waypoints.
        """
        best = yaw
        for candidate in (yaw - math.pi, yaw, yaw + math.pi):
            if abs(_wrap(candidate - reference)) < abs(_wrap(best - reference)):
                best = candidate
        return best

    def solve_ik(self, position: Point3, yaw: float, seed: FloatArray | None = None, lean: float = 0.0) -> IKSolution:
        """Top-down IK for the TCP at ``position`` with closing axis ``yaw`` (leaned by ``lean``
        about that axis, ``tool_quat``).

        An explicit ``seed`` close to the target (a waypoint of a straight-line move) is solved by
        Newton steps on the chain model (``local_ik``, a plan ~3x cheaper; ``ArmConfig.ik_local``);
        otherwise, or if Newton does not converge, pybullet's solver takes damped steps from the
        seed, and re-seeding with its own answer for a few rounds converges to < 1 mm wherever
        the pose is reachable. By default the joint limits
        are enforced after the fact (wrapping revolute joints by 2π where that helps, then
        rejecting what is still outside), because the solver's null-space mode, which takes the
        limits as input, was measured to reach fewer poses (84% vs 98% of a workspace grid);
        ``ArmConfig.ik_null_space`` switches it on.
        """
        target = np.asarray(position, dtype=np.float64)
        rotation = tool_rotation(yaw, lean)
        if seed is not None and self.config.ik_local:
            local = self._solve_local(target, rotation, np.asarray(seed, dtype=np.float64))
            if local is not None:
                return local
        quat = tool_quat(yaw, lean)
        q = self.joint_positions() if seed is None else np.asarray(seed, dtype=np.float64)
        current = [0.0] * len(self.movable_joints)
        arm_slots = self._arm_slots
        target_list = target.tolist()
        null_space = self._null_space(arm_slots)
        best: IKSolution | None = None
        for _ in range(self.config.ik_rounds):
            for slot, value in zip(arm_slots, q.tolist(), strict=True):
                current[slot] = value
            full = p.calculateInverseKinematics(
                self.body_id,
                self.tcp_link,
                target_list,
                quat,
                currentPositions=current,
                maxNumIterations=100,
                residualThreshold=1e-6,
                physicsClientId=self.client,
                **null_space,
            )
            q = self._into_limits(np.array([full[s] for s in arm_slots], dtype=np.float64))
            pose = self.forward(q)
            solution = IKSolution(
                q=q,
                position_error=float(np.linalg.norm(pose.position - target)),
                angle_error=rotation_angle(pose.rotation, rotation),
                within_limits=bool(np.all(q >= self._lower) and np.all(q <= self._upper)),
            )
            if best is None or solution.position_error < best.position_error:
                best = solution
            if solution.position_error < 1e-4 and solution.angle_error < 1e-3:
                break
        assert best is not None
        return best

    def _solve_local(self, target: FloatArray, rotation: FloatArray, seed: FloatArray) -> IKSolution | None:
        """Newton IK from a nearby seed (``local_ik``), checked like pybullet's answers; None
        when Newton does not apply (the caller then runs pybullet's solver)."""
        found = self._local_ik.solve(rotation, target - self.base_position, seed)
        if found is None:
            return None
        q, reached, at = found
        # whole turns of a joint (the same pose) and the errors, as the pybullet path checks its
        # answers (``_into_limits_checked``, ``rotation_angle``), compiled
        q, within, position_error, angle_error = checked_answer(
            q, reached, at, rotation, target - self.base_position, self._lower, self._upper)
        solution = IKSolution(q=q, position_error=position_error, angle_error=angle_error, within_limits=within)
        # Not good enough (outside the limits, say): pybullet's solver may find another posture.
        return solution if solution.ok(self.config) else None

    def _null_space(self, arm_slots: list[int]) -> dict[str, list[float]]:
        """Limit arguments for the solver's null-space mode (empty unless configured)."""
        if not self.config.ik_null_space:
            return {}
        n = len(self.movable_joints)
        lower, upper, rest = [-1.0] * n, [1.0] * n, [0.0] * n  # fingers: never moved by IK
        for slot, lo, hi, home in zip(arm_slots, self._lower, self._upper, HOME_Q, strict=True):
            lower[slot], upper[slot], rest[slot] = float(lo), float(hi), float(home)
        ranges = [hi - lo for lo, hi in zip(lower, upper, strict=True)]
        return {
            "lowerLimits": lower,
            "upperLimits": upper,
            "jointRanges": ranges,
            "restPoses": rest,
        }

    def _into_limits(self, q: FloatArray) -> FloatArray:
        """``q`` with each joint outside its limits shifted by +-2 pi where that lands inside
        (Python floats: the same IEEE additions and comparisons as on numpy scalars, faster)."""
        return self._into_limits_checked(q)[0]

    def _into_limits_checked(self, q: FloatArray) -> tuple[FloatArray, bool]:
        """``_into_limits(q)`` and whether every joint of it is within its limits (the check of
        ``np.all(q >= lower) and np.all(q <= upper)``, NaN outside, on the same floats)."""
        wrapped = q.tolist()
        for i, (lower, upper) in enumerate(self._limit_pairs):
            for shift in (2 * math.pi, -2 * math.pi):
                if not lower <= wrapped[i] <= upper:
                    candidate = wrapped[i] + shift
                    if lower <= candidate <= upper:
                        wrapped[i] = candidate
        within = all(lower <= v <= upper for v, (lower, upper) in zip(wrapped, self._limit_pairs, strict=True))
        return np.array(wrapped, dtype=np.float64), within

    def plan_linear(self, start_q: FloatArray, target: Point3, yaw: float, lean: float = 0.0) -> list[IKSolution]:
        """IK waypoints every ``cartesian_step`` along the straight TCP line to ``target``.

        Each waypoint is seeded with the previous one, so the arm keeps one posture along the
        line. While every waypoint so far is good, one that IK misses is tried again in
        ``ik_split_failed`` sub-steps from the last good one; if they all succeed they join the
        line (a finer stretch of the same straight path), else the miss stays and the rest of the
        line is solved as before. Returns all waypoints; callers check ``ok`` on each.
        """
        start = self.forward(start_q).position
        goal = np.asarray(target, dtype=np.float64)
        n = max(1, math.ceil(float(np.linalg.norm(goal - start)) / self.config.cartesian_step))
        seed = start_q
        solutions: list[IKSolution] = []
        intact = True  # every waypoint so far is good: only then is a miss worth a retry
        point = start
        for i in range(1, n + 1):
            last, point = point, start + (goal - start) * i / n
            solution = self.solve_ik(point, yaw, seed=seed, lean=lean)
            split = False
            if intact and not solution.ok(self.config):
                finer = self._split_step(solutions[-1].q if solutions else start_q, last, point, yaw, lean)
                if finer is not None:
                    solutions.extend(finer[:-1])
                    solution, split = finer[-1], True
                else:
                    intact = False
            solutions.append(solution)
            # Newton IK's next seed continues the last step (the joints move smoothly along a
            # line): it starts closer and needs one step fewer, converging to the same posture.
            # Not after a split, whose last step is shorter than the next.
            seed = solution.q
            if self.config.ik_local and len(solutions) > 1 and not split:
                step = solution.q - solutions[-2].q
                if float(np.abs(step).max()) < 0.2:
                    seed = solution.q + step
        return solutions

    def _split_step(self, seed: FloatArray, frm: FloatArray, to: FloatArray, yaw: float,
                    lean: float = 0.0) -> list[IKSolution] | None:
        """The waypoints of ``ik_split_failed`` equal sub-steps from ``frm`` (where the arm is at
        ``seed``) to ``to``, each seeded with the last, or None if one of them is missed too."""
        k = self.config.ik_split_failed
        if k < 2:
            return None
        out: list[IKSolution] = []
        for j in range(1, k + 1):
            solution = self.solve_ik(frm + (to - frm) * j / k, yaw, seed=seed, lean=lean)
            if not solution.ok(self.config):
                return None
            out.append(solution)
            seed = solution.q
        return out

    # ---------------------------------------------------------------- motion
    def _command(self, q: FloatArray) -> None:
        p.setJointMotorControlArray(
            self.body_id,
            self.arm_joints,
            p.POSITION_CONTROL,
            targetPositions=[float(v) for v in q],
            forces=[self.config.force] * len(self.arm_joints),
            positionGains=[self.config.position_gain] * len(self.arm_joints),
            physicsClientId=self.client,
        )

    def steps_for(self, path: FloatArray) -> int:
        """Steps to play a joint path: its longest joint travel at the peak speed.

        A smoothstep profile peaks at 1.5x its mean speed, hence the factor.
        """
        travel = (
            float(np.max(np.sum(np.abs(np.diff(path, axis=0)), axis=0))) if len(path) > 1 else 0
        )
        seconds = 1.5 * travel / self.config.max_joint_speed
        return max(self.config.min_steps, math.ceil(seconds / self.config.time_step))

    def follow(
        self,
        waypoints: Sequence[FloatArray],
        steps: int | None = None,
        monitor: Callable[[], bool] | None = None,
    ) -> bool:
        """Play the joint path current → waypoints with a smoothstep time law, then settle.

        ``monitor`` is asked every ``monitor_every`` steps whether to go on (e.g. "is the object
        still held?"); when it says no the arm holds where it is and ``False`` is returned, as a
        real controller would stop on a lost grasp.
        """
        # the current joints are the simulator's own state, the waypoints IK's answers
        path = np.vstack([self.joint_positions(), *(joint_targets(w) for w in waypoints)])
        seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        total = float(cum[-1])
        n = self.steps_for(path) if steps is None else steps
        for i in range(1, n + 1):
            t = i / n
            s = (3 * t**2 - 2 * t**3) * total
            if total > 0:
                q = np.array([np.interp(s, cum, path[:, j]) for j in range(path.shape[1])])
            else:
                q = path[-1]
            self._command(q)
            self._step(1)
            if monitor is not None and i % self.config.monitor_every == 0 and not monitor():
                self._command(self.joint_positions())
                return False
        self._command(path[-1])
        self._step(self.config.settle_steps)
        return monitor() if monitor is not None else True

    def hold(self) -> None:
        """Command the arm to stay where it is (after ``p.restoreState``, which brings back
        positions and velocities but not motor targets)."""
        self._command(self.joint_positions())

    def move_to(self, position: Point3, yaw: float) -> IKSolution:
        """Joint-space move to a top-down TCP pose; does not move if IK fails."""
        solution = self.solve_ik(position, yaw)
        if solution.ok(self.config):
            self.follow([solution.q])
        return solution

    def move_linear(self, position: Point3, yaw: float, lean: float = 0.0) -> list[IKSolution]:
        """Straight-line TCP move; does not move unless every waypoint is reachable."""
        plan = self.plan_linear(self.joint_positions(), position, yaw, lean)
        if all(s.ok(self.config) for s in plan):
            self.follow([s.q for s in plan])
        return plan


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi
