"""Newton IK on the chain model, for waypoints a short step from a known solution.

A pick's plan is ~50 IK solutions, almost all of them waypoints 2 cm apart on straight TCP lines
(``CR3Robot.plan_linear``), each seeded with the previous waypoint's joints. pybullet's
``calculateInverseKinematics`` needs about two calls of its damped solver per waypoint and made
the chosen grasp's IK plan the largest robot-side cost after the two networks (0.11 s/scene,
``benchmarks/bench_perception.py``; 0.03 s with Newton in numpy, ~0.01 s compiled).

From a seed that close, plain Newton steps on the model of the same URDF chain converge
quadratically: two steps usually reach the pose to 1e-6 m / 1e-6 rad. A 6-joint arm has isolated
solutions, so from a nearby seed Newton finds the posture pybullet's solver finds (which stops
anywhere within its tolerance, up to millimetres, so the joints agree to a few hundredths of a
radian), not another branch (``tests/test_local_ik.py``). Whatever Newton does not solve quickly
and well (a far seed, a pose out of reach, a singular Jacobian, an answer outside the joint
limits) returns None, and the caller runs pybullet's solver, so the set of reachable poses does
not shrink.

Why compiled (numba): on 6 joints the arithmetic is nothing; what a waypoint cost in numpy was
~25 array calls per Newton step at a microsecond or more each (~175 us a waypoint, ~9 ms of the
robot's ~22 ms ``ground_ik`` stage per scene). The kernels below are plain loops over doubles:
no BLAS, and neither fused multiply-adds nor reordered sums (numba leaves fast-math off), so only
the system libm's sin/cos/atan2 may differ between CPUs, in the last bit. They agree with the
numpy form to ~1e-13 rad (other orders of the same sums, and their own Gaussian elimination in
place of LAPACK's); the arm is sent its targets rounded to 1e-5 rad (``robot.joint_targets``), so
the physics does not see the difference (``tests/test_local_ik.py``; the published sim tables
reproduce, ``tests/test_eval_sim.py``). The first call of a process loads the compiled code from
numba's cache (``__pycache__``), or compiles it (~10 s, once per install).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import numpy.typing as npt

from .kinematics import SerialChain

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class LocalIKConfig:
    """When Newton steps are trusted; outside these the caller uses pybullet's solver."""

    max_steps: int = 8
    tolerance: float = 1e-6  # m and rad: the residual at which Newton has converged
    max_seed_distance: float = 0.05  # m from the seed's TCP to the target: "a short step"
    # rad between the seed's TCP rotation and the target's: a top-down grasp's closing axis is
    # turned at most a quarter turn (``CR3Robot.nearest_yaw``), e.g. on the first waypoint of a
    # transport to the drop zone
    max_seed_angle: float = 1.7
    max_joint_step: float = 1.7  # rad: a larger Newton step means a near-singular Jacobian


@numba.njit(cache=True)
def _walk(q: FloatArray, origins: FloatArray, cross: FloatArray, cross2: FloatArray, tail: FloatArray,
          frames: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """End pose ``[4, 4]``; fills ``frames[i]`` with joint ``i``'s frame after its motion (which
    leaves the joint's origin and axis where they were). Joint ``i``'s rotation is Rodrigues'
    ``(I + sin(q) K) + (1 - cos(q)) K^2``, after the fixed transform ``origins[i]``."""
    pose = np.eye(4)
    local = np.zeros((4, 4))
    motion = np.empty((3, 3))
    for i in range(q.shape[0]):
        s = math.sin(q[i])
        c = 1.0 - math.cos(q[i])
        for r in range(3):
            for k in range(3):
                motion[r, k] = ((1.0 if r == k else 0.0) + s * cross[i, r, k]) + c * cross2[i, r, k]
        for r in range(4):
            for k in range(3):
                local[r, k] = origins[i, r, 0] * motion[0, k] + origins[i, r, 1] * motion[1, k] \
                    + origins[i, r, 2] * motion[2, k]
            local[r, 3] = origins[i, r, 3]
        frames[i] = _product(pose, local)
        pose = frames[i]
    return _product(pose, tail)


@numba.njit(cache=True)
def _product(a: FloatArray, b: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """``a @ b`` of two 4x4 matrices as loops (no BLAS call: the same sums on every CPU)."""
    out = np.empty((4, 4))
    for r in range(4):
        for k in range(4):
            out[r, k] = a[r, 0] * b[0, k] + a[r, 1] * b[1, k] + a[r, 2] * b[2, k] + a[r, 3] * b[3, k]
    return out


@numba.njit(cache=True)
def _solve6(a: FloatArray, b: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """``a x = b`` by Gaussian elimination with partial pivoting (as LAPACK's ``getrf``: the
    largest pivot of each column, the first on ties); all NaN when ``a`` is singular. ``a`` and
    ``b`` are overwritten."""
    n = b.shape[0]
    for k in range(n):
        pivot, best = k, abs(a[k, k])
        for r in range(k + 1, n):
            if abs(a[r, k]) > best:
                pivot, best = r, abs(a[r, k])
        if best == 0.0 or best != best:
            return np.full(n, np.nan)
        if pivot != k:
            for c in range(n):
                a[k, c], a[pivot, c] = a[pivot, c], a[k, c]
            b[k], b[pivot] = b[pivot], b[k]
        for r in range(k + 1, n):
            f = a[r, k] / a[k, k]
            for c in range(k + 1, n):
                a[r, c] -= f * a[k, c]
            b[r] -= f * b[k]
    x = np.empty(n)
    for k in range(n - 1, -1, -1):
        s = b[k]
        for c in range(k + 1, n):
            s -= a[k, c] * x[c]
        x[k] = s / a[k, k]
    return x


@numba.njit(cache=True)
def _newton(rotation: FloatArray, position: FloatArray, seed: FloatArray, origins: FloatArray, cross: FloatArray,
            cross2: FloatArray, tail: FloatArray, axes: FloatArray, limits: FloatArray,
            max_steps: int) -> tuple[bool, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """(converged, joints, end pose) of Newton steps from ``seed`` to ``(rotation, position)``;
    ``limits``: tolerance, largest seed distance, cosine of the largest seed angle, largest
    joint step (``LocalIKConfig``). The orientation residual is the rotation vector of the
    remaining turn; near the identity (cosine > 0.999), where Newton spends its steps, its
    first-order form ``sin(angle) * axis`` (the skew part)."""
    tolerance, max_distance, min_cosine, max_joint_step = limits[0], limits[1], limits[2], limits[3]
    n = seed.shape[0]
    q = seed.copy()
    frames = np.empty((n, 4, 4))
    residual = np.empty(6)
    jacobian = np.empty((6, n))
    turn = np.empty((3, 3))
    end = np.eye(4)
    for step in range(max_steps + 1):
        end = _walk(q, origins, cross, cross2, tail, frames)
        for r in range(3):  # rotation @ end_rotation.T
            for k in range(3):
                turn[r, k] = rotation[r, 0] * end[k, 0] + rotation[r, 1] * end[k, 1] + rotation[r, 2] * end[k, 2]
        px, py, pz = end[0, 3], end[1, 3], end[2, 3]
        residual[0], residual[1], residual[2] = position[0] - px, position[1] - py, position[2] - pz
        sx, sy, sz = (turn[2, 1] - turn[1, 2]) * 0.5, (turn[0, 2] - turn[2, 0]) * 0.5, (turn[1, 0] - turn[0, 1]) * 0.5
        cosine = 0.5 * (turn[0, 0] + turn[1, 1] + turn[2, 2] - 1.0)
        if cosine <= 0.999:
            sine = math.sqrt(sx * sx + sy * sy + sz * sz)
            if sine > 1e-12:
                scale = math.atan2(sine, cosine) / sine
                sx, sy, sz = sx * scale, sy * scale, sz * scale
        residual[3], residual[4], residual[5] = sx, sy, sz
        if step == 0:
            distance = math.sqrt(residual[0] * residual[0] + residual[1] * residual[1] + residual[2] * residual[2])
            if distance > max_distance or cosine < min_cosine:
                return False, q, end
        converged = True
        for v in residual:
            if not abs(v) <= tolerance:  # NaN is not converged
                converged = False
        if converged:
            return cosine > 0.0, q, end  # a half turn has a zero skew part too
        if step == max_steps:
            return False, q, end
        for i in range(n):  # column i: (axis x lever, axis), the joint's axis in the root frame
            f = frames[i]
            ax = f[0, 0] * axes[i, 0] + f[0, 1] * axes[i, 1] + f[0, 2] * axes[i, 2]
            ay = f[1, 0] * axes[i, 0] + f[1, 1] * axes[i, 1] + f[1, 2] * axes[i, 2]
            az = f[2, 0] * axes[i, 0] + f[2, 1] * axes[i, 1] + f[2, 2] * axes[i, 2]
            lx, ly, lz = px - f[0, 3], py - f[1, 3], pz - f[2, 3]
            jacobian[0, i], jacobian[1, i], jacobian[2, i] = ay * lz - az * ly, az * lx - ax * lz, ax * ly - ay * lx
            jacobian[3, i], jacobian[4, i], jacobian[5, i] = ax, ay, az
        delta = _solve6(jacobian.copy(), residual.copy())
        for v in delta:
            if not abs(v) <= max_joint_step:  # a near-singular Jacobian (NaN when singular)
                return False, q, end
        q = q + delta
    return False, q, end


@numba.njit(cache=True)
def checked_answer(q: FloatArray, reached: FloatArray, at: FloatArray, rotation: FloatArray, position: FloatArray,
             lower: FloatArray, upper: FloatArray) -> tuple[FloatArray, bool, float, float]:  # pragma: no cover
    """A Newton answer as the robot checks it: ``q`` with each joint outside its limits shifted by
    +2 pi, else -2 pi, where that lands inside (a whole turn: the same pose), whether every joint
    is then within, the distance from the reached position ``at`` to ``position`` and the angle
    between the ``reached`` rotation and ``rotation`` (``robot.rotation_angle``)."""
    wrapped = q.copy()
    within = True
    for i in range(q.shape[0]):
        for shift in (2 * math.pi, -2 * math.pi):
            if not lower[i] <= wrapped[i] <= upper[i]:
                candidate = wrapped[i] + shift
                if lower[i] <= candidate <= upper[i]:
                    wrapped[i] = candidate
        within = within and lower[i] <= wrapped[i] <= upper[i]
    dx, dy, dz = at[0] - position[0], at[1] - position[1], at[2] - position[2]
    trace = 0.0
    for r in range(3):
        trace += reached[0, r] * rotation[0, r] + reached[1, r] * rotation[1, r] + reached[2, r] * rotation[2, r]
    cosine = min(1.0, max(-1.0, (trace - 1.0) / 2.0))
    return wrapped, within, math.sqrt(dx * dx + dy * dy + dz * dz), math.acos(cosine)


class ChainIK:
    """Forward kinematics and Newton IK of one revolute ``SerialChain``.

    The fixed joints are folded into their neighbours once; ``pose`` agrees with
    ``SerialChain.forward`` to float rounding (``tests/test_local_ik.py``).
    """

    def __init__(self, chain: SerialChain, config: LocalIKConfig | None = None) -> None:
        self.config = config or LocalIKConfig()
        origins: list[FloatArray] = []
        axes: list[FloatArray] = []
        pending = np.eye(4)
        #: every joint's child frame from the walk's frames: (name, last movable joint's index at
        #: or before it, -1 for none; the fixed transform after that frame, None when movable)
        self._named: list[tuple[str, int, FloatArray | None]] = []
        for joint in chain.joints:
            pending = pending @ joint.origin
            if not joint.movable:
                self._named.append((joint.name, len(axes) - 1, pending.copy()))
                continue
            if joint.kind not in ("revolute", "continuous"):
                raise ValueError(f"joint {joint.name} is {joint.kind}: local IK handles revolute joints only")
            origins.append(pending)
            axes.append(joint.axis / np.linalg.norm(joint.axis))
            self._named.append((joint.name, len(axes) - 1, None))
            pending = np.eye(4)
        self._origins = np.ascontiguousarray(origins, dtype=np.float64)  # [n, 4, 4]: before each joint
        self._axes = np.ascontiguousarray(axes, dtype=np.float64)  # [n, 3]: each joint's axis, own frame
        k = np.zeros((len(axes), 3, 3))
        k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -self._axes[:, 2], self._axes[:, 1], -self._axes[:, 0]
        k[:, 1, 0], k[:, 2, 0], k[:, 2, 1] = self._axes[:, 2], -self._axes[:, 1], self._axes[:, 0]
        self._cross, self._cross2 = k, np.ascontiguousarray(k @ k)  # Rodrigues' formula, per joint
        self._tail = np.ascontiguousarray(pending)  # fixed transform from the last joint to the end link
        cfg = self.config
        self._limits = np.array([cfg.tolerance, cfg.max_seed_distance, math.cos(cfg.max_seed_angle),
                                 cfg.max_joint_step])

    @property
    def dof(self) -> int:
        return len(self._axes)

    def pose(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """End-link ``(rotation [3, 3], position [3])`` in the chain's root frame."""
        end = self.walk(q)[0]
        return end[:3, :3], end[:3, 3]

    def walk(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """End pose ``[4, 4]`` and each joint's frame ``[n, 4, 4]`` (after its motion)."""
        frames = np.empty((self.dof, 4, 4))
        end: FloatArray = _walk(np.asarray(q, dtype=np.float64), self._origins, self._cross, self._cross2,
                                self._tail, frames)
        return end, frames

    def joint_frames(self, frames: FloatArray) -> dict[str, FloatArray]:
        """Every joint's child frame by name (4x4, root frame), as ``SerialChain.frames`` gives
        them (to float rounding), from ``walk``'s movable-joint ``frames``."""
        out: dict[str, FloatArray] = {}
        for name, index, fixed in self._named:
            if fixed is None:
                out[name] = frames[index]
            else:
                out[name] = fixed if index < 0 else frames[index] @ fixed
        return out

    def solve(
        self, rotation: FloatArray, position: FloatArray, seed: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """Joints that put the end link at ``(rotation, position)`` (root frame), by Newton steps
        from ``seed``, with the end link's rotation and position they reach; None if the seed is
        not close or the steps do not converge."""
        converged, q, end = _newton(
            np.ascontiguousarray(rotation, dtype=np.float64), np.ascontiguousarray(position, dtype=np.float64),
            np.ascontiguousarray(seed, dtype=np.float64), self._origins, self._cross, self._cross2, self._tail,
            self._axes, self._limits, self.config.max_steps)
        if not converged:
            return None
        return q, end[:3, :3], end[:3, 3]
