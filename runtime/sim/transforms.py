"""Rotation helpers in numpy/scipy.

pybullet's math helpers (getQuaternionFromEuler, computeViewMatrix...) are module functions that
take an optional client id; keeping pure geometry out of pybullet means every remaining pybullet
call is one that talks to a physics client, and passes it explicitly.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

FloatArray = npt.NDArray[np.float64]


def quat_to_matrix(xyzw: Sequence[float] | FloatArray) -> FloatArray:
    """3x3 rotation of a pybullet-order (x, y, z, w) quaternion.

    A tuple (what ``rpy_to_quat`` and pybullet return) is looked up in a cache and gets a
    read-only matrix: IK converts the same grasp orientation at every waypoint of a pick."""
    if isinstance(xyzw, tuple):
        return _cached_matrix(tuple(float(v) for v in xyzw))
    out: FloatArray = Rotation.from_quat(np.asarray(xyzw, dtype=np.float64)).as_matrix()
    return out


@lru_cache(maxsize=1024)
def _cached_matrix(xyzw: tuple[float, ...]) -> FloatArray:
    out: FloatArray = Rotation.from_quat(np.asarray(xyzw, dtype=np.float64)).as_matrix()
    out.flags.writeable = False
    return out


@lru_cache(maxsize=1024)
def rpy_to_quat(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Fixed-axis roll-pitch-yaw (R = Rz Ry Rx, as URDF and pybullet use) → (x, y, z, w).

    Cached (an immutable tuple): IK asks for the same grasp yaw at every waypoint of a pick."""
    x, y, z, w = Rotation.from_euler("xyz", [roll, pitch, yaw]).as_quat()
    return float(x), float(y), float(z), float(w)


def look_at(eye: Sequence[float], target: Sequence[float], up: Sequence[float]) -> FloatArray:
    """OpenGL view matrix (world → camera, camera looking down its -z), 4x4 row-major."""
    e, t, u = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    forward = (t - e) / np.linalg.norm(t - e)
    side = np.cross(forward, u)
    norm = np.linalg.norm(side)
    if norm < 1e-9:
        raise ValueError(f"camera up {tuple(u)} is parallel to the viewing direction")
    side /= norm
    true_up = np.cross(side, forward)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = side, true_up, -forward
    view[:3, 3] = -view[:3, :3] @ e
    return view
