"""The bytes a camera's frame travels as (PNG, ``.npy``, base64), for the tests of ``craft
perceive`` and ``POST /perceive``: written once, so both send frames the same way."""

from __future__ import annotations

import base64
import io

import numpy as np


def b64(data: bytes) -> str:
    """Base64 text of ``data``, as a JSON body carries it."""
    return base64.b64encode(data).decode("ascii")


def png_bytes(array: np.ndarray) -> bytes:
    """``array`` (H x W x 3 uint8, or H x W of a PNG's grey modes) as a PNG file's bytes."""
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(array).save(out, format="PNG")
    return out.getvalue()


def npy_bytes(array: np.ndarray) -> bytes:
    """``array`` as a ``.npy`` file's bytes (no pickle)."""
    out = io.BytesIO()
    np.save(out, array, allow_pickle=False)
    return out.getvalue()
