"""A bundle's look-alike knowledge applied to the ConSE encoder for one object vocabulary.

``object_lookalikes.json`` says which ImageNet-1k classes photos of each object get; the ConSE
encoder links those classes to the object's name (``conse.link_class_embeddings``). The links are
made for a whole vocabulary or not at all: linking only part of it would pull images toward the
linked names.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..grounding.size_cue import CueUnavailableError
from .conse import ConSEImageEncoder

if TYPE_CHECKING:
    from ..kb.bundle import Bundle
    from .image import ImageEncoder

__all__ = ["LookalikesUnavailableError", "linked_encoder"]


class LookalikesUnavailableError(CueUnavailableError):
    """The bundle has no look-alike record (or no name embedding) for some vocabulary names."""


def linked_encoder(encoder: ImageEncoder, bundle: Bundle, vocabulary: Sequence[str]) -> ConSEImageEncoder:
    """``encoder`` with its class embeddings linked to ``vocabulary`` by ``bundle``'s look-alikes.

    The name embeddings are the bundle's (the grounder compares images with the same vectors).
    Raises ``LookalikesUnavailableError`` naming the uncovered names and the fix.
    """
    if not isinstance(encoder, ConSEImageEncoder):
        raise TypeError(f"look-alike links need the ConSE encoder (ImageNet classes), not {encoder.id}")
    missing = [n for n in vocabulary if n not in bundle.lookalikes or n not in bundle.object_index]
    if missing:
        shown = ", ".join(repr(n) for n in missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
        raise LookalikesUnavailableError(
            f"{bundle.path}: no look-alike classes for {shown}; record answers to the "
            "object_lookalike prompt (craftc curate pending --prompt object_lookalike) and rebuild the "
            "bundle, or run without --lookalikes")
    objects = bundle.embeddings["object"]
    links = {n: bundle.lookalikes[n] for n in vocabulary}
    names = {n: objects[bundle.object_index[n]] for n in vocabulary}
    return encoder.with_lookalikes(links, names)
