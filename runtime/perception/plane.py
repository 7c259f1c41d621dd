"""Dominant-plane fit (the table) by RANSAC, refined by least squares on the inliers.

Class-agnostic segmentation needs "what is table" before "what is object". Fitting the plane from
the depth image itself, instead of trusting a configured table height, keeps the segmenter usable
with a real camera whose pose is only roughly known.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

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
        out: FloatArray = points @ self.normal
        out += self.offset  # in place: the same sums without a second array
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
    # Preemptive scoring (Nister 2003): every candidate is first counted on an evenly spread
    # probe of this many points, in one matrix product, and only the ``preemptive_keep`` best
    # are counted on all the samples. 0 keeps counts all candidates on all samples.
    preemptive_points: int = 2000
    preemptive_keep: int = 10


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
    """Fit the plane with the most inliers among the finite ``points [..., 3]`` (a list ``[n, 3]``
    or an image ``[H, W, 3]``, taken in row-major order); returns (plane, inliers).

    Seeded, so the same image gives the same plane.
    """
    cfg = config or PlaneFitConfig()
    # a point is finite iff its coordinates' sum is (metres: no overflow); the columns added as
    # three vector adds, faster than numpy's sum over an axis of length 3 (the mask is the same)
    finite = np.flatnonzero(np.isfinite(points[..., 0] + points[..., 1] + points[..., 2]))
    if len(finite) < 3:
        raise ValueError("need at least 3 valid depth points to fit a plane")
    chosen, triples = _draws(len(finite), cfg.seed, cfg.max_samples, cfg.iterations)
    # only the sampled points are gathered (the finite points' ``chosen`` rows): the same sample
    # as gathering every finite point first, without copying the ~4x as many that RANSAC never reads
    picked = finite if chosen is None else finite[chosen]
    sample = points[picked] if points.ndim == 2 else points[np.unravel_index(picked, points.shape[:-1])]
    planes = (_plane_through(sample[t]) for t in _preempted(triples, sample, cfg))
    candidates = [c for c in planes if c is not None]
    if not candidates:
        raise ValueError("all RANSAC samples were degenerate (collinear points)")
    best, best_count = candidates[0], -1
    for candidate in candidates:
        count = int(np.count_nonzero(np.abs(candidate.distance(sample)) < cfg.inlier_threshold))
        if count > best_count:
            best, best_count = candidate, count
    inliers = sample[np.abs(best.distance(sample)) < cfg.inlier_threshold]
    refined = _least_squares(inliers) if len(inliers) >= 3 else best
    return refined, len(inliers)


@lru_cache(maxsize=8)
def _draws(
    count: int, seed: int, max_samples: int, iterations: int
) -> tuple[npt.NDArray[np.intp] | None, npt.NDArray[np.intp]]:
    """RANSAC's random draws for ``count`` points: which points are sampled (None: all of them)
    and the ``[iterations, 3]`` point triples, indices into the sample; read-only.

    Why cached: the draws depend on the point count and the settings only (the generator is
    seeded per fit), and a fixed camera with full depth sees the same count every frame. Drawing
    them (a permutation and 200 separate ``rng.choice`` calls) was about half of the plane fit's
    time on the robot's path (an ad-hoc timing); a cached draw is the same integers, so the same plane bit for bit."""
    rng = np.random.default_rng(seed)
    chosen = None if count <= max_samples else rng.choice(count, max_samples, replace=False)
    size = count if chosen is None else max_samples
    triples = np.array([rng.choice(size, 3, replace=False) for _ in range(iterations)])  # [m, 3]
    for array in (chosen, triples):
        if array is not None:
            array.flags.writeable = False
    return chosen, triples


def _preempted(triples: npt.NDArray[np.intp], sample: FloatArray, cfg: PlaneFitConfig) -> npt.NDArray[np.intp]:
    """The ``preemptive_keep`` point triples whose planes have the most inliers among an evenly
    strided probe of ``sample``, in their drawing order (ties then go to the earlier draw, as
    without the probe); all triples when preemption is off or would keep them all.

    Why: building and counting 200 candidate planes on 20k points was half of segmentation's
    time on the robot's path. The table is the dominant plane, so its candidates lead on any
    fair probe (the probe's count estimates a candidate's share to ~1 %). The probe's planes are
    built in one vectorised pass; the kept ones are rebuilt by ``_plane_through`` and counted
    exactly on all the samples, so the chosen plane is one the full count would choose among them
    (on all 105 dev frames the same plane, bit for bit, as counting all 200:
    ``benchmarks/plane_preemption.py``)."""
    keep = cfg.preemptive_keep
    if keep <= 0 or len(triples) <= keep or cfg.preemptive_points >= len(sample):
        return triples
    p0, p1, p2 = sample[triples[:, 0]], sample[triples[:, 1]], sample[triples[:, 2]]  # [m, 3] each
    normals = np.cross(p1 - p0, p2 - p0)
    norms = np.linalg.norm(normals, axis=1)
    usable = norms >= 1e-9  # collinear triples make no plane (as in _plane_through)
    normals = normals / np.where(usable, norms, 1.0)[:, None]
    offsets = -np.einsum("ij,ij->i", normals, p0)
    probe = sample[:: len(sample) // cfg.preemptive_points]  # [~k, 3], spread over the frame
    distances = probe @ normals.T  # [k, m]; offset and magnitude in place (the same values,
    distances += offsets  # without two more [k, m] temporaries: ~3x faster)
    np.abs(distances, out=distances)
    counts = np.count_nonzero(distances < cfg.inlier_threshold, axis=0)  # [m]
    counts = np.where(usable, counts, -1)
    kept = np.sort(np.argsort(-counts, kind="stable")[:keep])
    return triples[kept]
