"""CLIP ViT-B/32 (the paper's encoder): vision and text towers, BPE tokenizer, checked loading.

No CLIP weights can be obtained on the project's machines (see shared/README.md), so this code path
cannot be exercised for accuracy here; it is kept so a user who has the weights can run the
paper's configuration. The user supplies the weights file and its sha256:

* a torch state dict (``.pt``/``.pth``, plain or OpenAI's TorchScript archive) or ``.safetensors``
  with OpenAI CLIP key names (``visual.conv1.weight``, ``transformer.resblocks.0.attn...``);
* or ONNX exports of the towers, run with ``onnxruntime`` when it is installed;
* and, for the text tower, OpenAI's BPE merges file (``bpe_simple_vocab_16e6.txt.gz``).

Shapes and errors are tested with small random-init configs of the same architecture. A bundle
built for CLIP carries text encoder id ``clip-vit-b32``; the runtime refuses to mix it with MiniLM.
"""

from __future__ import annotations

import gzip
import html
import importlib
import re
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import torch
from torch import nn

from ...files import sha256_file
from .image import FloatArray, UInt8Image, resize_center_crop
from .text import EncoderError, TextEncoderSpec

CLIP_ID = "clip-vit-b32"
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
# OpenAI's TorchScript state dicts carry these scalars; they are not parameters.
_NON_PARAM_KEYS = ("input_resolution", "context_length", "vocab_size")


@dataclass(frozen=True)
class ClipConfig:
    """Architecture hyperparameters; ``vit_b32()`` is the paper's model."""

    embed_dim: int = 512
    image_resolution: int = 224
    vision_layers: int = 12
    vision_width: int = 768
    vision_patch_size: int = 32
    context_length: int = 77
    vocab_size: int = 49408
    transformer_width: int = 512
    transformer_heads: int = 8
    transformer_layers: int = 12

    @property
    def vision_heads(self) -> int:
        return self.vision_width // 64 if self.vision_width >= 64 else 1

    @classmethod
    def vit_b32(cls) -> ClipConfig:
        return cls()

    @classmethod
    def from_state_dict(cls, state: Mapping[str, torch.Tensor]) -> ClipConfig:
        """Hyperparameters read from tensor shapes (as OpenAI's ``build_model`` does)."""
        try:
            conv = state["visual.conv1.weight"]
            grid = round((state["visual.positional_embedding"].shape[0] - 1) ** 0.5)
            width = state["ln_final.weight"].shape[0]
            return cls(
                embed_dim=int(state["text_projection"].shape[1]),
                image_resolution=int(conv.shape[-1] * grid),
                vision_layers=len({k.split(".")[3] for k in state
                                   if k.startswith("visual.transformer.resblocks.")}),
                vision_width=int(conv.shape[0]),
                vision_patch_size=int(conv.shape[-1]),
                context_length=int(state["positional_embedding"].shape[0]),
                vocab_size=int(state["token_embedding.weight"].shape[0]),
                transformer_width=int(width),
                transformer_heads=max(1, int(width) // 64),
                transformer_layers=len({k.split(".")[2] for k in state
                                        if k.startswith("transformer.resblocks.")}),
            )
        except KeyError as exc:
            raise EncoderError(f"not a CLIP state dict: tensor {exc.args[0]!r} is missing") from None


class QuickGELU(nn.Module):
    """CLIP's activation: x * sigmoid(1.702 x)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * torch.sigmoid(1.702 * x)


class ResidualAttentionBlock(nn.Module):
    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        self.attn = nn.MultiheadAttention(width, heads, batch_first=True)
        self.ln_1 = nn.LayerNorm(width)
        self.mlp = nn.Sequential(OrderedDict([
            ("c_fc", nn.Linear(width, width * 4)), ("gelu", QuickGELU()), ("c_proj", nn.Linear(width * 4, width)),
        ]))
        self.ln_2 = nn.LayerNorm(width)

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        h = self.ln_1(x)  # [B, L, W]
        x = x + self.attn(h, h, h, need_weights=False, attn_mask=mask)[0]
        out: torch.Tensor = x + self.mlp(self.ln_2(x))
        return out


class Transformer(nn.Module):
    def __init__(self, width: int, layers: int, heads: int) -> None:
        super().__init__()
        self.resblocks = nn.ModuleList([ResidualAttentionBlock(width, heads) for _ in range(layers)])

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        for block in self.resblocks:
            x = block(x, mask)
        return x


class VisionTransformer(nn.Module):
    """``[B, 3, R, R]`` normalized pixels -> ``[B, embed_dim]`` (not normalized)."""

    def __init__(self, cfg: ClipConfig) -> None:
        super().__init__()
        w, p = cfg.vision_width, cfg.vision_patch_size
        grid = cfg.image_resolution // p
        scale = w**-0.5
        self.conv1 = nn.Conv2d(3, w, kernel_size=p, stride=p, bias=False)
        self.class_embedding = nn.Parameter(scale * torch.randn(w))
        self.positional_embedding = nn.Parameter(scale * torch.randn(grid * grid + 1, w))
        self.ln_pre = nn.LayerNorm(w)
        self.transformer = Transformer(w, cfg.vision_layers, cfg.vision_heads)
        self.ln_post = nn.LayerNorm(w)
        self.proj = nn.Parameter(scale * torch.randn(w, cfg.embed_dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.conv1(x)  # [B, W, g, g]
        x = x.flatten(2).transpose(1, 2)  # [B, g*g, W]
        cls = self.class_embedding.to(x.dtype).expand(x.shape[0], 1, -1)  # [B, 1, W]
        x = torch.cat([cls, x], dim=1) + self.positional_embedding  # [B, g*g+1, W]
        x = self.transformer(self.ln_pre(x))
        out: torch.Tensor = self.ln_post(x[:, 0]) @ self.proj  # [B, D]
        return out


class ClipModel(nn.Module):
    """Both towers with OpenAI's parameter names, so their state dicts load unchanged."""

    def __init__(self, cfg: ClipConfig) -> None:
        super().__init__()
        self.config = cfg
        self.visual = VisionTransformer(cfg)
        self.transformer = Transformer(cfg.transformer_width, cfg.transformer_layers, cfg.transformer_heads)
        self.token_embedding = nn.Embedding(cfg.vocab_size, cfg.transformer_width)
        self.positional_embedding = nn.Parameter(0.01 * torch.randn(cfg.context_length, cfg.transformer_width))
        self.ln_final = nn.LayerNorm(cfg.transformer_width)
        self.text_projection = nn.Parameter(cfg.transformer_width**-0.5 * torch.randn(cfg.transformer_width, cfg.embed_dim))
        self.logit_scale = nn.Parameter(torch.tensor(float(np.log(1 / 0.07))))
        causal = torch.full((cfg.context_length, cfg.context_length), float("-inf")).triu(1)
        self.register_buffer("attn_mask", causal, persistent=False)

    def encode_image(self, pixels: torch.Tensor) -> torch.Tensor:
        """``[B, 3, R, R]`` -> ``[B, D]``."""
        out: torch.Tensor = self.visual(pixels)
        return out

    def encode_text(self, tokens: torch.Tensor) -> torch.Tensor:
        """``[B, L]`` token ids (end-of-text has the largest id) -> ``[B, D]``."""
        length = tokens.shape[1]
        x = self.token_embedding(tokens) + self.positional_embedding[:length]  # [B, L, W]
        mask: torch.Tensor = self.attn_mask[:length, :length]  # type: ignore[index]
        x = self.ln_final(self.transformer(x, mask))
        eot = x[torch.arange(x.shape[0]), tokens.argmax(dim=-1)]  # [B, W]
        out: torch.Tensor = eot @ self.text_projection  # [B, D]
        return out


# ---------------------------------------------------------------------------------------------
# Tokenizer (OpenAI's simple BPE; ftfy's text repair is omitted, html unescaping is kept)


@lru_cache
def _bytes_to_unicode() -> dict[int, str]:
    bs = list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1)) + list(range(ord("®"), ord("ÿ") + 1))
    cs = bs[:]
    n = 0
    for b in range(256):
        if b not in bs:
            bs.append(b)
            cs.append(256 + n)
            n += 1
    return dict(zip(bs, [chr(c) for c in cs], strict=True))


def _token_pattern() -> Any:
    try:
        regex = importlib.import_module("regex")  # \p{L}/\p{N} classes; optional dependency
        return regex.compile(r"""<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+""",
                             regex.IGNORECASE)
    except ImportError:  # ``re`` has no \p{..}; letters = word chars minus digits and underscore
        return re.compile(r"""<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[^\W\d_]+|\d|[^\s\w]+|_+""",
                          re.IGNORECASE)


class ClipTokenizer:
    """BPE over bytes with ``</w>`` word ends; ``<|startoftext|>`` / ``<|endoftext|>`` specials."""

    def __init__(self, bpe_path: Path, max_merges: int = 49152 - 256 - 2) -> None:
        if not bpe_path.is_file():
            raise EncoderError(f"{bpe_path}: CLIP BPE merges file not found (bpe_simple_vocab_16e6.txt.gz)")
        raw = gzip.decompress(bpe_path.read_bytes()) if bpe_path.suffix == ".gz" else bpe_path.read_bytes()
        lines = raw.decode("utf-8").split("\n")[1 : max_merges + 1]
        merges = [tuple(line.split()) for line in lines if len(line.split()) == 2]
        vocab = list(_bytes_to_unicode().values())
        vocab = vocab + [v + "</w>" for v in vocab] + ["".join(m) for m in merges]
        vocab += ["<|startoftext|>", "<|endoftext|>"]
        self.encoder = {tok: i for i, tok in enumerate(vocab)}
        self.bpe_ranks = {m: i for i, m in enumerate(merges)}
        self.byte_encoder = _bytes_to_unicode()
        self.pattern = _token_pattern()
        self.sot, self.eot = self.encoder["<|startoftext|>"], self.encoder["<|endoftext|>"]
        self._cache: dict[str, str] = {}

    @property
    def vocab_size(self) -> int:
        return len(self.encoder)

    def _bpe(self, token: str) -> str:
        if token in self._cache:
            return self._cache[token]
        word: tuple[str, ...] = (*token[:-1], token[-1] + "</w>")
        while len(word) > 1:
            pairs = {(word[i], word[i + 1]) for i in range(len(word) - 1)}
            best = min(pairs, key=lambda p: self.bpe_ranks.get(p, 1 << 30))
            if best not in self.bpe_ranks:
                break
            merged: list[str] = []
            i = 0
            while i < len(word):
                if i < len(word) - 1 and (word[i], word[i + 1]) == best:
                    merged.append(word[i] + word[i + 1])
                    i += 2
                else:
                    merged.append(word[i])
                    i += 1
            word = tuple(merged)
        out = " ".join(word)
        self._cache[token] = out
        return out

    def encode(self, text: str) -> list[int]:
        text = re.sub(r"\s+", " ", html.unescape(html.unescape(text))).strip().lower()
        ids: list[int] = []
        for token in self.pattern.findall(text):
            mapped = "".join(self.byte_encoder[b] for b in token.encode("utf-8"))
            ids.extend(self.encoder[piece] for piece in self._bpe(mapped).split(" "))
        return ids

    def tokenize(self, texts: Sequence[str], context_length: int = 77) -> torch.Tensor:
        """``[N, context_length]`` int64, zero-padded; too long texts are cut, keeping the EOT."""
        out = torch.zeros(len(texts), context_length, dtype=torch.long)
        for i, text in enumerate(texts):
            ids = [self.sot, *self.encode(text), self.eot]
            if len(ids) > context_length:
                ids = [*ids[: context_length - 1], self.eot]
            out[i, : len(ids)] = torch.tensor(ids)
        return out


# ---------------------------------------------------------------------------------------------
# Loading


def _verify(path: Path, sha256: str) -> None:
    if not path.is_file():
        raise EncoderError(f"{path}: CLIP weights not found; pass the path of your ViT-B/32 checkpoint")
    if not re.fullmatch(r"[0-9a-f]{64}", sha256 or ""):
        raise EncoderError(f"{path}: pass the expected sha256 of the weights (64 hex digits), got {sha256!r}")
    actual = sha256_file(path)
    if actual != sha256:
        raise EncoderError(f"{path}: sha256 {actual} is not the expected {sha256}; "
                           "the file is not the checkpoint you meant, or it is corrupt")


def _read_state_dict(path: Path) -> dict[str, torch.Tensor]:
    if path.suffix == ".safetensors":
        from safetensors.torch import load_file

        return dict(load_file(str(path)))
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # OpenAI's release is a TorchScript archive, not a pickle of tensors
        try:
            jit_load: Any = torch.jit.load
            obj = jit_load(str(path), map_location="cpu").state_dict()
        except Exception as exc:
            raise EncoderError(f"{path}: neither a torch state dict nor a TorchScript archive ({exc})") from None
    if isinstance(obj, dict) and "state_dict" in obj and isinstance(obj["state_dict"], dict):
        obj = obj["state_dict"]
    if not isinstance(obj, dict):
        raise EncoderError(f"{path}: expected a state dict, got {type(obj).__name__}")
    return {str(k): v for k, v in obj.items() if isinstance(v, torch.Tensor)}


def load_clip(weights: Path | str, sha256: str, *, config: ClipConfig | None = None) -> ClipModel:
    """A verified CLIP model in eval mode from a user-supplied state dict.

    ``config`` pins the architecture (the registry passes ViT-B/32); ``None`` reads it from the
    tensor shapes. Missing or unexpected tensors are an error naming the first few.
    """
    path = Path(weights)
    _verify(path, sha256)
    if path.suffix == ".onnx":
        raise EncoderError(f"{path}: an ONNX file; use load_clip_onnx (needs onnxruntime)")
    state = {k: v for k, v in _read_state_dict(path).items() if k not in _NON_PARAM_KEYS}
    cfg = config or ClipConfig.from_state_dict(state)
    with torch.device("meta"):  # expected names and shapes, without allocating the weights
        expected = {k: tuple(v.shape) for k, v in ClipModel(cfg).state_dict().items()}
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    wrong = [f"{k} {tuple(state[k].shape)} (expected {expected[k]})"
             for k in sorted(set(expected) & set(state)) if tuple(state[k].shape) != expected[k]]
    if missing or unexpected or wrong:
        raise EncoderError(f"{path}: not a CLIP {CLIP_ID} state dict: missing {missing[:5]}, "
                           f"unexpected {unexpected[:5]}, wrong shapes {wrong[:3]}")
    model = ClipModel(cfg)
    model.load_state_dict(state)
    model.float()
    return model.eval()


class OnnxTower:
    """One exported tower: its first input in, its first output out (``[N, D]``)."""

    def __init__(self, path: Path, sha256: str) -> None:
        _verify(path, sha256)
        try:
            onnxruntime = importlib.import_module("onnxruntime")
        except ImportError:
            raise EncoderError(f"{path}: running ONNX CLIP towers needs onnxruntime (pip install onnxruntime)") from None
        self.session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        self.input_name = self.session.get_inputs()[0].name

    def __call__(self, array: npt.NDArray[Any]) -> FloatArray:
        out = self.session.run(None, {self.input_name: array})[0]
        return np.asarray(out, dtype=np.float32)


def _normalize(x: npt.NDArray[Any]) -> FloatArray:
    v = np.asarray(x, dtype=np.float32)  # [N, D]
    out: FloatArray = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), np.float32(1e-12))
    return out


def clip_pixels(crops: Sequence[UInt8Image], resolution: int = 224) -> torch.Tensor:
    """CLIP preprocessing: short side to ``resolution`` (bicubic), centre crop, mean/std ->
    ``[N, 3, R, R]`` float32."""
    raw = np.stack([resize_center_crop(c, resolution, resolution) for c in crops])  # [N, R, R, 3] uint8
    scaled = raw.astype(np.float32) / np.float32(255.0)
    normed = ((scaled - np.asarray(CLIP_MEAN, np.float32)) / np.asarray(CLIP_STD, np.float32)).astype(np.float32)
    return torch.from_numpy(normed).permute(0, 3, 1, 2).contiguous()  # [N, 3, R, R]


class ClipImageEncoder:
    """CLIP vision tower as an ``ImageEncoder`` (text space ``clip-vit-b32``)."""

    text_encoder_id = CLIP_ID

    def __init__(self, model: ClipModel | OnnxTower, *, resolution: int = 224, dim: int = 512) -> None:
        self.model = model
        self.resolution = model.config.image_resolution if isinstance(model, ClipModel) else resolution
        self.dim = model.config.embed_dim if isinstance(model, ClipModel) else dim
        self.id = CLIP_ID

    def embed_images(self, crops: Sequence[UInt8Image], batch_size: int = 16) -> FloatArray:
        """``[N, D]`` unit vectors."""
        out = np.zeros((len(crops), self.dim), dtype=np.float32)
        for start in range(0, len(crops), max(1, batch_size)):
            pixels = clip_pixels(crops[start : start + batch_size], self.resolution)  # [B, 3, R, R]
            if isinstance(self.model, ClipModel):
                with torch.inference_mode():
                    emb = self.model.encode_image(pixels).numpy()
            else:
                emb = self.model(pixels.numpy())
            out[start : start + len(pixels)] = _normalize(emb)
        return out


class ClipTextEncoder:
    """CLIP text tower with the same ``embed(texts) -> [N, D]`` API as the MiniLM encoder."""

    def __init__(self, model: ClipModel | OnnxTower, tokenizer: ClipTokenizer, weights_sha256: str,
                 *, dim: int = 512, context_length: int = 77) -> None:
        self.model = model
        self.tokenizer = tokenizer
        self.context_length = model.config.context_length if isinstance(model, ClipModel) else context_length
        d = model.config.embed_dim if isinstance(model, ClipModel) else dim
        self.spec = TextEncoderSpec(CLIP_ID, d, weights_sha256)

    def embed(self, texts: list[str]) -> FloatArray:
        if not texts:
            return np.zeros((0, self.spec.dim), dtype=np.float32)
        tokens = self.tokenizer.tokenize(texts, self.context_length)  # [N, L]
        if isinstance(self.model, ClipModel):
            with torch.inference_mode():
                emb = self.model.encode_text(tokens).numpy()
        else:
            emb = self.model(tokens.numpy())
        return _normalize(emb)


def load_clip_image_encoder(weights: Path | str, sha256: str, *, config: ClipConfig | None = None) -> ClipImageEncoder:
    """Vision tower from a state dict (``.pt``/``.pth``/``.safetensors``) or an ONNX export."""
    path = Path(weights)
    if path.suffix == ".onnx":
        return ClipImageEncoder(OnnxTower(path, sha256))
    return ClipImageEncoder(load_clip(path, sha256, config=config))


def load_clip_text_encoder(weights: Path | str, sha256: str, bpe_path: Path | str,
                           *, config: ClipConfig | None = None) -> ClipTextEncoder:
    """Text tower + tokenizer (the BPE merges file is required)."""
    path = Path(weights)
    tokenizer = ClipTokenizer(Path(bpe_path))
    model: ClipModel | OnnxTower = OnnxTower(path, sha256) if path.suffix == ".onnx" else load_clip(path, sha256, config=config)
    return ClipTextEncoder(model, tokenizer, sha256)
