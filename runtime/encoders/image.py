"""What every image encoder shares: the ``ImageEncoder`` protocol, ROI crops and preprocessing.

An image encoder maps RGB crops into the *text* embedding space of a bundle (``text_encoder_id``),
so that ``cos(phi_I(r), phi_T(o))`` is meaningful; the grounder refuses an encoder whose text
space is not the bundle's.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

UInt8Image = npt.NDArray[np.uint8]
FloatArray = npt.NDArray[np.float32]


@runtime_checkable
class ImageEncoder(Protocol):
    """``embed_images(crops) -> [N, dim]`` unit vectors in the space of ``text_encoder_id``."""

    @property
    def id(self) -> str: ...

    @property
    def text_encoder_id(self) -> str: ...

    @property
    def dim(self) -> int: ...

    def embed_images(self, crops: Sequence[UInt8Image], batch_size: int = 16) -> FloatArray: ...


@runtime_checkable
class FusableImageEncoder(ImageEncoder, Protocol):
    """An encoder with a faster inference twin: the same embeddings to float rounding."""

    def fused(self) -> ImageEncoder: ...


def inference_encoder(encoder: ImageEncoder) -> ImageEncoder:
    """``encoder``'s fused twin where it has one (the robot's path), else ``encoder``."""
    return encoder.fused() if isinstance(encoder, FusableImageEncoder) else encoder


def as_rgb_uint8(image: npt.ArrayLike) -> UInt8Image:
    """Validate an ``HxWx3`` uint8 image (grey ``HxW`` and RGBA are converted)."""
    arr = np.asarray(image)
    if arr.dtype != np.uint8:
        raise ValueError(f"image must be uint8 RGB, got dtype {arr.dtype}")
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    if arr.ndim != 3 or arr.shape[2] not in (3, 4):
        raise ValueError(f"image must be HxWx3, got shape {arr.shape}")
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"image is empty: shape {arr.shape}")
    return np.ascontiguousarray(arr[:, :, :3])


def crop_box(
    image: npt.ArrayLike, box_xywh: Sequence[float], *, margin: float = 0.1, square: bool = True
) -> UInt8Image:
    """The ROI ``box_xywh`` (pixels) cut from ``image`` with some context, clipped to the image.

    ``margin`` grows each side by that fraction of the box; ``square`` grows the short side so the
    classifier's centre crop does not cut the object off. Boxes partly outside the image are
    clipped; a box entirely outside is an error (it names the box).
    """
    img = as_rgb_uint8(image)
    h, w = img.shape[:2]
    x, y, bw, bh = (float(v) for v in box_xywh)
    if bw <= 0 or bh <= 0:
        raise ValueError(f"box {tuple(box_xywh)} has no area")
    cx, cy = x + bw / 2.0, y + bh / 2.0
    half_w, half_h = bw * (1 + 2 * margin) / 2.0, bh * (1 + 2 * margin) / 2.0
    if square:
        half_w = half_h = max(half_w, half_h)
    x0, x1 = int(max(0, np.floor(cx - half_w))), int(min(w, np.ceil(cx + half_w)))
    y0, y1 = int(max(0, np.floor(cy - half_h))), int(min(h, np.ceil(cy + half_h)))
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"box {tuple(box_xywh)} lies outside the {w}x{h} image")
    return img[y0:y1, x0:x1]


def resize_center_crop(
    crop: UInt8Image, size: int = 224, resize: int = 256
) -> UInt8Image:
    """ImageNet evaluation transform: short side to ``resize`` (bicubic), centre ``size`` crop.

    PIL bicubic is what the classifier was validated with here (195/218 top-1 on the shared images,
    193 with bilinear).
    """
    from PIL import Image

    img = Image.fromarray(as_rgb_uint8(crop))
    w, h = img.size
    scale = resize / min(w, h)
    nw, nh = max(size, round(w * scale)), max(size, round(h * scale))
    img = img.resize((nw, nh), Image.Resampling.BICUBIC)
    left, top = (nw - size) // 2, (nh - size) // 2
    return np.asarray(img.crop((left, top, left + size, top + size)), dtype=np.uint8)  # [S, S, 3]


def resize_fit(crop: UInt8Image, size: int = 224) -> UInt8Image:
    """The whole crop resized to ``size`` x ``size`` (bicubic): for square ROI crops that already
    carry their context, where a centre crop would cut the object's ends off."""
    from PIL import Image

    img = Image.fromarray(as_rgb_uint8(crop)).resize((size, size), Image.Resampling.BICUBIC)
    return np.asarray(img, dtype=np.uint8)  # [S, S, 3]


def load_image(path: str) -> UInt8Image:
    """An image file as ``HxWx3`` uint8 RGB."""
    from PIL import Image

    with Image.open(path) as img:
        return np.asarray(img.convert("RGB"), dtype=np.uint8)
