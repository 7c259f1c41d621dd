"""The cavity cue: does an ROI show the open hollow that the knowledge base says an object has?

The knowledge base's properties were written to be visually checkable (``artifacts/curation``):
"is concave" is defined as "has a hollow, cupped shape that can hold loose material", and its
property -> object weights ``w(o)`` (cup 0.8, bowl 1.0, mug 1.0, pitcher 0.9, plate 0.3, knife
0) are the knowledge. The overhead depth measures the same thing: how far an ROI's inside lies
below its rim (``perception/cavity.py``). ``p(o | r)`` becomes

    p(o | r)  ∝  p(o | r) · [ s(r) · P_seen(o) + (1 − s(r)) · (1 − P_seen(o)) ]
    P_seen(o)  = h(o) · SEEN_IF_CONCAVE + (1 − h(o)) · SEEN_IF_NOT,   h(o) = w(o) · d(o)
    s(r)       = sigmoid((c(r) − THRESHOLD_M) / SCALE_M)

with ``c(r)`` the measured cavity depth: a cavity seen is strong evidence for the hollow objects,
none seen is weak evidence against them. The detector's rates were fixed before any measurement:
a concave object shows its hollow from above in ``SEEN_IF_CONCAVE`` = 60 % of views (it may lie
on its side, or its hollow be a spoon's, too shallow for the camera), anything else in 3 %
(a gap between parts); a hollow counts from 2 cm deep (a cup's floor lies 5 cm or more below its
rim, a flat top's texture a few millimetres), give or take 5 mm. No asset, render or result
entered these numbers; the one look at the measurement before them (every sim asset alone, ad
hoc) is reported in ``docs/recognition.md``.

``d(o)`` is the depth bound (2026-12-05, later): a hollow cannot be deeper than its object is thick,
so an object can show a hollow of ``THRESHOLD_M`` only if its thinnest edge is longer than that.
With the bundle's typical size (``object_sizes.json``: the thinnest of the three edges ``t(o)``
and the spread of instances ``σ(o)``, the size cue's ``SIGMA_BY_VARIABILITY``)
``d(o) = Φ(ln(t(o) / THRESHOLD_M) / σ(o))``, the chance that an instance is thicker than the
threshold: a cup (8 cm) 1.0, a plate (2.5 cm) 0.71, a spoon (2 cm) 0.5; 1 for a name without a
recorded size. An upper bound (a floor and walls make every hollow shallower than its object), so
it only removes evidence the geometry rules out. Why: the "is concave" weight says what shape an
object has, not how deep its hollow is, and with it alone a spoon that shows no 2 cm hollow (none
can) counted as evidence against the spoon: on sim-dev, a 0.8 rate lost three spoon episodes
(``benchmarks/bench_cavity_cue.py``).

It is a check of a property, so it belongs to the bundles that have properties: a bundle whose
graph does not define "is concave" (direct-LLM's verb -> object lists, ConceptNet's relations)
grounds without it, and results record per method whether it was on (``cavity_cue_active``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from ..kb.bundle import Bundle
from ..kb.sizes import TypicalSize
from .size_cue import SIGMA_BY_VARIABILITY
from .size_cue import with_cue as with_cavity_cue  # the same renormalised reweighting

FloatArray = npt.NDArray[np.float32]
__all__ = ["cavity_log_likelihood", "cavity_table", "depth_bound", "with_cavity_cue"]

#: The knowledge base property whose weights say which objects are hollow.
CONCAVE_PROPERTY = "is concave"
SEEN_IF_CONCAVE = 0.6
SEEN_IF_NOT = 0.03
THRESHOLD_M = 0.02
SCALE_M = 0.005
#: Weigh "is concave" by the chance that the object is thick enough to hold a hollow of
#: ``THRESHOLD_M`` (``depth_bound``); off only to measure what it changes (bench_cavity_cue.py).
DEPTH_BOUND = True


def cavity_table(names: Sequence[str], bundle: Bundle) -> FloatArray | None:
    """``P_seen(o)`` ``[O]`` for ``names`` in order, or ``None`` when the bundle's graph has no
    "is concave" property or does not know every name as an object (a name the graph does not
    hold would read as "not hollow", which is not what the graph says)."""
    graph = bundle.index
    edges = graph.property_objects.get(CONCAVE_PROPERTY)
    known = graph.object_names
    if not names or edges is None or any(n not in known for n in names):
        return None
    weight = {e.target_name: e.weight for e in edges}
    w = np.array([weight.get(n, 0.0) for n in names], dtype=np.float64)
    if DEPTH_BOUND:
        w = w * np.array([depth_bound(bundle.sizes.get(n)) for n in names], dtype=np.float64)
    return (w * SEEN_IF_CONCAVE + (1.0 - w) * SEEN_IF_NOT).astype(np.float32)


def depth_bound(size: TypicalSize | None, threshold_m: float | None = None) -> float:
    """The chance that an instance of an object of typical ``size`` is thicker than the
    threshold (``THRESHOLD_M`` unless given), so that it could hold a hollow that deep: its
    thinnest edge log-normal around the recorded one, with the size cue's spread for the record's
    variability. 1 when no size is recorded (no bound known)."""
    if size is None:
        return 1.0
    thinnest = min(size.dimensions_m)
    sigma = SIGMA_BY_VARIABILITY[size.variability]
    z = math.log(thinnest / (THRESHOLD_M if threshold_m is None else threshold_m)) / sigma
    return 0.5 * math.erfc(-z / math.sqrt(2.0))


def cavity_log_likelihood(cavity_m: npt.NDArray[np.floating], table: FloatArray) -> FloatArray:
    """``[N, O]`` log-likelihood of each ROI's cavity depth (``[N]`` metres; NaN: not measured,
    likelihood 1 for every name) under each object's chance of showing a hollow."""
    c = np.asarray(cavity_m, dtype=np.float64)
    measured = np.isfinite(c)
    seen = 1.0 / (1.0 + np.exp(-(np.where(measured, c, 0.0) - THRESHOLD_M) / SCALE_M))  # [N]
    p_seen = table.astype(np.float64)[None, :]  # [1, O]
    likelihood = seen[:, None] * p_seen + (1.0 - seen[:, None]) * (1.0 - p_seen)
    return np.where(measured[:, None], np.log(likelihood), 0.0).astype(np.float32)
