"""Object names read in their sense: the text side of ``p(o | r)``.

ConSE places a crop among the embeddings of the ImageNet class names its classifier answers, and
``p(o | r)`` compares that point with each vocabulary name's embedding. A bare name is a poor
anchor there: "remote" or "cup" alone sit where MiniLM puts the word, not where the classes a
photo of one gets ("remote control", "coffee mug") lie. The gloss a name was asked in
("a hand-held remote control with buttons, for a television or other device") says what it is
in the words those class names use. So each name with a gloss is read as the unit mean of its
own embedding and its gloss's, weighted ``1 - w`` and ``w`` (``GroundingSettings.sense_weight``);
a name without a gloss keeps its own embedding, and ``w = 0`` reads names alone (every result
stored before 2026-12-06's change).

Measured on dev data only (``docs/recognition.md``, "Names read in their sense"): on the 222
renders of the testbed's assets top-1 45.9 → 50.5 %, on the ImageNet dev labels CRAFT-E's
top-1 82.7 → 90.5 %, and on three sets of sim-dev layouts 3 more right choices of 315.

The gloss embeddings are computed with the bundle's own text encoder when a ``Grounder`` is
built (a few hundred short texts: about a second, after the encoder's load), once per process
for the same texts.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from ..encoders.base import TextEncoder

FloatArray = npt.NDArray[np.float32]

#: ``id(encoder)``, the texts -> their embeddings: every grounder of a process that reads the
#: same vocabulary's senses (one per method) embeds them once
_EMBEDDED: dict[tuple[int, tuple[str, ...]], FloatArray] = {}


def _unit(x: npt.NDArray[np.floating]) -> FloatArray:
    x64 = np.asarray(x, dtype=np.float64)
    out: FloatArray = (x64 / np.maximum(np.linalg.norm(x64, axis=1, keepdims=True), 1e-12)).astype(np.float32)
    return out


def embed_glosses(encoder: TextEncoder, glosses: Sequence[str]) -> FloatArray:
    """``[n, d]`` embeddings of ``glosses`` (memoized per encoder object and text list)."""
    key = (id(encoder), tuple(glosses))
    cached = _EMBEDDED.get(key)
    if cached is None:
        cached = _EMBEDDED[key] = np.asarray(encoder.embed(list(glosses)), dtype=np.float32)
    return cached


def read_in_sense(names: FloatArray, glosses: Sequence[str | None], weight: float,
                  encoder: TextEncoder | None) -> FloatArray:
    """``[O, d]`` the names' embeddings ``names`` with each glossed row replaced by the unit mean
    ``(1 - weight) * unit(name) + weight * unit(gloss)``; rows without a gloss, and every row when
    ``weight`` is 0 or no name has a gloss, come back as given (``encoder`` is then not used)."""
    rows = [i for i, g in enumerate(glosses) if g]
    if weight == 0.0 or not rows:
        return names
    if encoder is None:
        raise ValueError("reading names in their sense needs the bundle's text encoder")
    gloss_emb = embed_glosses(encoder, [str(glosses[i]) for i in rows])
    if gloss_emb.shape != (len(rows), names.shape[1]):
        raise ValueError(f"gloss embeddings are {tuple(gloss_emb.shape)}, expected [{len(rows)}, {names.shape[1]}]: "
                         "the text encoder does not embed into the bundle's space")
    out = np.array(names, dtype=np.float32, copy=True)
    mixed = (1.0 - weight) * _unit(names[rows]).astype(np.float64) + weight * _unit(gloss_emb).astype(np.float64)
    out[rows] = _unit(mixed)
    return out
