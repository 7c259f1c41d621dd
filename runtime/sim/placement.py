"""Random non-overlapping object poses on a table, by rejection sampling.

Objects are represented by their footprint, the object-frame x-y bounding rectangle, turned by
the sampled yaw. Rectangles rather than circles: long tools (knife, hammer, screwdriver) would
need a circle as wide as they are long and five of them would rarely fit the workspace. Pure numpy
and seeded, so a layout depends on nothing but the seed and the footprints.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Rect:
    """An axis-aligned x-y region (metres)."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float

    def contains(self, points: FloatArray) -> bool:
        """True if every point ``[n, 2]`` lies inside."""
        x, y = points[:, 0], points[:, 1]
        return bool(
            np.all((x >= self.x_min) & (x <= self.x_max) & (y >= self.y_min) & (y <= self.y_max))
        )

    @property
    def center(self) -> tuple[float, float]:
        return ((self.x_min + self.x_max) / 2, (self.y_min + self.y_max) / 2)


@dataclass(frozen=True)
class Footprint:
    """An object's x-y extent in its own frame: the rectangle's centre and half sizes."""

    center: tuple[float, float]
    half_size: tuple[float, float]


@dataclass(frozen=True)
class PlanarPose:
    """Where a footprint's centre goes on the table and how it is turned."""

    x: float
    y: float
    yaw: float

    def body_xy(self, footprint: Footprint) -> tuple[float, float]:
        """Body-origin position that puts the footprint centre at (x, y)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        fx, fy = footprint.center
        return (self.x - (c * fx - s * fy), self.y - (s * fx + c * fy))


def corners(footprint: Footprint, pose: PlanarPose, margin: float = 0.0) -> FloatArray:
    """World corners ``[4, 2]`` of the footprint at ``pose``, grown by ``margin`` on each side."""
    hx, hy = footprint.half_size[0] + margin, footprint.half_size[1] + margin
    local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    rot = np.array([[c, -s], [s, c]])
    out: FloatArray = local @ rot.T + np.array([pose.x, pose.y])
    return out


def rects_overlap(a: FloatArray, b: FloatArray) -> bool:
    """Separating-axis test for two convex quads ``[4, 2]``."""
    for quad in (a, b):
        for i in range(4):
            edge = quad[(i + 1) % 4] - quad[i]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


@dataclass(frozen=True)
class PlacementConfig:
    """Where centres may go (reachable workspace), where footprints must stay (camera view)."""

    centers: Rect = Rect(0.25, 0.50, -0.20, 0.20)
    bounds: Rect = Rect(0.14, 0.61, -0.30, 0.30)
    margin: float = 0.015  # m of free space kept around each footprint
    tries_per_object: int = 200
    restarts: int = 50
    # ``bounds`` holds footprints at table height only; the top of a 25 cm bottle near its edge
    # still leaves the overhead image, and an object seen in part lost its grasp (the pitcher's
    # handle, the bleach bottle's cap: 5 of the 6 such dev targets failed). With this on, the
    # evaluation redraws a settled scene in which any object's pixels touch the image's edge
    # (``evaluation.sim_eval.make_episode_specs``), as one sets a real testbed up in view.
    whole_in_view: bool = True


class PlacementError(RuntimeError):
    """The objects do not fit; the message says which and how many tries were made."""


def sample_layout(
    footprints: Sequence[Footprint], rng: np.random.Generator, config: PlacementConfig
) -> list[PlanarPose]:
    """One pose per footprint, in order, with no two footprints (plus margins) overlapping.

    Objects are placed one by one; if one cannot be placed the whole layout restarts, so early
    objects do not box in later ones for good.
    """
    for _ in range(config.restarts):
        poses: list[PlanarPose] = []
        placed: list[FloatArray] = []
        for footprint in footprints:
            pose = _place_one(footprint, placed, rng, config)
            if pose is None:
                break
            poses.append(pose)
            placed.append(corners(footprint, pose, config.margin / 2))
        else:
            return poses
    sizes = [f"{2 * f.half_size[0]:.2f}x{2 * f.half_size[1]:.2f}" for f in footprints]
    raise PlacementError(
        f"could not place footprints {sizes} in {config.centers} after {config.restarts} "
        "restarts; use smaller objects or fewer of them"
    )


def _place_one(
    footprint: Footprint,
    placed: list[FloatArray],
    rng: np.random.Generator,
    config: PlacementConfig,
) -> PlanarPose | None:
    c = config.centers
    for _ in range(config.tries_per_object):
        pose = PlanarPose(
            x=float(rng.uniform(c.x_min, c.x_max)),
            y=float(rng.uniform(c.y_min, c.y_max)),
            yaw=float(rng.uniform(-math.pi, math.pi)),
        )
        quad = corners(footprint, pose, config.margin / 2)
        if not config.bounds.contains(quad):
            continue
        if not any(rects_overlap(quad, other) for other in placed):
            return pose
    return None
