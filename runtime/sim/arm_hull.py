"""The arm's links as the simulator collides them: points on each link mesh's convex hull.

Why: the clearance check modelled the arm as 5 cm capsules around the segments joining the joint
frames. The CR3's wrist frame (joint 4) sits 12.8 cm beside the end of the forearm, along the
joint axis, so the segment from the elbow to it cuts the corner the forearm's housing really
turns: on sim-val the forearm (``Link3``) came down on a standing wood block and a mustard bottle
(pybullet contacts 19-21 cm high, the hand stopped 4.4 and 1.7 cm above its grasp) where the
capsules passed clear of both, and the fingers closed on nothing.

pybullet collides a moving link's mesh as its convex hull, so the hull is what can touch: its
surface is sampled once per link (``spacing`` apart at most), in the link's frame, and the check
(``clearance.first_hit``) moves the samples with the links' frames from the arm's own forward
kinematics. Only the robot's geometry is read here, never the objects'.
"""

from __future__ import annotations

import functools
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.spatial import ConvexHull

from .collision_meshes import stl_vertices
from .kinematics import rpy_matrix

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class LinkHull:
    """One arm link: the joint whose child frame its mesh is expressed in, and points of its
    convex hull's surface in that frame ``[n, 3]`` (read-only)."""

    link: str
    joint: str
    points: FloatArray


def hull_surface_points(vertices: FloatArray, spacing: float) -> FloatArray:
    """Points on the surface of the convex hull of ``vertices``, about ``spacing`` apart: every
    hull triangle subdivided finer than ``spacing``, then one point per ``spacing`` cube, its
    lowest (the check asks whether anything under the link rises above it)."""
    if spacing <= 0:
        raise ValueError(f"spacing {spacing} m: must be positive")
    hull = ConvexHull(vertices)
    fine = spacing / 2
    out: list[FloatArray] = []
    for a, b, c in vertices[hull.simplices]:
        longest = max(float(np.linalg.norm(b - a)), float(np.linalg.norm(c - a)), float(np.linalg.norm(c - b)))
        n = max(1, math.ceil(longest / fine))
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = (i + j) <= n
        u, v = i[keep][:, None] / n, j[keep][:, None] / n
        out.append(a + u * (b - a) + v * (c - a))
    points = np.concatenate(out)
    cells = np.floor(points / spacing).astype(np.int64)
    order = np.lexsort((points[:, 2], cells[:, 2], cells[:, 1], cells[:, 0]))  # by cell, lowest first
    cells, points = cells[order], points[order]
    first = np.ones(len(points), dtype=bool)
    first[1:] = np.any(cells[1:] != cells[:-1], axis=1)
    lowest: FloatArray = points[first]
    return lowest


def _origin(element: ET.Element | None) -> tuple[FloatArray, FloatArray]:
    """(rotation, translation) of a URDF ``<origin>`` (identity when absent)."""
    if element is None:
        return np.eye(3), np.zeros(3)
    xyz = np.array([float(v) for v in element.attrib.get("xyz", "0 0 0").split()])
    rpy = np.array([float(v) for v in element.attrib.get("rpy", "0 0 0").split()])
    return rpy_matrix(rpy), xyz


@functools.cache
def link_hulls(urdf: Path, links: tuple[str, ...], spacing: float) -> tuple[LinkHull, ...]:
    """The hull samples of ``links`` of the robot URDF ``urdf`` (binary STL collision meshes, as
    the CR3's are), made once per process and argument set."""
    root = ET.parse(urdf).getroot()
    parent_joint = {j.find("child").attrib["link"]: j.attrib["name"]  # type: ignore[union-attr]
                    for j in root.findall("joint") if j.find("child") is not None}
    out: list[LinkHull] = []
    for name in links:
        link = root.find(f"link[@name='{name}']")
        if link is None or name not in parent_joint:
            raise ValueError(f"{urdf}: no link {name!r} with a parent joint")
        parts: list[FloatArray] = []
        for collision in link.findall("collision"):
            mesh = collision.find("geometry/mesh")
            if mesh is None:
                raise ValueError(f"{urdf}: link {name!r} has a collision that is not a mesh")
            scale = np.array([float(v) for v in mesh.attrib.get("scale", "1 1 1").split()])
            rotation, translation = _origin(collision.find("origin"))
            vertices = stl_vertices(Path(mesh.attrib["filename"])) * scale
            parts.append(hull_surface_points(vertices, spacing) @ rotation.T + translation)
        if not parts:
            raise ValueError(f"{urdf}: link {name!r} has no collision mesh")
        points = np.concatenate(parts)
        points.flags.writeable = False
        out.append(LinkHull(name, parent_joint[name], points))
    return tuple(out)


def hull_points_world(hulls: tuple[LinkHull, ...], frames: dict[str, FloatArray],
                      base: FloatArray) -> list[FloatArray]:
    """Each hull's samples ``[n, 3]`` in the world for the joint frames ``frames`` (4x4, the
    chain's root frame, by joint name) of a robot whose root stands at ``base``."""
    return [h.points @ frames[h.joint][:3, :3].T + (frames[h.joint][:3, 3] + base) for h in hulls]
