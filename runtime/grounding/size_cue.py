"""The size cue: how well an ROI's measured extents fit each object's typical size.

``p(o | r)`` from the image encoder alone names a rendered cup a "pill bottle" and a marker a
"hammer": the ImageNet label space has no better word, and the text space then lands near the
wrong vocabulary name. A depth camera measures what the colour image cannot: an ROI 12 cm long
is not a 33 cm hammer. With the bundle's typical sizes (``object_sizes.json``, one recorded
answer per object, no picture of any asset), ``p(o | r)`` becomes

    p(o | r)  ∝  p_image(o | r) · N(log e(r) ; log s(o), σ(o)² + σ_m²)

over the three box edges sorted longest first (so an object's pose does not matter): ``e(r)``
the ROI's measured extents, ``s(o)`` the typical ones, ``σ(o)`` how much instances of ``o`` vary
(the record's ``variability``) and ``σ_m`` the measurement's own error (a top view sees the top
of a partly hidden object). Both are in log space: 30 % too long counts the same for a marble as
for a pitcher. The Gaussian's normaliser stays in: a name that allows any size must not win
every ROI.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt

from ..kb.sizes import TypicalSize

FloatArray = npt.NDArray[np.float32]

class CueUnavailableError(ValueError):
    """A perception cue was required over a vocabulary the bundle lacks its knowledge for."""


class SizeCueUnavailableError(CueUnavailableError):
    """``size_cue=True`` over a vocabulary the bundle has no typical size for (names them)."""


#: Log-space spread of instances' sizes for each ``variability`` grade, fixed a priori from the
#: prompt's wording: "within about 20 %", "within about a factor of 1.5", "a factor of 2 or more".
SIGMA_BY_VARIABILITY: dict[str, float] = {"low": 0.2, "medium": 0.4, "high": 0.7}
#: Log-space error of a top view's extents (occlusion, the unseen underside, segmentation).
MEASUREMENT_SIGMA = 0.3


def size_table(names: Sequence[str], sizes: Mapping[str, TypicalSize]) -> tuple[FloatArray, FloatArray] | None:
    """``(log sizes [O, 3], variances [O])`` for ``names`` in order, or ``None`` when any name has
    no recorded size (a cue over part of the vocabulary would favour the unmeasured names)."""
    if not names or any(n not in sizes for n in names):
        return None
    log_dims = np.log(np.array([sizes[n].dimensions_m for n in names], dtype=np.float64))
    spread = np.array([SIGMA_BY_VARIABILITY[sizes[n].variability] for n in names], dtype=np.float64)
    return log_dims.astype(np.float32), (spread**2 + MEASUREMENT_SIGMA**2).astype(np.float32)


def size_log_likelihood(extents_m: npt.NDArray[np.floating], table: tuple[FloatArray, FloatArray]) -> FloatArray:
    """``[N, O]`` log-likelihood of each ROI's extents (``[N, 3]`` metres, longest first; a row
    of NaN: not measured, likelihood 0 for every name) under each object's typical size."""
    log_dims, var = table
    ext = np.asarray(extents_m, dtype=np.float64)
    measured: npt.NDArray[np.bool_] = np.asarray(np.isfinite(ext).all(axis=1) & (ext > 0).all(axis=1))  # [N]
    log_ext = np.log(np.where(measured[:, None], ext, 1.0))  # [N, 3]
    d2 = ((log_ext[:, None, :] - log_dims[None, :, :].astype(np.float64)) ** 2).sum(axis=2)  # [N, O]
    ll = -d2 / (2.0 * var[None, :]) - 1.5 * np.log(var[None, :].astype(np.float64))
    return np.where(measured[:, None], ll, 0.0).astype(np.float32)


def with_cue(p: FloatArray, log_likelihood: FloatArray) -> FloatArray:
    """``p(o | r)`` reweighted by a cue's likelihood (size, colour), renormalised per ROI (``[N, O]``)."""
    ll = log_likelihood.astype(np.float64)
    w = p.astype(np.float64) * np.exp(ll - ll.max(axis=1, keepdims=True))
    total = w.sum(axis=1, keepdims=True)
    out = np.where(total > 0, w / np.where(total > 0, total, 1.0), p)
    return out.astype(np.float32)


with_size_cue = with_cue
