"""Embedding pass: text embeddings for verbs, verb queries, objects and properties.

Embeddings are cached by (encoder id, text) under ``artifacts/cache/embeddings/<encoder>/`` as
``.npy`` files, so changing one verb re-embeds only its own texts; the encoder is loaded only
when something is missing.

Each folder keeps an index (``INDEX.tsv``, see ``compiler/cache.py``) binding every file to its
phrase and to its vector's bytes: the file name only hashes the phrase, so without it two
swapped files would be used silently. A file the index does not list (an older cache) is
re-embedded; one that contradicts its entry is an error naming the file.
"""

from __future__ import annotations

import hashlib
import io
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ..files import atomic_write_bytes
from ..runtime.encoders.text import load_text_encoder
from .cache import EmbeddingIndex, embedding_digest

FloatArray = npt.NDArray[np.float32]
#: Embeddings added to ``INDEX.tsv`` per rewrite of it.
INDEX_BATCH = 1024


class EmbeddingCache:
    """``<root>/<encoder_id>/<sha256(text)>.npy``, one unit vector per file."""

    def __init__(self, root: Path, encoder_id: str) -> None:
        self.folder = root / encoder_id
        self.index = EmbeddingIndex(self.folder)
        self.encoder_id = encoder_id
        self.hits = 0
        self.misses = 0

    def _path(self, text: str) -> Path:
        return self.folder / f"{hashlib.sha256(text.encode()).hexdigest()}.npy"

    def embed(self, texts: list[str], progress: Callable[[int], None] | None = None) -> FloatArray:
        """Embeddings for ``texts`` (``[N, d]``), computing only the ones not cached."""
        found: dict[str, FloatArray] = {}
        missing: list[str] = []
        entries = self.index.read()
        for text in dict.fromkeys(texts):
            path = self._path(text)
            if path.is_file():
                data = path.read_bytes()
                if self.index.check(path, text, data, entries.get(path.name)):
                    found[text] = np.load(io.BytesIO(data), allow_pickle=False)
                    continue
            missing.append(text)
        self.hits += len(found)
        self.misses += len(missing)
        if missing:
            encoder = load_text_encoder(self.encoder_id)
            # The index is rewritten whole on each add, so entries go in batches (a rewrite per
            # 16 texts was quadratic: minutes at 10,000 objects). Files written but not yet
            # indexed when a build dies are simply re-embedded by the next one.
            added: dict[str, tuple[str, str]] = {}
            try:
                for start in range(0, len(missing), 16):
                    chunk = missing[start : start + 16]
                    vectors = encoder.embed(chunk)  # [len(chunk), d]
                    for text, vec in zip(chunk, vectors, strict=True):
                        buffer = io.BytesIO()
                        np.save(buffer, vec.astype(np.float32), allow_pickle=False)
                        path = self._path(text)
                        atomic_write_bytes(path, buffer.getvalue())
                        added[path.name] = (embedding_digest(text, buffer.getvalue()), text)
                        found[text] = vec
                    if len(added) >= INDEX_BATCH:
                        self.index.add(added)
                        added = {}
                    if progress is not None:
                        progress(len(chunk))
            finally:
                self.index.add(added)
        if not texts:
            return np.zeros((0, 0), dtype=np.float32)
        return np.stack([found[t] for t in texts]).astype(np.float32)
