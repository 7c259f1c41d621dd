"""Hubness correction of p(o | r): names that sit near many of the image encoder's labels.

Why: ConSE (``encoders/conse.py``) embeds a crop as the probability-weighted mean of the text
embeddings of its top ImageNet classes, so every crop lies among the 1000 class names. A
vocabulary name close to *many* class names — "tennis ball" beside every ImageNet ball, "cup"
beside the cups, mugs and goblets — collects cosine from any crop whose classifier hesitates
among them, and wins crops that are none of them; a name with no class nearby ("correction
fluid", "dice") wins almost none. This is the hubness problem of nearest-neighbour zero-shot
recognition (Dinu, Lazaridou and Baroni 2015, "Improving zero-shot learning by mitigating the
hubness problem"), and cross-domain similarity local scaling (CSLS; Conneau et al. 2018, "Word
translation without parallel data") is its standard remedy:

    CSLS(r, o) = 2 cos(r, o) - h(o) - h(r),   h(o) = mean of the k highest cos(o, c) over labels c

``h(r)`` is the same for every name of one crop, so in the softmax over names the correction is
``cos(r, o) - h(o) / 2``: a per-name offset, computed once per vocabulary from text embeddings
alone (no image, no asset, no label of any benchmark). ``k = 10`` and the weight 1/2 are CSLS's
own; nothing was fitted. Measured on the dev data before it became the default
(``docs/recognition.md``, "The hubness correction").

The reference labels are those of the image encoder whose embeddings live in the bundle's text
space: for the MiniLM space that is ConSE's 1000 ImageNet class names (``reference_for``). A
bundle in another text space (CLIP) has no such reference here, and grounds without it.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from .size_cue import CueUnavailableError

FloatArray = npt.NDArray[np.float32]

#: neighbours per name (CSLS's k)
HUBNESS_K = 10
#: the offset's weight against the cosine: CSLS's 2 cos - h(o), halved
HUBNESS_WEIGHT = 0.5


class HubnessUnavailableError(CueUnavailableError):
    """``--hubness`` was required but the bundle's text space has no reference labels."""


def name_hubness(names: FloatArray, reference: FloatArray, k: int = HUBNESS_K) -> FloatArray:
    """``[O]`` h(o): the mean of each name's ``k`` highest cosines to the ``reference`` labels.

    ``names`` ``[O, d]`` and ``reference`` ``[R, d]`` need not be unit rows (they are normalized
    here); ``k`` is capped at ``R``."""
    if names.ndim != 2 or reference.ndim != 2 or names.shape[1] != reference.shape[1]:
        raise ValueError(f"names {tuple(names.shape)} and reference {tuple(reference.shape)} must be "
                         "[O, d] and [R, d] in one space")
    if k < 1 or len(reference) == 0:
        raise ValueError(f"k must be >= 1 and the reference non-empty (k={k}, {len(reference)} labels)")
    a = names / np.maximum(np.linalg.norm(names, axis=1, keepdims=True), 1e-12)
    b = reference / np.maximum(np.linalg.norm(reference, axis=1, keepdims=True), 1e-12)
    sims = a.astype(np.float32) @ b.astype(np.float32).T  # [O, R]
    k = min(k, sims.shape[1])
    top = np.partition(sims, sims.shape[1] - k, axis=1)[:, -k:]  # [O, k]
    hub: FloatArray = top.mean(axis=1, dtype=np.float64).astype(np.float32)
    return hub


def with_hubness(cosine: FloatArray, hub: FloatArray, weight: float = HUBNESS_WEIGHT) -> FloatArray:
    """``cosine`` ``[N, O]`` less ``weight`` times each name's hubness ``[O]`` (CSLS)."""
    out: FloatArray = (cosine - np.float32(weight) * hub[None, :]).astype(np.float32)
    return out


def reference_for(text_encoder_id: str, weights_sha256: str, sense_weight: float) -> FloatArray | None:
    """The labels of the image encoder that embeds into this text space (``[R, d]``), or None.

    Only ConSE embeds images into a sentence-embedding space here: for its text encoder (the
    same weights) the reference is its ImageNet class names (``encoders.conse.load_class_embeddings``:
    cached, or computed once by the local text encoder), read in their sense at ``sense_weight``,
    as the ConSE encoder of the same settings reads them."""
    from ..encoders.conse import load_class_embeddings
    from ..encoders.text import MINILM_ID, MINILM_SHA256

    if (text_encoder_id, weights_sha256) != (MINILM_ID, MINILM_SHA256):
        return None
    return np.asarray(load_class_embeddings(sense_weight=sense_weight), dtype=np.float32)
