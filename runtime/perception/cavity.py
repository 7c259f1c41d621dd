"""An ROI's open cavity from depth: how far its inside lies below its rim, seen from above.

The image encoder names an upright cup a "pill bottle" and a mug a "drill": the ImageNet label
space has no better word. The overhead depth camera sees what makes a cup a cup for pouring and
containing: an open hollow whose floor lies centimetres below its rim. A ball, a box, a tool or a
closed bottle shows none (their tops are domes, flats or ridges). The cavity cue
(``grounding/cavity_cue.py``) compares this measurement with what the knowledge base says of each
object's shape (the property "is concave").

The measure: the region's raised pixels are split into a rim band (its outer ring) and a core (the
mask eroded by a fifth of its equivalent diameter); the cavity depth is the rim's height minus the
core's median height (``np.percentile``'s values, ``extents._percentiles``). An open container's
core is its floor, well below the rim; a dome's core is its highest part (a negative depth); a
flat top gives about zero. Percentiles, not extremes, so stray depth pixels at the mask's edge do
not count.

The rim's height is that of an *enclosing* rim (since 2026-12-05, later): the band is cut into
``RIM_SECTORS`` angular sectors around the region's centroid, each sector's rim is its
``RIM_PERCENTILE``-th height, and the rim is the median over the sectors, so at least half the
directions around the core must stand that high. A hollow is walled all round; an object that is
only high at one end is not one. Before, the band's 90th percentile over all its pixels let one
raised end count as a rim: a glue bottle lying with its cap up read as 2.4-4.3 cm deep, as deep
as a bowl, and was taken for a spoon or a cup (docs/recognition.md, "The enclosing rim"). Cups and
bowls, walled all round, measure the same either way.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from .extents import _percentiles

BoolMask = npt.NDArray[np.bool_]

#: Fewer raised pixels than this and the ROI is not measured (its cavity cue is neutral).
MIN_PIXELS = 30
#: ... and fewer core pixels than this after the erosion (a thin object: a marker, a knife).
MIN_CORE_PIXELS = 10
#: The rim band's width as a share of the mask's equivalent diameter (sqrt of its area).
CORE_EROSION = 0.2
RIM_PERCENTILE = 90.0
#: Angular sectors of the rim band; the rim is the median of their heights (an enclosing rim).
RIM_SECTORS = 8
#: A sector with fewer band pixels than this has no height of its own (it is left out).
MIN_SECTOR_PIXELS = 3


def measure_cavity(height_m: npt.NDArray[np.floating], mask: BoolMask) -> float | None:
    """Depth in metres of the open cavity of the region ``mask`` (``[H, W]``, its raised pixels)
    in ``height_m`` (``[H, W]``, each pixel's height above the table); ``None`` when the region is
    too small or too thin to have a core. Pixels without depth must be False in ``mask`` (the
    heights under it must be finite).

    Works on the mask's bounding box only: the core is the same as over the whole frame (every
    pixel outside the box is outside the mask) at a fraction of the cost."""
    ys, xs = np.nonzero(mask)
    if len(ys) < MIN_PIXELS:
        return None
    top, bottom, left, right = int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1
    region = mask[top:bottom, left:right]
    heights = np.asarray(height_m[top:bottom, left:right], dtype=np.float64)
    band = max(2, int(CORE_EROSION * math.sqrt(len(ys))))
    # ``band`` erosions by the 4-neighbour cross, in one pass: the pixels more than ``band``
    # steps (taxicab) from the outside, the crop padded so that its edge is outside too
    steps = ndimage.distance_transform_cdt(np.pad(region, 1), metric="taxicab")[1:-1, 1:-1]
    core = steps > band
    if int(np.count_nonzero(core)) < MIN_CORE_PIXELS:
        return None
    centre = (float((ys - top).mean()), float((xs - left).mean()))  # the region's centroid in the crop
    return enclosing_rim(heights, region, core, centre) - _percentiles(heights[core], (50.0,))[0]


def enclosing_rim(heights: npt.NDArray[np.float64], region: BoolMask, core: BoolMask,
                  centre: tuple[float, float]) -> float:
    """The height that the rim band (``region`` outside ``core``) reaches in at least half the
    directions around ``centre`` (row, column: the region's centroid): the median over
    ``RIM_SECTORS`` angular sectors of each sector's ``RIM_PERCENTILE``-th height (sectors with
    fewer than ``MIN_SECTOR_PIXELS`` band pixels left out)."""
    cy, cx = centre
    band = region & ~core
    by, bx = np.nonzero(band)
    angle = np.arctan2(by - cy, bx - cx)  # (-pi, pi]
    sector = np.minimum((angle + np.pi) * (RIM_SECTORS / (2 * np.pi)), RIM_SECTORS - 1).astype(np.intp)
    band_heights = heights[by, bx]
    members = [band_heights[sector == k] for k in range(RIM_SECTORS)]
    tops = [_percentiles(m, (RIM_PERCENTILE,))[0] for m in members if len(m) >= MIN_SECTOR_PIXELS]
    if not tops:  # a band too thin to fill any sector: all of it is one rim
        return _percentiles(band_heights, (RIM_PERCENTILE,))[0]
    return _percentiles(np.array(tops, dtype=np.float64), (50.0,))[0]
