"""The look-alike cue: how well an ROI's ImageNet classes fit the classes each object's photos get.

The image encoder only knows the ImageNet-1k label space, and ConSE reads its answer by the class
*names*: a stapler classified as a "can opener" lands near the name "can opener", far from
"stapler". The bundle's look-alike answers (``object_lookalikes.json``: for each object, up to five
ImageNet classes with the share of photos of a typical instance expected to get each; no picture
of any asset) say which classes an object's photos get, whatever the classes are called. With
``p(c | r)`` the classifier's output on the ROI (its top ``CLASS_TOP_K`` classes) and ``q(c | o)``
the answer's shares, the unnamed rest spread evenly over the 1000 classes,

    L(r | o) = sum_c p(c | r) · ((1 - λ) q(c | o) + λ / C)
    p(o | r)  ∝  p(o | r) · L(r | o)^κ

the chance that the classifier's answer is one the object's photos get. ``λ`` spreads part of
every object's expectation evenly (the answers are guesses about a classifier that never saw
these renders, so no name can be ruled out); ``κ = 1``: one crop is one observation.

How the constants were set (``docs/recognition.md``): the cue's first form, moving ConSE's class
embeddings toward the linked names, was fixed before any measurement and raised top-1 on the
recognition renders by 1–2 points only; this product form was then compared on the same renders
for λ ∈ {0.25, 0.5, 0.75, 0.9} and κ ∈ {0.5, 1} (``benchmarks/bench_lookalike_lambda.py``), and
λ = 0.5, κ = 1 taken from the plateau.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt

from ..encoders.conse import ClassTop
from .size_cue import CueUnavailableError
from .size_cue import with_cue as with_lookalike_cue  # the same renormalised reweighting

FloatArray = npt.NDArray[np.float32]
__all__ = ["KAPPA", "LAMBDA", "LookalikeCueUnavailableError", "lookalike_log_likelihood", "lookalike_table",
           "with_lookalike_cue"]

#: Share of every object's expected classes spread evenly over all classes.
LAMBDA = 0.5
#: Weight of one crop's classifier output.
KAPPA = 1.0


class LookalikeCueUnavailableError(CueUnavailableError):
    """``lookalikes=True`` over a vocabulary the bundle has no look-alike classes for (names them)."""


def lookalike_table(names: Sequence[str], lookalikes: Mapping[str, Sequence[tuple[str, float]]],
                    class_names: Sequence[str], lam: float = LAMBDA) -> FloatArray | None:
    """``(1 - λ) q(c | o) + λ / C`` ``[O, C]`` for ``names`` in order (λ = ``lam``; the grounder
    uses ``LAMBDA``, ``benchmarks/bench_lookalike_lambda.py`` others), or ``None`` when any name has
    no recorded look-alikes (a cue over part of the vocabulary would favour the others). Every
    row sums to one. A class name shared by two classes ('crane') splits its share between them."""
    if not names or any(n not in lookalikes for n in names):
        return None
    rows: dict[str, list[int]] = {}
    for i, c in enumerate(class_names):
        rows.setdefault(c, []).append(i)
    n_classes = len(class_names)
    q = np.zeros((len(names), n_classes), dtype=np.float64)
    for o, name in enumerate(names):
        for cls, share in lookalikes[name]:
            for i in rows[cls]:
                q[o, i] += share / len(rows[cls])
        q[o] += (1.0 - q[o].sum()) / n_classes  # the unnamed rest: any class
    table: FloatArray = ((1.0 - lam) * q + lam / n_classes).astype(np.float32)
    return table


def lookalike_log_likelihood(classes: Sequence[ClassTop | None], table: FloatArray,
                             kappa: float = KAPPA) -> FloatArray:
    """``[N, O]`` ``κ log L(r | o)`` (κ = ``kappa``) of each ROI's top classes under each object's expected
    classes; an ROI without classes (another encoder): 0 for every name, the cue is neutral."""
    out = np.zeros((len(classes), table.shape[0]), dtype=np.float64)
    for n, top in enumerate(classes):
        if not top:
            continue
        idx = np.array([c for c, _ in top], dtype=np.int64)
        p = np.array([v for _, v in top], dtype=np.float64)
        out[n] = kappa * np.log(np.maximum(p @ table[:, idx].astype(np.float64).T, 1e-300))
    return out.astype(np.float32)
