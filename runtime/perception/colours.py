"""An ROI's colours: the share of its pixels in each of the eleven basic colour terms.

The colour cue (``grounding/colour_cue.py``) compares them with each object's typical colours, a
bundle's knowledge written in the same eleven words (``kb/colours.py``). Each pixel is named by
fixed HSV rules set a priori from the terms' usual boundaries (hue sectors for the chromatic
terms; black, grey and white by brightness where saturation is low; brown for dark or greyish
oranges and yellows). They are deliberately coarse: the cue asks "is this ROI mostly yellow",
not for a colour science measurement, and nothing about any asset went into them.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..kb.colours import COLOUR_TERMS

FloatArray = npt.NDArray[np.float64]
#: Fewer object pixels than this and the ROI's colours are not measured (the cue is neutral).
MIN_PIXELS = 30
_INDEX = {t: i for i, t in enumerate(COLOUR_TERMS)}
#: Chromatic hue sectors in degrees, ``[start, end)``, checked in order (red wraps around 0).
_HUES: tuple[tuple[float, float, str], ...] = (
    (15.0, 45.0, "orange"), (45.0, 70.0, "yellow"), (70.0, 170.0, "green"),
    (170.0, 260.0, "blue"), (260.0, 300.0, "purple"), (300.0, 340.0, "pink"),
)
BLACK_VALUE = 0.18  # V below this: black whatever the hue
ACHROMATIC_SATURATION = 0.2  # S below this: black, grey or white by V
WHITE_VALUE = 0.75
GREY_VALUE = 0.35
BROWN_VALUE = 0.55  # an orange or yellow darker than this is brown
BROWN_SATURATION = 0.45  # ... or greyish (tan, beige, wood)
PINK_SATURATION = 0.55  # a red this pale and bright is pink
PINK_VALUE = 0.6


def colour_terms(rgb: npt.NDArray[np.uint8]) -> npt.NDArray[np.intp]:
    """The index into ``COLOUR_TERMS`` of each pixel of ``rgb`` ``[M, 3]``."""
    x = np.asarray(rgb, dtype=np.float64).reshape(-1, 3) / 255.0
    v = x.max(axis=1)
    c = v - x.min(axis=1)
    s = np.where(v > 0, c / np.where(v > 0, v, 1.0), 0.0)
    r, g, b = x[:, 0], x[:, 1], x[:, 2]
    safe_c = np.where(c > 0, c, 1.0)
    h = np.where(v == r, ((g - b) / safe_c) % 6.0, np.where(v == g, (b - r) / safe_c + 2.0, (r - g) / safe_c + 4.0))
    hue = np.where(c > 0, 60.0 * h, 0.0)
    out = np.full(len(x), _INDEX["red"], dtype=np.intp)
    for start, end, term in _HUES:
        out[(hue >= start) & (hue < end)] = _INDEX[term]
    warm = (out == _INDEX["orange"]) | (out == _INDEX["yellow"])
    out[warm & ((v < BROWN_VALUE) | (s < BROWN_SATURATION))] = _INDEX["brown"]
    out[(out == _INDEX["red"]) & (s < PINK_SATURATION) & (v > PINK_VALUE)] = _INDEX["pink"]
    out[(out == _INDEX["pink"]) & (v < GREY_VALUE + 0.15)] = _INDEX["purple"]
    achromatic = s < ACHROMATIC_SATURATION
    out[achromatic] = np.where(v[achromatic] >= WHITE_VALUE, _INDEX["white"],
                               np.where(v[achromatic] >= GREY_VALUE, _INDEX["grey"], _INDEX["black"]))
    out[v < BLACK_VALUE] = _INDEX["black"]
    return out


def measure_colours(rgb_pixels: npt.NDArray[np.uint8]) -> tuple[float, ...] | None:
    """Shares of ``rgb_pixels`` ``[M, 3]`` (one object's pixels) in each colour term, in
    ``COLOUR_TERMS`` order; ``None`` when too few pixels to measure."""
    pixels = np.asarray(rgb_pixels).reshape(-1, 3)
    if len(pixels) < MIN_PIXELS:
        return None
    counts = np.bincount(colour_terms(pixels), minlength=len(COLOUR_TERMS)).astype(np.float64)
    return tuple(round(float(v), 6) for v in counts / counts.sum())
