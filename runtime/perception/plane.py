"""Dominant-plane fit (the table) by RANSAC, refined by least squares on the inliers.

Class-agnostic segmentation needs "what is table" before "what is object". Fitting the plane from
the depth image itself, instead of trusting a configured table height, keeps the segmenter usable
with a real camera whose pose is only roughly known.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Plane:
    """Points x with ``normal · x + offset = 0``; ``normal`` is unit length."""

    normal: FloatArray  # [3]
    offset: float

    def distance(self, points: FloatArray) -> FloatArray:
        """Signed distance of points ``[..., 3]``."""
        out: FloatArray = points @ self.normal + self.offset
        return out

    def facing(self, viewpoint: FloatArray) -> Plane:
        """The same plane, oriented so ``viewpoint`` has positive distance (heights up)."""
        if float(viewpoint @ self.normal + self.offset) < 0:
            return Plane(-self.normal, -self.offset)
        return self


@dataclass(frozen=True)
class PlaneFitConfig:
    iterations: int = 200
    inlier_threshold: float = 0.003  # m
    max_samples: int = 20000  # points used for RANSAC scoring (subsampled for speed)
    seed: int = 0


def _plane_through(points: FloatArray) -> Plane | None:
    u0, u1, u2 = (points[1] - points[0]).tolist()
    v0, v1, v2 = (points[2] - points[0]).tolist()
    # np.cross(u, v), written out: the same products and differences in the same order (so the
    # same bits), without np.cross's ~60 us of array plumbing per call (200 calls per frame)
    normal = np.array([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0])
    norm = float(np.linalg.norm(normal))
    if norm < 1e-9:
        return None
    normal = normal / norm
    return Plane(normal, -float(normal @ points[0]))


def _least_squares(points: FloatArray) -> Plane:
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    normal = vt[-1]
    return Plane(normal, -float(normal @ centroid))


def fit_plane(points: FloatArray, config: PlaneFitConfig | None = None) -> tuple[Plane, int]:
    """Fit the plane with the most inliers among finite ``points [n, 3]``; returns (plane, inliers).

    Seeded, so the same image gives the same plane.
    """
    cfg = config or PlaneFitConfig()
    pts = points[np.all(np.isfinite(points), axis=1)]
    if len(pts) < 3:
        raise ValueError("need at least 3 valid depth points to fit a plane")
    rng = np.random.default_rng(cfg.seed)
    sample = (
        pts
        if len(pts) <= cfg.max_samples
        else pts[rng.choice(len(pts), cfg.max_samples, replace=False)]
    )
    best: Plane | None = None
    best_count = -1
    for _ in range(cfg.iterations):
        candidate = _plane_through(sample[rng.choice(len(sample), 3, replace=False)])
        if candidate is None:
            continue
        count = int(np.count_nonzero(np.abs(candidate.distance(sample)) < cfg.inlier_threshold))
        if count > best_count:
            best, best_count = candidate, count
    if best is None:
        raise ValueError("all RANSAC samples were degenerate (collinear points)")
    inliers = sample[np.abs(best.distance(sample)) < cfg.inlier_threshold]
    refined = _least_squares(inliers) if len(inliers) >= 3 else best
    return refined, len(inliers)
