"""The colour cue: how well an ROI's colours fit each object's typical colours.

After the size cue, the image encoder still names a rendered orange a "bowl" and a peach a
"racquetball": the ImageNet label space lands near a vocabulary name of the wrong colour. The
bundle's typical colours (``object_colours.json``, one recorded answer per object in the eleven
basic colour terms, no picture of any asset) and the ROI's measured colour shares ``h(r)``
(``perception/colours.py``, the same eleven terms) give

    p(o | r)  ∝  p(o | r) · exp(κ · Σ_k h_k(r) · log q_k(o))

a cross-entropy between what the camera sees and what the object is expected to show. ``q(o)``
is the answer's shares, the unnamed rest spread evenly over the eleven terms, mixed with an even
spread by the answer's ``variability`` (a mug "made in any colour" expects little). ``q`` sums to
one for every object, so a name that allows any colour cannot win every ROI. ``κ = 1``: an ROI's
pixels are one surface under one light, one observation rather than thousands. Both constants
were fixed a priori, before any measurement.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt

from ..kb.colours import COLOUR_TERMS, TypicalColours
from .size_cue import CueUnavailableError
from .size_cue import with_cue as with_colour_cue  # the same renormalised reweighting

FloatArray = npt.NDArray[np.float32]
__all__ = ["ColourCueUnavailableError", "colour_log_likelihood", "colour_table", "with_colour_cue"]


class ColourCueUnavailableError(CueUnavailableError):
    """``colour_cue=True`` over a vocabulary the bundle has no typical colours for (names them)."""


#: Share of an object's expected colours spread evenly over all terms, by ``variability``:
#: "almost every instance", "usual colours, others common", "made in any colour".
EVEN_SHARE_BY_VARIABILITY: dict[str, float] = {"low": 0.15, "medium": 0.4, "high": 0.75}
#: Weight of one ROI's colour evidence (one observation of one surface).
KAPPA = 1.0


def colour_table(names: Sequence[str], colours: Mapping[str, TypicalColours]) -> FloatArray | None:
    """``log q`` ``[O, K]`` for ``names`` in order (K = the eleven terms), or ``None`` when any name
    has no recorded colours (a cue over part of the vocabulary would favour the others)."""
    if not names or any(n not in colours for n in names):
        return None
    k = len(COLOUR_TERMS)
    index = {t: i for i, t in enumerate(COLOUR_TERMS)}
    q = np.zeros((len(names), k), dtype=np.float64)
    for row, name in enumerate(names):
        entry = colours[name]
        for term, share in entry.shares:
            q[row, index[term]] += share
        q[row] += (1.0 - q[row].sum()) / k  # the unnamed rest: any colour
        even = EVEN_SHARE_BY_VARIABILITY[entry.variability]
        q[row] = (1.0 - even) * q[row] + even / k
    return np.log(q).astype(np.float32)


def colour_log_likelihood(shares: npt.NDArray[np.floating], table: FloatArray) -> FloatArray:
    """``[N, O]`` log-likelihood of each ROI's colour shares (``[N, K]``; a row of NaN: not
    measured, likelihood 0 for every name) under each object's typical colours."""
    h = np.asarray(shares, dtype=np.float64)
    measured: npt.NDArray[np.bool_] = np.asarray(np.isfinite(h).all(axis=1))  # [N]
    ll = KAPPA * (np.where(measured[:, None], h, 0.0) @ table.astype(np.float64).T)  # [N, O]
    return np.where(measured[:, None], ll, 0.0).astype(np.float32)

