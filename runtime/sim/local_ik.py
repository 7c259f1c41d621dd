"""Newton IK on the chain model, for waypoints a short step from a known solution.

A pick's plan is ~50 IK solutions, almost all of them waypoints 2 cm apart on straight TCP lines
(``CR3Robot.plan_linear``), each seeded with the previous waypoint's joints. pybullet's
``calculateInverseKinematics`` needs about two calls of its damped solver per waypoint and made
the chosen grasp's IK plan the largest robot-side cost after the two networks (0.11 s/scene,
``benchmarks/bench_perception.py``; 0.03 s with Newton).

From a seed that close, plain Newton steps on the numpy model of the same URDF chain converge
quadratically: two steps usually reach the pose to 1e-6 m / 1e-6 rad; what a waypoint costs is
mostly numpy's per-call overhead on small matrices, not arithmetic. A 6-joint arm has isolated solutions, so
from a nearby seed Newton finds the posture pybullet's solver finds (which stops anywhere within
its tolerance, up to millimetres, so the joints agree to a few hundredths of a radian), not
another branch (``tests/test_local_ik.py``). Whatever Newton does not solve quickly and well (a
far seed, a pose out of reach, a singular Jacobian, an answer outside the joint limits) returns
None, and the caller runs pybullet's solver, so the set of reachable poses does not shrink.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from .kinematics import SerialChain

FloatArray = npt.NDArray[np.float64]
_EYE3 = np.eye(3)


def _solve_linear(a: FloatArray, b: FloatArray) -> FloatArray:
    """``numpy.linalg.solve(a, b)`` for one right-hand side, NaN where ``a`` is singular.

    Calls numpy's own kernel (the gufunc ``numpy.linalg.solve`` wraps) without the wrapper's
    checks, which cost more than a 6x6 solve: the same LAPACK call, so the same answer
    (``tests/test_local_ik.py``). The kernel lives in a private module; a numpy without it
    gets the public function, which gives the same answers at the wrapper's cost."""
    if _SOLVE1 is None:
        try:
            solved: FloatArray = np.linalg.solve(a, b).astype(np.float64, copy=False)
            return solved
        except np.linalg.LinAlgError:
            return np.full(len(b), np.nan)
    out: FloatArray = _SOLVE1(a, b, signature="dd->d")
    return out


def _private_solve_kernel() -> Any:
    """numpy's ``solve1`` gufunc (``_solve_linear``), or None where this numpy has no such module."""
    try:
        from numpy.linalg import _umath_linalg
    except ImportError:
        return None
    return getattr(_umath_linalg, "solve1", None)


_SOLVE1 = _private_solve_kernel()


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


class ChainIK:
    """Forward kinematics, Jacobian and Newton IK of one revolute ``SerialChain``.

    The fixed joints are folded into their neighbours once, and every joint's local transform is
    built in one batched numpy expression, so a pose costs a handful of numpy calls (per-call
    overhead, not arithmetic, is what costs on 4x4 matrices); ``pose`` agrees with
    ``SerialChain.forward`` to float rounding (``tests/test_local_ik.py``).
    """

    def __init__(self, chain: SerialChain, config: LocalIKConfig | None = None) -> None:
        self.config = config or LocalIKConfig()
        origins: list[FloatArray] = []
        axes: list[FloatArray] = []
        pending = np.eye(4)
        for joint in chain.joints:
            pending = pending @ joint.origin
            if not joint.movable:
                continue
            if joint.kind not in ("revolute", "continuous"):
                raise ValueError(f"joint {joint.name} is {joint.kind}: local IK handles revolute joints only")
            origins.append(pending)
            axes.append(joint.axis / np.linalg.norm(joint.axis))
            pending = np.eye(4)
        self._origins = np.array(origins)  # [n, 4, 4]: fixed transform before each joint
        self._axes = np.array(axes)  # [n, 3]: each joint's axis in its own frame
        k = np.zeros((len(axes), 3, 3))
        k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -self._axes[:, 2], self._axes[:, 1], -self._axes[:, 0]
        k[:, 1, 0], k[:, 2, 0], k[:, 2, 1] = self._axes[:, 2], -self._axes[:, 1], self._axes[:, 0]
        self._cross, self._cross2 = k, k @ k  # Rodrigues' formula, per joint
        self._tail = pending  # fixed transform from the last joint to the end link
        self._motion_template = np.zeros_like(self._origins)  # each joint's motion, less its rotation
        self._motion_template[:, 3, 3] = 1.0

    @property
    def dof(self) -> int:
        return len(self._axes)

    def pose(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """End-link ``(rotation [3, 3], position [3])`` in the chain's root frame."""
        end, _ = self._walk(q)
        return end[:3, :3], end[:3, 3]

    def _walk(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """End pose ``[4, 4]`` and each joint's frame ``[n, 4, 4]`` (after its motion, which
        leaves the joint's origin and axis where they were)."""
        angles = np.asarray(q, dtype=np.float64)[:, None, None]
        motion = self._motion_template.copy()
        motion[:, :3, :3] = _EYE3 + np.sin(angles) * self._cross + (1.0 - np.cos(angles)) * self._cross2
        local = self._origins @ motion  # [n, 4, 4], one batched product
        frames = np.empty_like(local)
        pose = frames[0] = local[0]
        for i in range(1, len(local)):
            pose = frames[i] = pose @ local[i]
        return pose @ self._tail, frames

    def solve(
        self, rotation: FloatArray, position: FloatArray, seed: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """Joints that put the end link at ``(rotation, position)`` (root frame), by Newton steps
        from ``seed``, with the end link's rotation and position they reach; None if the seed is
        not close or the steps do not converge.

        The residual, the Jacobian's cross products and the checks are elementwise, so they run
        on Python floats (the same IEEE operations in the same order as on numpy arrays, at a
        fraction of the per-call cost); the matrix products, the norm and the linear solve stay
        in numpy, whose kernels may fuse and reorder (``tests/test_local_ik.py`` pins the answers
        bit for bit against the all-numpy form).
        """
        cfg = self.config
        tx, ty, tz = np.asarray(position, dtype=np.float64).tolist()
        q = np.array(seed, dtype=np.float64)
        axes_local = self._axes[:, :, None]
        with np.errstate(invalid="ignore"):  # a singular Jacobian solves to NaN: declined below
            for step in range(cfg.max_steps + 1):
                end, frames = self._walk(q)
                turn = (rotation @ end[:3, :3].T).tolist()
                px, py, pz = end[:3, 3].tolist()
                residual = [tx - px, ty - py, tz - pz, *_orientation_error(turn)]
                cosine = 0.5 * (turn[0][0] + turn[1][1] + turn[2][2] - 1.0)  # of the remaining turn's angle
                if step == 0 and (float(np.linalg.norm(np.array(residual[:3]))) > cfg.max_seed_distance
                                  or cosine < math.cos(cfg.max_seed_angle)):
                    return None
                if all(abs(v) <= cfg.tolerance for v in residual):  # False for NaN, as numpy's max
                    return (q, end[:3, :3], end[:3, 3]) if cosine > 0.0 else None  # sin is 0 at pi too
                if step == cfg.max_steps:
                    return None
                axes = (frames[:, :3, :3] @ axes_local)[:, :, 0].tolist()  # each joint's axis, root frame
                origins = frames[:, :3, 3].tolist()
                rows: list[list[float]] = [[], [], [], [], [], []]
                for (ax, ay, az), (ox, oy, oz) in zip(axes, origins, strict=True):
                    lx, ly, lz = px - ox, py - oy, pz - oz  # lever from the joint to the end link
                    rows[0].append(ay * lz - az * ly)  # axis x lever
                    rows[1].append(az * lx - ax * lz)
                    rows[2].append(ax * ly - ay * lx)
                    rows[3].append(ax)
                    rows[4].append(ay)
                    rows[5].append(az)
                delta = _solve_linear(np.array(rows), np.array(residual))
                if not all(abs(v) <= cfg.max_joint_step for v in delta.tolist()):  # NaN too
                    return None
                q = q + delta
        return None


def _orientation_error(rotation: list[list[float]]) -> list[float]:
    """Rotation vector (axis times angle) of ``rotation`` (rows of Python floats), the orientation
    residual Newton drives to zero. Near the identity, where Newton spends its steps,
    ``sin(angle) * axis`` (the skew part) equals it to first order and costs a fraction of the
    logarithm."""
    r = rotation
    skew = [(r[2][1] - r[1][2]) * 0.5, (r[0][2] - r[2][0]) * 0.5, (r[1][0] - r[0][1]) * 0.5]
    cosine = 0.5 * (r[0][0] + r[1][1] + r[2][2] - 1.0)
    if cosine > 0.999:
        return skew
    sine = float(np.linalg.norm(np.array(skew)))
    if sine <= 1e-12:
        return skew
    scale = math.atan2(sine, cosine) / sine
    return [v * scale for v in skew]
