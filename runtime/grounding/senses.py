"""Object names read in their sense: the text side of ``p(o | r)``.

ConSE places a crop among the embeddings of the ImageNet class names its classifier answers, and
``p(o | r)`` compares that point with each vocabulary name's embedding. A bare name is a poor
anchor there: "shampoo" or "clamp" alone sit where MiniLM puts the word, not near the class
names a photo of one gets. The gloss a name was asked in ("a hand tool with jaws tightened by a
screw or spring to hold things together firmly") says what it is in the everyday words those
class names use. So each name with a gloss is read as the unit mean of its own embedding and its
gloss's, weighted ``1 - w`` and ``w`` (``GroundingSettings.sense_weight``); a name without a
gloss keeps its own embedding, and ``w = 0`` reads names alone (every result stored before
2026-12-06's change).

Measured on dev data only (``docs/recognition.md``, "Names read in their sense"): on the 222
renders of the testbed's assets top-1 45.9 → 50.5 %, on the ImageNet dev labels CRAFT-E's
top-1 82.7 → 90.5 %, and on three sets of sim-dev layouts 3 more right choices of 315.

The glosses are embedded with the bundle's text encoder, one text per pass (each vector
independent of the others), when a ``Grounder`` is built: once per process for the same texts,
and, for the shipped MiniLM encoder, cached on disk beside ConSE's class names
(``encoders/conse.py``), so a later process (a server's restart, an evaluation's workers) reads
them without loading the encoder.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ..encoders.base import TextEncoder
from ..encoders.text import sense_mean

FloatArray = npt.NDArray[np.float32]

#: (the encoder: its (id, weights sha256) when cached on disk, else the object's id), the texts
#: -> their embeddings: every grounder of a process reading the same senses embeds them once
_EMBEDDED: dict[tuple[object, tuple[str, ...]], FloatArray] = {}


def _texts_sha256(texts: Sequence[str]) -> str:
    return hashlib.sha256("\n".join(texts).encode()).hexdigest()


def senses_cache_path(cache_dir: Path, text_id: str, text_sha256: str, glosses: Sequence[str]) -> Path:
    """Cache file of one list of glosses' embeddings under one text encoder."""
    return cache_dir / f"senses.{text_id}.{text_sha256[:12]}.{_texts_sha256(glosses)[:12]}.safetensors"


def embed_glosses(glosses: Sequence[str], encoder: Callable[[], TextEncoder],
                  cached_as: tuple[str, str] | None = None, cache_dir: Path | None = None) -> FloatArray:
    """``[n, d]`` embeddings of ``glosses`` by ``encoder()`` (called only when they must be
    computed), memoized per process. ``cached_as`` (the encoder's id and weights sha256: only for
    an encoder known by them, never a caller's stand-in) also keeps them on disk in ``cache_dir``
    (default: ConSE's cache folder)."""
    from ..encoders.conse import ENCODER_CACHE_DIR, cached_text_embeddings

    texts = tuple(glosses)
    key: tuple[object, tuple[str, ...]] = (cached_as if cached_as is not None else id(encoder()), texts)
    found = _EMBEDDED.get(key)
    if found is None:
        if cached_as is None:
            found = np.asarray(encoder().embed(list(texts)), dtype=np.float32)
        else:
            text_id, sha = cached_as
            path = senses_cache_path(cache_dir or ENCODER_CACHE_DIR, text_id, sha, texts)
            meta = {"text_encoder": text_id, "weights_sha256": sha, "glosses_sha256": _texts_sha256(texts)}
            found = cached_text_embeddings(path, meta, "gloss_embeddings", texts, encoder, batched=False)
        _EMBEDDED[key] = found
    return found


def read_in_sense(names: FloatArray, glosses: Sequence[str | None], weight: float,
                  embed: Callable[[list[str]], FloatArray] | None) -> FloatArray:
    """``[O, d]`` the names' embeddings ``names`` with each glossed row replaced by the unit mean
    ``(1 - weight) * unit(name) + weight * unit(gloss)``, the glosses embedded by ``embed``; rows
    without a gloss, and every row when ``weight`` is 0 or no name has a gloss, come back as given
    (``embed`` is then not called)."""
    rows = [i for i, g in enumerate(glosses) if g]
    if weight == 0.0 or not rows:
        return names
    if embed is None:
        raise ValueError("reading names in their sense needs the bundle's text encoder")
    gloss_emb = np.asarray(embed([str(glosses[i]) for i in rows]), dtype=np.float32)
    if gloss_emb.shape != (len(rows), names.shape[1]):
        raise ValueError(f"gloss embeddings are {tuple(gloss_emb.shape)}, expected [{len(rows)}, {names.shape[1]}]: "
                         "the text encoder does not embed into the bundle's space")
    out = np.array(names, dtype=np.float32, copy=True)
    out[rows] = sense_mean(names[rows], gloss_emb, weight)
    return out
