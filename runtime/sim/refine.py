"""Fit a network's grasp to this hand when its object section is too wide: turn it, or move it
onto a wall.

Cornell-trained networks (GR-ConvNet, GG-CNN) learned grasp centres, angles and widths from
human-labelled rectangles for no particular hand, so on the CR3's hand (76 mm of free opening)
they often put a sound grasp centre under an angle the hand cannot close across: a sponge or a
bleach bottle taken across its long side, a cup or a mug across its whole mouth. Rejecting such a
grasp (``fingers.finger_check``) left the object without any grasp: on the dev scenes every
``no_grasp`` episode was a cup, mug, pitcher, bottle or sponge rejected this way.

``refine`` keeps the network's judgement of *where* to grasp and adapts the rest to the hand,
from the ROI's own depth points only (nothing about the object's identity):

1. **Turn** about the same centre, smallest turn first (15° steps up to 90°): GR-ConvNet's
   quality map does not depend on the angle (the angle is a separate regression), so the turned
   grasp keeps the network's quality.
2. **Onto a wall**: along the closing axis (at the network's angle, then at the turned ones), the
   object surface above the finger tips splits into runs; an open vessel shows two thin runs
   (its walls) around a deep gap. Centring the hand on a wall that fits puts one finger inside,
   one outside: the rim grasp people use on cups and bowls. The grasp's height is the wall's top.

A candidate is kept only if ``finger_check`` accepts it at its own finger-tip height; the first
that does is returned, so a grasp that already fits is never changed. The refined grasp keeps
the network grasp's quality (its ``E_grasp``): the network judged the spot, the hand only the
angle and the offset.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..grasp.geometry import TopDownGrasp, wrap_half_pi
from .fingers import FingerGeometry, SurfacePoints, finger_check, surface_of

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class RefineConfig:
    """How far a network grasp may be turned or moved to fit the hand."""

    enabled: bool = True
    yaw_step_deg: float = 15.0
    max_yaw_deg: float = 90.0
    max_shift: float = 0.05  # m along the closing axis: a wall farther than this is another grasp

    def __post_init__(self) -> None:
        if not 0 < self.yaw_step_deg <= self.max_yaw_deg <= 90:
            raise ValueError(f"yaw step {self.yaw_step_deg}° and limit {self.max_yaw_deg}° must satisfy "
                             "0 < step <= limit <= 90")
        if self.max_shift < 0:
            raise ValueError(f"max_shift {self.max_shift} m must be >= 0")


def turns(cfg: RefineConfig) -> list[float]:
    """Yaw offsets in radians, smallest first, each sign once (+90° and -90° are one grasp)."""
    out: list[float] = [0.0]
    k = 1
    while k * cfg.yaw_step_deg <= cfg.max_yaw_deg + 1e-9:
        deg = k * cfg.yaw_step_deg
        out.extend([math.radians(deg)] if abs(deg - 90.0) < 1e-9 else [math.radians(deg), -math.radians(deg)])
        k += 1
    return out


def wall_runs(
    material: FloatArray | SurfacePoints, centre_xy: FloatArray, yaw: float,
    tip_z_of: Callable[[TopDownGrasp], float], fingers: FingerGeometry,
) -> list[tuple[float, float, float]]:
    """Runs of surface along the closing axis through ``centre_xy``: ``(low, high, top_z)`` in
    metres along the axis from the centre, split where a gap is wide enough for a finger.

    Only points within the pad strip count, and only those above the finger tips of a grasp
    taken at the strip's highest point (a rim grasp inserts from the rim's top, so a vessel's
    floor lies below the tips and shows as the gap between its walls)."""
    surface = surface_of(material)
    axis = np.array([math.cos(yaw), math.sin(yaw)])
    normal = np.array([-axis[1], axis[0]])
    in_strip = surface.strip(centre_xy, normal, fingers.pad_half_width)
    if np.count_nonzero(in_strip) < fingers.min_points:
        return []
    crest = float(surface.z[in_strip].max())
    tip_z = tip_z_of(TopDownGrasp(position=np.array([centre_xy[0], centre_xy[1], crest]), yaw=yaw, width_m=0.0))
    strip = in_strip & surface.above(tip_z + fingers.height_tolerance)
    along = surface.along(centre_xy, strip, axis)  # [k]
    if along.size < fingers.min_points:
        return []
    order = np.argsort(along, kind="stable")
    along, heights = along[order], surface.z[strip][order]
    breaks = np.nonzero(np.diff(along) > fingers.thickness)[0]
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks + 1, [along.size]])
    return [(float(along[s]), float(along[e - 1]), float(heights[s:e].max()))
            for s, e in zip(starts, ends, strict=True) if e - s >= fingers.min_points]


def candidates(
    pose: TopDownGrasp, material: FloatArray | SurfacePoints, tip_z_of: Callable[[TopDownGrasp], float],
    fingers: FingerGeometry, cfg: RefineConfig,
) -> Iterator[TopDownGrasp]:
    """Turned grasps about the same centre (smallest turn first), then wall-centred ones (nearest
    wall first, at each turn in the same order); unchecked."""
    surface = surface_of(material)
    centre = np.asarray(pose.position, dtype=np.float64)
    offsets = turns(cfg)
    for delta in offsets[1:]:
        yield TopDownGrasp(position=centre.copy(), yaw=wrap_half_pi(pose.yaw + delta), width_m=pose.width_m)
    for delta in offsets:
        yaw = wrap_half_pi(pose.yaw + delta)
        axis = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        runs = wall_runs(surface, centre[:2], yaw, tip_z_of, fingers)
        for low, high, top in sorted(runs, key=lambda r: abs(r[0] + r[1])):
            mid = (low + high) / 2
            if not 0 < abs(mid) <= cfg.max_shift or high - low > fingers.max_span:
                continue
            moved = centre + mid * axis
            moved[2] = top
            yield TopDownGrasp(position=moved, yaw=yaw, width_m=pose.width_m)


def refine(
    pose: TopDownGrasp, material: FloatArray | SurfacePoints, tip_z_of: Callable[[TopDownGrasp], float],
    fingers: FingerGeometry, cfg: RefineConfig,
) -> TopDownGrasp | None:
    """The first of ``candidates`` the fingers fit around (``finger_check`` at its own tip
    height), or None. Call it for a grasp that does not fit: one that fits needs nothing.

    The candidates share one ``SurfacePoints`` (pass the caller's to share its work too): the
    turns and the walls about the network's centre reuse its offsets and strips."""
    if not cfg.enabled:
        return None
    surface = surface_of(material)
    for c in candidates(pose, surface, tip_z_of, fingers, cfg):
        if finger_check(surface, c, tip_z_of(c), fingers)[0]:
            return c
    return None
