"""Geometric grasps for a region the fingers fit around none of the network's grasps on.

Why: on the dev episodes some regions get no network grasp the hand can close around. GR-ConvNet
finds no peak at all on the dice and the golf ball (4 sim-val targets), and elsewhere every peak
may close across a section wider than the hand (the sponge, whose section at the fingers' height
is about the Franka hand's limit, 7.6 cm when this was written, in 4 sim-val episodes).
Grounding excludes a region without a usable grasp, so the knowledge never got a say
(``no_grasp``). A robot is not limited to one grasp detector: the analytic antipodal sampler
(``grasp/antipodal.py``) reads the same depth image and region mask and proposes grasps across
the region's narrow parts.

It is a *fallback*: asked for only when the fingers fit around none of the network's grasps on
the region (nor their refinements), and its grasps go through the same finger and IK checks. A
region whose network grasps fit but whose picks are unreachable gets none, so each region's
list is either the network's or the sampler's, each best first, which the robot's lazy path
needs (``sim/choose.py``, where the sampler runs only if the region could win).

Its grasps keep the sampler's score as their quality (``quality_scale`` 1). A first version
scaled it by 0.2, the networks' peak threshold, to rank every fallback grasp below every network
grasp; on the evaluation's dice and golf-ball episodes that left all four wrong choices, where
the sampler's own score lets three succeed (``benchmarks/bench_pick_settings.py``,
``docs/results/sim_execution.md``).

The sampler's centres gather where the region is deepest. A mug or a pitcher is wider than the
hand everywhere but at its handle, and the handle, thin, held almost none of them: the region got
no grasp (3 of sim-dev's pitcher episodes and a mug's, layout seeds 0-2). Where the sampler finds
nothing, the fallback therefore asks it again with ``thin_centres`` more centres on the ridge of
the region's parts narrow enough for the opening (``AntipodalConfig.n_thin_centres``).

The sampler runs on a crop around the region (its box plus the open hand's half-width and
``margin_m``), not on the whole frame: several times cheaper, and the same grasps, shifted,
wherever the fingers' zones stay inside the crop (``tests/test_grasp_fallback.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from ..grasp.antipodal import AntipodalConfig, sample_antipodal_grasps
from ..grasp.geometry import CameraIntrinsics, Grasp2D


@dataclass(frozen=True)
class FallbackConfig:
    """Whether regions no network grasp fits get the antipodal sampler's grasps, and how."""

    enabled: bool = True
    #: extra metres around the region's box in the sampler's crop, beyond the open hand's
    #: half-width: the finger zones it inspects must lie inside the crop
    margin_m: float = 0.03
    #: the fallback's grasp scores are the sampler's times this (0.2, the networks' threshold,
    #: puts them below every network grasp: measured first, ``docs/results/sim_execution.md``)
    quality_scale: float = 1.0
    #: the gap per side the sampler leaves between the open jaw and the object (its span limit is
    #: the opening less twice this); None: the hand's own finger-check clearance
    #: (``FingerGeometry.clearance``, 3 mm; 2 mm when this was chosen), since every fallback grasp goes
    #: through that check anyway. The sampler's own default, 5 mm, was the fallback's first
    #: setting: it capped spans at 7 cm where the check allowed 7.6, and the sponge (about as wide
    #: as the opening) got no grasp (``docs/results/sim_execution.md``).
    min_clearance_m: float | None = None
    #: the sampler's extra centres on the region's thin parts (``AntipodalConfig.n_thin_centres``),
    #: drawn only when its other centres give no grasp: those gather where the region is deepest,
    #: so a mug's or a pitcher's handle, the only part of them the fingers fit around, got none and
    #: the region no grasp. Only then: on a region that has grasps the thin parts won on their
    #: narrow span and a spray bottle was held by its nozzle, far from its mass, and slipped in the
    #: carry (``docs/results/sim_execution.md``). 0: none (the fallback before 2026-12-07, session 43)
    thin_centres: int = 32

    def __post_init__(self) -> None:
        if not 0 < self.quality_scale <= 1:
            raise ValueError(f"quality_scale {self.quality_scale}: must be in (0, 1]")
        if self.min_clearance_m is not None and not 0 <= self.min_clearance_m < 0.05:
            raise ValueError(f"min_clearance_m {self.min_clearance_m} m: must be in [0, 0.05)")
        if self.thin_centres < 0:
            raise ValueError(f"thin_centres {self.thin_centres}: must be >= 0 (0: none)")

    def clearance(self, hand_clearance: float) -> float:
        """The sampler's gap per side for a hand whose finger check leaves ``hand_clearance``."""
        return hand_clearance if self.min_clearance_m is None else self.min_clearance_m


def fallback_grasps(
    depth: npt.NDArray[np.floating], mask: npt.NDArray[np.bool_], box_xywh: tuple[int, int, int, int],
    intrinsics: CameraIntrinsics, *, max_opening_m: float, min_clearance_m: float, max_grasps: int,
    config: FallbackConfig,
) -> list[Grasp2D]:
    """Antipodal grasps on ``mask`` (full-frame ``[H, W]``), best first, in full-frame pixels,
    their quality times ``config.quality_scale``; spans up to ``max_opening_m`` less
    ``min_clearance_m`` a side (``FallbackConfig.clearance`` gives it for a hand)."""
    if not mask.any():
        return []
    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    seen = np.asarray(depth, dtype=np.float64)[ys, xs]
    seen = seen[np.isfinite(seen) & (seen > 0)]
    if not seen.size:
        return []  # no depth on the region: nothing to measure a grasp with
    depth_m = float(np.median(seen))
    px_per_m = 0.5 * (intrinsics.fx + intrinsics.fy) / depth_m
    pad = math.ceil((max_opening_m / 2 + config.margin_m) * px_per_m)
    x, y, bw, bh = box_xywh
    x0, y0 = max(x - pad, 0), max(y - pad, 0)
    x1, y1 = min(x + bw + pad, w), min(y + bh + pad, h)
    crop_intrinsics = CameraIntrinsics(x1 - x0, y1 - y0, intrinsics.fx, intrinsics.fy,
                                       intrinsics.cx - x0, intrinsics.cy - y0)
    sampler = AntipodalConfig(max_opening_m=max_opening_m, min_clearance_m=min_clearance_m)
    depth_crop, mask_crop = np.asarray(depth)[y0:y1, x0:x1], mask[y0:y1, x0:x1]
    found = sample_antipodal_grasps(depth_crop, mask_crop, crop_intrinsics, max_grasps, sampler)
    if not found and config.thin_centres > 0:  # a last resort: see ``FallbackConfig.thin_centres``
        found = sample_antipodal_grasps(depth_crop, mask_crop, crop_intrinsics, max_grasps,
                                        replace(sampler, n_thin_centres=config.thin_centres))
    return [replace(g, center_xy=(g.center_xy[0] + x0, g.center_xy[1] + y0),
                    quality=float(g.quality) * config.quality_scale) for g in found]
