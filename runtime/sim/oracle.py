"""Ground truth the simulator knows and a real robot would not: masks and grasps.

Used for the oracle settings of the evaluation (GT boxes, GT grasps) and by tests that must check
perception and execution separately.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pybullet as p

from ..grasp.geometry import TopDownGrasp, wrap_half_pi
from ..perception.observation import Observation
from ..perception.roi import Region, roi_from_mask
from .scene import Scene

FloatArray = npt.NDArray[np.float64]


def gt_rois(obs: Observation, scene: Scene, min_area: int = 20) -> list[Region]:
    """One ROI per scene object visible in the segmentation buffer, labelled with its body id."""
    if obs.seg is None:
        raise ValueError("observation has no segmentation buffer; render it from the simulator")
    rois: list[Region] = []
    for obj in scene.objects:
        mask = obs.seg == obj.body_id
        if int(np.count_nonzero(mask)) >= min_area:
            rois.append(roi_from_mask(mask, label=obj.body_id))
    return rois


@dataclass(frozen=True)
class OracleConfig:
    """Sampling of the object's top surface and limits of the gripper."""

    ray_spacing: float = 0.004  # m between vertical rays over the object's bounding box
    max_width: float = 0.08  # the gripper's full opening
    side_clearance: float = 0.002  # m of free opening wanted on each side of the object
    strip_half_width: float = 0.01  # m: half the finger pad size along the object's long axis
    slide_step: float = 0.01  # m between candidate centres along the long axis
    taper_tolerance: float = 0.015  # m the width may change over the pad length


def top_surface_points(scene: Scene, body_id: int, spacing: float) -> FloatArray:
    """World points ``[n, 3]`` where vertical rays over the body's AABB first hit the body."""
    lo, hi = p.getAABB(body_id, physicsClientId=scene.client)
    xs = np.arange(lo[0], hi[0] + spacing, spacing)
    ys = np.arange(lo[1], hi[1] + spacing, spacing)
    gx, gy = np.meshgrid(xs, ys)
    starts = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, hi[2] + 0.05)], axis=1)
    ends = starts.copy()
    ends[:, 2] = scene.layout.table_z - 0.01
    points: list[tuple[float, float, float]] = []
    batch = 16000  # pybullet's limit per rayTestBatch call is 16384
    for i in range(0, len(starts), batch):
        hits = p.rayTestBatch(
            starts[i : i + batch].tolist(),
            ends[i : i + batch].tolist(),
            physicsClientId=scene.client,
        )
        points.extend(tuple(h[3]) for h in hits if h[0] == body_id)
    return np.array(points, dtype=np.float64).reshape(-1, 3)


def oracle_grasp(
    scene: Scene, body_id: int, config: OracleConfig | None = None
) -> TopDownGrasp | None:
    """Top-down grasp across the narrow axis of the object's footprint, or None if none fits.

    The footprint is the object's top surface, sampled by vertical rays inside its bounding box;
    its principal axes give the long and the narrow direction. Candidate centres slide along the
    long axis from the centroid outwards, and the first whose cross-section (a finger-pad-wide
    strip) fits the opening and has parallel sides wins: for a box that is the centre, for a
    hammer the handle next to the head. Parallel sides matter: the edge of a ball or a wide can
    fits the opening too, but it is a chord on a slope and tends to squeeze out of the fingers;
    only when no parallel-sided section exists is the first section that fits returned (and
    physics decides).
    The position is the top surface next to the grasp centre, as a grasp network would report
    from depth; the executor adds its own insertion depth.
    """
    cfg = config or OracleConfig()
    if scene.object_by_body(body_id) is None:
        raise KeyError(f"body {body_id} is not an object of this scene")
    points = top_surface_points(scene, body_id, cfg.ray_spacing)
    if len(points) < 3:
        return None
    xy = points[:, :2]
    centroid = xy.mean(axis=0)
    _, _, vt = np.linalg.svd(xy - centroid, full_matrices=False)
    long_axis, narrow_axis = vt[0], vt[1]
    along = (xy - centroid) @ long_axis  # [n]
    reach = float(np.abs(along).max())
    offsets = np.arange(0.0, reach, cfg.slide_step)
    candidates = sorted(np.concatenate([offsets, -offsets[1:]]), key=abs)
    yaw = math.atan2(float(narrow_axis[1]), float(narrow_axis[0]))
    for offset, parallel in [(o, True) for o in candidates] + [(o, False) for o in candidates]:
        grasp = grasp_at(points, centroid, long_axis, narrow_axis, yaw, float(offset), cfg, parallel)
        if grasp is not None:
            return grasp
    return None


def grasp_at(
    points: FloatArray, centroid: FloatArray, along_axis: FloatArray, closing: FloatArray,
    yaw: float, offset: float, cfg: OracleConfig, parallel: bool,
) -> TopDownGrasp | None:
    """The grasp closing along ``closing`` (yaw ``yaw``) at ``offset`` along ``along_axis`` from
    the footprint's ``centroid``, if its cross-section fits (``cross_section``); its height is the
    top surface next to the centre. Shared by the oracle and the static table's GT grasps."""
    xy = points[:, :2]
    along = (xy - centroid) @ along_axis  # [n]
    across = (xy - centroid) @ closing  # [n]
    section = cross_section(along, across, offset, cfg, parallel)
    if section is None:
        return None
    low, high = section
    center = centroid + offset * along_axis + (low + high) / 2 * closing
    near = np.linalg.norm(xy - center, axis=1) <= cfg.strip_half_width
    strip = np.abs(along - offset) <= cfg.strip_half_width
    top = float(points[near if np.any(near) else strip, 2].max())
    width = high - low + cfg.ray_spacing  # rays sample; the true edge lies up to one step out
    return TopDownGrasp(position=np.array([center[0], center[1], top]), yaw=wrap_half_pi(yaw), width_m=width)


def cross_section(
    along: FloatArray, across: FloatArray, offset: float, cfg: OracleConfig, parallel: bool
) -> tuple[float, float] | None:
    """(low, high) extent across the strip at ``offset`` if it fits (and, if asked, is not
    tapering)."""
    strip = np.abs(along - offset) <= cfg.strip_half_width
    if not np.any(strip):
        return None
    low, high = float(across[strip].min()), float(across[strip].max())
    if high - low + cfg.ray_spacing > cfg.max_width - 2 * cfg.side_clearance:
        return None
    if not parallel:
        return low, high
    widths = []
    for shift in (-cfg.strip_half_width, 0.0, cfg.strip_half_width):
        line = np.abs(along - offset - shift) <= cfg.ray_spacing
        if not np.any(line):
            return None  # the strip runs off the object: the pads would hang over an end
        widths.append(float(across[line].max() - across[line].min()))
    if max(widths) - min(widths) > cfg.taper_tolerance:
        return None  # tapering fast along the pads: a chord on a curved side
    return low, high
