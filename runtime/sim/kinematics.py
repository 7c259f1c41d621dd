"""Forward kinematics of a serial URDF chain in numpy.

pybullet can only report link poses for the joint state the body is *in*; checking an IK solution
that way means moving the robot (and disturbing the scene) before we know whether the solution is
any good. A numpy FK over the URDF's joint origins lets us verify every waypoint up front and
report ``ik_failure`` without touching the simulation.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import numpy.typing as npt

Mat4 = npt.NDArray[np.float64]


def _floats(text: str | None, default: str) -> npt.NDArray[np.float64]:
    return np.array([float(v) for v in (text or default).split()], dtype=np.float64)


def rpy_matrix(rpy: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """URDF fixed-axis roll-pitch-yaw: R = Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def cross_matrices(axis: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """``(K, K @ K)`` of the unit axis: the angle-independent parts of Rodrigues' formula."""
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return kx, kx @ kx


def axis_angle_matrix(axis: npt.NDArray[np.float64], angle: float) -> npt.NDArray[np.float64]:
    """Rodrigues rotation about a unit axis."""
    kx, kx2 = cross_matrices(axis)
    return _rodrigues(kx, kx2, angle)


_EYE3 = np.eye(3)
_EYE4 = np.eye(4)


def _rodrigues(kx: npt.NDArray[np.float64], kx2: npt.NDArray[np.float64], angle: float) -> npt.NDArray[np.float64]:
    out: npt.NDArray[np.float64] = _EYE3 + np.sin(angle) * kx + (1.0 - np.cos(angle)) * kx2
    return out


def _revolute_motion(kx: list[float], kx2: list[float], angle: float) -> npt.NDArray[np.float64]:
    """``[[R, 0], [0, 1]]`` with ``R = _rodrigues(kx, kx2, angle)`` (row-major 3x3 parts as
    lists): each entry is the same ``(I + s kx) + (1 - c) kx2`` of IEEE doubles, computed on
    Python floats instead of three temporary arrays (forward kinematics runs ~100 times per
    IK plan)."""
    s = float(np.sin(angle))
    c = float(1.0 - np.cos(angle))
    e = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    r = [(e[i] + s * kx[i]) + c * kx2[i] for i in range(9)]
    return np.array([[r[0], r[1], r[2], 0.0], [r[3], r[4], r[5], 0.0], [r[6], r[7], r[8], 0.0],
                     [0.0, 0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class ChainJoint:
    """One joint on the path from the root link to the end link."""

    name: str
    kind: str  # "revolute", "continuous", "prismatic" or "fixed"
    origin: Mat4
    axis: npt.NDArray[np.float64]

    @property
    def movable(self) -> bool:
        return self.kind != "fixed"


@dataclass(frozen=True)
class SerialChain:
    """The joints from the URDF root to ``end_link``, in order."""

    joints: tuple[ChainJoint, ...]

    @cached_property
    def _rodrigues_parts(self) -> tuple[tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]], ...]:
        """Per joint, ``cross_matrices`` of its axis: computed once, not on every call (the grasp
        checks run forward kinematics thousands of times per scene)."""
        return tuple(cross_matrices(j.axis) for j in self.joints)

    @cached_property
    def _rodrigues_lists(self) -> tuple[tuple[list[float], list[float]], ...]:
        """``_rodrigues_parts`` as row-major lists of floats, for ``_revolute_motion``."""
        return tuple((kx.ravel().tolist(), kx2.ravel().tolist()) for kx, kx2 in self._rodrigues_parts)

    def forward(self, q: npt.NDArray[np.float64]) -> Mat4:
        """Pose of the end link in the root frame for the movable joint values ``q``."""
        return self._walk(q, None)

    def frames(self, q: npt.NDArray[np.float64]) -> dict[str, Mat4]:
        """Pose of every joint's child frame, by joint name: the clearance check needs the
        elbow and wrist, not only the end link."""
        out: dict[str, Mat4] = {}
        self._walk(q, out)
        return out

    def forward_and_frames(self, q: npt.NDArray[np.float64]) -> tuple[Mat4, dict[str, Mat4]]:
        """``forward(q)`` and ``frames(q)`` from one walk down the chain (the same matrices as
        calling both: the clearance check needs both for every pose it checks)."""
        out: dict[str, Mat4] = {}
        end = self._walk(q, out)
        return end, out

    def _walk(self, q: npt.NDArray[np.float64], frames: dict[str, Mat4] | None) -> Mat4:
        """The chain's poses joint by joint (recorded in ``frames`` if given); the last one."""
        pose = _EYE4.copy()  # copies, not np.eye: the same matrices at a tenth of the cost
        values = iter(np.asarray(q, dtype=np.float64))
        for joint, (kx, kx2) in zip(self.joints, self._rodrigues_lists, strict=True):
            pose = pose @ joint.origin
            if joint.movable:
                value = float(next(values))
                if joint.kind == "prismatic":
                    motion = _EYE4.copy()
                    motion[:3, 3] = joint.axis * value
                else:
                    motion = _revolute_motion(kx, kx2, value)
                pose = pose @ motion
            if frames is not None:
                frames[joint.name] = pose
        return pose


def load_chain(urdf: Path, end_link: str) -> SerialChain:
    """Parse ``urdf`` and return the chain from its root link to ``end_link``."""
    root = ET.parse(urdf).getroot()
    by_child: dict[str, ET.Element] = {}
    for joint in root.findall("joint"):
        child = joint.find("child")
        if child is not None:
            by_child[child.attrib["link"]] = joint
    path: list[ChainJoint] = []
    link = end_link
    while link in by_child:
        element = by_child[link]
        origin_el = element.find("origin")
        axis_el = element.find("axis")
        origin = np.eye(4)
        if origin_el is not None:
            origin[:3, :3] = rpy_matrix(_floats(origin_el.get("rpy"), "0 0 0"))
            origin[:3, 3] = _floats(origin_el.get("xyz"), "0 0 0")
        axis = _floats(axis_el.get("xyz") if axis_el is not None else None, "1 0 0")
        path.append(ChainJoint(element.attrib["name"], element.attrib["type"], origin, axis))
        parent = element.find("parent")
        if parent is None:
            raise ValueError(f"{urdf}: joint {element.attrib['name']} has no parent")
        link = parent.attrib["link"]
    if not path:
        raise ValueError(f"{urdf}: link {end_link!r} is not the child of any joint")
    return SerialChain(tuple(reversed(path)))
