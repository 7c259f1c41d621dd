"""Embedding pass: text embeddings for verbs, verb queries, objects and properties.

Embeddings are cached by (encoder id, text) under ``artifacts/cache/embeddings/<encoder>/`` as
``.npy`` files, so changing one verb re-embeds only its own texts; the encoder is loaded only
when something is missing.
"""

from __future__ import annotations

import hashlib
import io
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt

from craft_e.compiler.cache import atomic_write_bytes
from craft_e.runtime.encoders.text import load_text_encoder

FloatArray = npt.NDArray[np.float32]


class EmbeddingCache:
    """``<root>/<encoder_id>/<sha256(text)>.npy``, one unit vector per file."""

    def __init__(self, root: Path, encoder_id: str) -> None:
        self.folder = root / encoder_id
        self.encoder_id = encoder_id
        self.hits = 0
        self.misses = 0

    def _path(self, text: str) -> Path:
        return self.folder / f"{hashlib.sha256(text.encode()).hexdigest()}.npy"

    def embed(self, texts: list[str], progress: Callable[[int], None] | None = None) -> FloatArray:
        """Embeddings for ``texts`` (``[N, d]``), computing only the ones not cached."""
        found: dict[str, FloatArray] = {}
        missing: list[str] = []
        for text in dict.fromkeys(texts):
            path = self._path(text)
            if path.is_file():
                found[text] = np.load(path, allow_pickle=False)
            else:
                missing.append(text)
        self.hits += len(found)
        self.misses += len(missing)
        if missing:
            encoder = load_text_encoder(self.encoder_id)
            for start in range(0, len(missing), 16):
                chunk = missing[start : start + 16]
                vectors = encoder.embed(chunk)  # [len(chunk), d]
                for text, vec in zip(chunk, vectors, strict=True):
                    buffer = io.BytesIO()
                    np.save(buffer, vec.astype(np.float32), allow_pickle=False)
                    atomic_write_bytes(self._path(text), buffer.getvalue())
                    found[text] = vec
                if progress is not None:
                    progress(len(chunk))
        if not texts:
            return np.zeros((0, 0), dtype=np.float32)
        return np.stack([found[t] for t in texts]).astype(np.float32)
