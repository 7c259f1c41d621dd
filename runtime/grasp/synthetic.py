"""Tiny analytic RGB-D scenes (boxes lying on a table) with exact masks and depth.

Why: the grasp code needs offline, deterministic inputs whose right answer is known — "grasp the
15 mm bar across its width at its middle" — without a renderer. Depth is exact for a camera
looking straight down at a table ``z_table`` metres away (or a tilted table, via ``tilt``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from .geometry import CameraIntrinsics


@dataclass(frozen=True)
class Box:
    """An axis-aligned-in-its-own-frame box on the table, seen from above.

    ``center_xy`` in image pixels; ``angle_deg`` is the long side's direction in the image
    (counter-clockwise on screen, as grasp angles); sizes in metres.
    """

    center_xy: tuple[float, float]
    angle_deg: float
    length_m: float
    width_m: float
    height_m: float
    color: tuple[int, int, int] = (40, 40, 160)


@dataclass(frozen=True)
class SyntheticScene:
    rgb: npt.NDArray[np.uint8]  # [H, W, 3]
    depth: npt.NDArray[np.float32]  # [H, W] metres
    masks: list[npt.NDArray[np.bool_]] = field(default_factory=list)  # one [H, W] per box
    intrinsics: CameraIntrinsics = field(default_factory=CameraIntrinsics.realsense_d435)


def table_scene(
    boxes: list[Box],
    intrinsics: CameraIntrinsics | None = None,
    z_table: float = 0.5,
    tilt: tuple[float, float] = (0.0, 0.0),
    table_color: tuple[int, int, int] = (200, 190, 170),
) -> SyntheticScene:
    """Render boxes on a table plane. ``tilt`` adds ``(a, b)`` to the plane's inverse depth per
    pixel (1/z = 1/z_table + a·(u-cx) + b·(v-cy)), a tilted table under a pinhole camera."""
    intr = intrinsics or CameraIntrinsics.realsense_d435()
    h, w = intr.height, intr.width
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    inv = 1.0 / z_table + tilt[0] * (uu - intr.cx) + tilt[1] * (vv - intr.cy)
    table = 1.0 / inv  # [H, W]
    depth = table.copy()
    rgb = np.empty((h, w, 3), dtype=np.uint8)
    rgb[:] = table_color
    masks: list[npt.NDArray[np.bool_]] = []
    for box in boxes:
        zc = float(table[round(box.center_xy[1]), round(box.center_xy[0])])
        # metric offsets from the box centre on the plane z = zc (small boxes: plane ≈ constant)
        X = (uu - box.center_xy[0]) / intr.fx * zc
        Y = (vv - box.center_xy[1]) / intr.fy * zc
        a = math.radians(box.angle_deg)
        ax, ay = math.cos(a), -math.sin(a)
        along = X * ax + Y * ay
        across = -X * ay + Y * ax
        mask = (np.abs(along) <= box.length_m / 2) & (np.abs(across) <= box.width_m / 2)
        depth = np.where(mask, np.minimum(depth, table - box.height_m), depth)
        rgb[mask] = box.color
        masks.append(mask)
    return SyntheticScene(rgb, depth.astype(np.float32), masks, intr)


def bar_scene(
    angle_deg: float = 30.0,
    width_m: float = 0.015,
    length_m: float = 0.18,
    height_m: float = 0.012,
    center_xy: tuple[float, float] = (330.0, 250.0),
    z_table: float = 0.5,
) -> SyntheticScene:
    """One thin bar (knife / screwdriver stand-in) on the table."""
    return table_scene([Box(center_xy, angle_deg, length_m, width_m, height_m)], z_table=z_table)
