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
    rim_depth: float = 0.03  # m an inner finger goes below a rim (the executor's insertion depth)
    rim_floor_clearance: float = 0.007  # m: finger tips stop 4 mm above the table, 3 mm tolerance
    rim_yaw_step_deg: float = 15.0  # directions tried around a vessel's rim


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
    physics decides). An object too wide for every section (a bowl, a plate) is grasped by its
    rim (``rim_grasps``), if it has one.
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
    rims = rim_grasps(points, cfg, scene.layout.table_z)  # too wide everywhere: a bowl or a plate is taken by its rim
    return rims[0] if rims else None


def rim_grasps(points: FloatArray, cfg: OracleConfig, table_z: float) -> list[TopDownGrasp]:
    """Radial grasps across the wall of an open vessel, one per direction where one exists.

    How people (and Cornell-trained networks) take a bowl, a plate or a pitcher too wide for
    the hand: one finger outside, one inside, closing across the rim. ``points`` ``[n, 3]`` are
    the top surface from vertical rays, so the inside of a vessel shows as its deep floor. Along
    each direction from the footprint's centroid, the wall is the run of surface, from the
    outermost point inwards, that stands within ``rim_depth`` of the rim's top (and higher than
    the finger tips can go, ``rim_floor_clearance`` above ``table_z``); it is a rim if it
    fits the opening and the surface then drops (or stops) for a finger's room inside it
    (``2 * strip_half_width``). A solid object has no drop and gets none. ``width_m`` is the
    wall's section; ``position`` the top of the rim above the grasp centre.
    """
    xy = points[:, :2]
    centroid = xy.mean(axis=0)
    rel = xy - centroid  # [n, 2]
    limit = cfg.max_width - 2 * cfg.side_clearance
    grasps: list[TopDownGrasp] = []
    for k in range(round(360.0 / cfg.rim_yaw_step_deg)):
        theta = math.radians(k * cfg.rim_yaw_step_deg)
        u = np.array([math.cos(theta), math.sin(theta)])
        radial, across = rel @ u, rel @ np.array([-u[1], u[0]])
        ray = (np.abs(across) <= cfg.strip_half_width) & (radial > 0)
        if np.count_nonzero(ray) < 3:
            continue
        r, z = radial[ray], points[ray, 2]
        order = np.argsort(-r)  # outermost first
        r, z = r[order], z[order]
        crest = float(z[r >= r[0] - limit].max())
        floor = max(crest - cfg.rim_depth, table_z + cfg.rim_floor_clearance)  # what the tips pass
        high = z > floor
        # the wall: from the outermost point inwards while the surface stays high and unbroken
        breaks = np.nonzero(~high | (np.concatenate([[0.0], -np.diff(r)]) > 2 * cfg.ray_spacing))[0]
        end = int(breaks[0]) if breaks.size else len(r)
        if end in (0, len(r)):
            continue  # the outermost point is low, or no inside to reach into
        r_in, r_out = float(r[end - 1]), float(r[0])
        if r_out - r_in + cfg.ray_spacing > limit:
            continue  # a wall wider than the hand
        room = (r < r_in) & (r >= r_in - 2 * cfg.strip_half_width)
        if np.any(z[room] > floor):
            continue  # the surface rises again right inside: no room for the inner finger
        mid = centroid + (r_in + r_out) / 2 * u
        grasps.append(TopDownGrasp(position=np.array([mid[0], mid[1], crest]), yaw=wrap_half_pi(theta),
                                   width_m=r_out - r_in + cfg.ray_spacing))
    return grasps


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
