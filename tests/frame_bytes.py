"""The bytes a camera's frame travels as (PNG, ``.npy``, base64), for the tests of ``craft
perceive`` and ``POST /perceive``: written once, so both send frames the same way; and the
synthetic frames' camera pose."""

from __future__ import annotations

import base64
import io

import numpy as np

#: the testbed camera's pose: 0.7 m above (0.375, 0), looking straight down, world z up; a pixel's
#: world x is 0.375 less its camera y, its world y minus its camera x
OVERHEAD_POSE = [[0.0, -1.0, 0.0, 0.375], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.7], [0.0, 0.0, 0.0, 1.0]]


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
