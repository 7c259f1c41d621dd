"""EfficientNet-Lite (Lite0, Lite1) rewritten for inference on CPU: the same logits, faster operations.

Why: the robot embeds every ROI crop of a scene (~4.5 crops) before it can ground, and the
checkpoint's layer layout (conv, then batch norm, then ReLU6, each a pass over memory; TF "same"
padding as a zero-filled copy) is not what a CPU runs fastest. Each rewrite is exact in real
arithmetic; in float32 the logits differ from ``EfficientNetLite``'s by rounding only
(``tests/test_encoders_fused.py``: < 1e-5 on the ConSE embeddings):

* batch norm (eval mode: a per-channel affine map) folded into the conv before it, ReLU6 in
  place;
* channels-last tensors; 1x1 convs (expand, project, head) as one matrix product over pixels;
* TF "same" padding of a stride-2 conv pads one pixel more at the bottom/right than at the
  top/left (``lo = hi - 1``): a (k+1)x(k+1) kernel whose first row and column are zero, with
  symmetric padding ``hi``, reads exactly the same pixels with the same weights, without the
  padded copy of the input.

The evaluation keeps ``EfficientNetLite`` (its published results are bit-for-bit
reproducible); the robot's own path (``sim.choose``) runs this module.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from .efficientnet import EfficientNetLite, MBConvBlock, SameConv2d

_CL = torch.channels_last


def same_padding(size: int, kernel: int, stride: int) -> tuple[int, int]:
    """TensorFlow "same" padding (before, after) of one axis, as ``SameConv2d`` pads it."""
    pad = max((math.ceil(size / stride) - 1) * stride + kernel - size, 0)
    return pad // 2, pad - pad // 2


class _FusedConv(nn.Module):
    """``relu6?(bn(SameConv2d(x)))`` for inputs of one fixed spatial size, channels-last."""

    def __init__(self, conv: SameConv2d, bn: nn.BatchNorm2d, act: bool, size: int) -> None:
        super().__init__()
        assert bn.running_mean is not None and bn.running_var is not None
        scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
        weight = conv.weight * scale.view(-1, 1, 1, 1)
        self.bias = nn.Parameter(bn.bias - bn.running_mean * scale, requires_grad=False)
        self.stride = conv.stride[0]
        self.groups = conv.groups
        self.act = act
        self.size = size
        k = weight.shape[-1]
        lo, hi = same_padding(size, k, self.stride)
        self.pointwise = k == 1 and self.stride == 1 and conv.groups == 1
        self.pre_pad: list[int] | None = None
        if self.pointwise:
            weight = weight[:, :, 0, 0]  # [C_out, C_in]
            self.padding = 0
        elif lo == hi:
            self.padding = lo
        elif lo == hi - 1 and conv.groups > 1:
            weight = F.pad(weight, [1, 0, 1, 0])  # zero first row and column: reads from lo - 1
            self.padding = hi
        else:  # the 3-channel stem: a padded copy of the input is cheap
            self.padding = 0
            self.pre_pad = [lo, hi, lo, hi]
        self.weight = nn.Parameter(weight.contiguous() if self.pointwise else weight.contiguous(memory_format=_CL),
                                   requires_grad=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[-1] != self.size or x.shape[-2] != self.size:
            raise ValueError(f"built for {self.size}x{self.size} inputs, got {tuple(x.shape[-2:])}")
        if self.pointwise:  # [B, C, H, W] channels-last is [B, H, W, C] in memory
            y: torch.Tensor = F.linear(x.permute(0, 2, 3, 1), self.weight, self.bias).permute(0, 3, 1, 2)
        else:
            if self.pre_pad is not None:
                x = F.pad(x, self.pre_pad)
            y = F.conv2d(x, self.weight, self.bias, self.stride, self.padding, 1, self.groups)
        return y.clamp_(0.0, 6.0) if self.act else y


class _FusedBlock(nn.Module):
    """``MBConvBlock`` of one input size."""

    def __init__(self, block: MBConvBlock, size: int) -> None:
        super().__init__()
        self.expand = _FusedConv(block._expand_conv, block._bn0, True, size) if block.expand != 1 else None
        self.depthwise = _FusedConv(block._depthwise_conv, block._bn1, True, size)
        self.out_size = math.ceil(size / block._depthwise_conv.stride[0])
        self.project = _FusedConv(block._project_conv, block._bn2, False, self.out_size)
        self.skip = block.skip

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y: torch.Tensor = self.expand(x) if self.expand is not None else x
        y = self.project(self.depthwise(y))
        return y.add_(x) if self.skip else y


class FusedEfficientNetLite(nn.Module):
    """``EfficientNetLite``'s logits ``[B, 1000]`` for ``[B, 3, size, size]`` inputs (the
    paddings are fixed for one input size: the classifier's own, as ``ConSEImageEncoder`` passes it)."""

    def __init__(self, ref: EfficientNetLite, size: int = 224) -> None:
        super().__init__()
        self.size = size
        self.stem = _FusedConv(ref._conv_stem, ref._bn0, True, size)
        s = math.ceil(size / ref._conv_stem.stride[0])
        blocks: list[_FusedBlock] = []
        for block in ref._blocks:
            assert isinstance(block, MBConvBlock)
            blocks.append(_FusedBlock(block, s))
            s = blocks[-1].out_size
        self.blocks = nn.ModuleList(blocks)
        self.head = _FusedConv(ref._conv_head, ref._bn1, True, s)
        self.fc = ref._fc

    @classmethod
    def from_reference(cls, ref: EfficientNetLite, size: int = 224) -> FusedEfficientNetLite:
        """The fused network of a loaded ``EfficientNetLite`` in eval mode (its batch-norm
        statistics are folded); parameters are frozen."""
        with torch.no_grad():
            model = cls(ref, size).eval()
        model.requires_grad_(False)
        return model

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.stem(x.contiguous(memory_format=_CL))  # [B, 32, S/2, S/2]
        for block in self.blocks:
            x = block(x)  # ... -> [B, 320, S/32, S/32]
        x = self.head(x)  # [B, 1280, S/32, S/32]
        logits: torch.Tensor = self.fc(x.mean(dim=(2, 3)))  # [B, 1000]
        return logits
