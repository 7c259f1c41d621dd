"""What the runtime needs of an encoder, as protocols: callers get a typed object from
``encoders.load_image`` / ``load_text_encoder`` and never probe it with ``getattr``."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float32]
UInt8Image = npt.NDArray[np.uint8]


@runtime_checkable
class TextEncoder(Protocol):
    """Names and phrases -> unit vectors ``[N, d]`` in one embedding space."""

    def embed(self, texts: list[str]) -> FloatArray: ...


@runtime_checkable
class ImageEncoder(Protocol):
    """Image crops -> vectors ``[N, d]`` in the space of the text encoder ``text_encoder_id``."""

    id: str
    text_encoder_id: str

    def embed_images(self, crops: Sequence[UInt8Image], batch_size: int = 16) -> FloatArray: ...


def as_image_encoder(obj: Any, name: str) -> ImageEncoder:
    """``obj`` checked against :class:`ImageEncoder` (a registry entry of kind ``image``)."""
    if not isinstance(obj, ImageEncoder):
        raise TypeError(f"encoder {name!r} does not provide embed_images/text_encoder_id")
    return obj
