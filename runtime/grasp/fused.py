"""GR-ConvNet rewritten for inference on CPU: the same function, fewer and faster operations.

Why: the robot's grasp-network pass over a scene's window (~430 x 500 px at native scale) is
most of its perception time, and the checkpoint's layer layout is not what a CPU runs fastest.
Every rewrite below is exact in real arithmetic; in float32 the maps differ from
``GenerativeResnet``'s by rounding only (``tests/test_grasp_fused.py``: < 1e-5 on the reference
input/output file and on random inputs of several sizes):

* batch norm (eval mode: a per-channel affine map) folded into the convolution before it;
* channels-last tensors throughout (oneDNN's fast layout: the 4-channel 9x9 input conv runs
  ~5x faster than in NCHW);
* each stride-2 transposed conv (4x4 kernel) as one ordinary 2x2 conv with four output phases
  per channel, then a pixel shuffle and a crop (polyphase decomposition): no zero-stuffed input;
* the last transposed conv (stride 1, 9x9, no activation after it) and the four linear 2x2 heads
  composed into one 16 -> 4 conv with a 10x10 kernel: a third of the multiply-adds.

The evaluation keeps ``GenerativeResnet`` (its published results are bit-for-bit reproducible);
the robot's own path (``sim.choose``) runs this module.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import torch
import torch.nn.functional as F
from torch import nn

from .base import GraspMaps, GraspNet, Modality
from .grconvnet import GenerativeResnet, ResidualBlock

_CL = torch.channels_last


def _first(value: tuple[int, ...] | str) -> int:
    """First entry of a conv's ``padding``/``output_padding`` (never a string here)."""
    if isinstance(value, str):
        raise ValueError(f"explicit padding expected, got {value!r}")
    return int(value[0])


def fold_batchnorm(
    weight: torch.Tensor, bias: torch.Tensor | None, bn: nn.BatchNorm2d, *, transposed: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """``bn(conv(x))`` as one conv: weight and bias scaled per output channel (dim 1 of a
    transposed conv's ``[C_in, C_out, k, k]`` weight, dim 0 of an ordinary one)."""
    assert bn.running_mean is not None and bn.running_var is not None
    scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)  # [C_out]
    shift = bn.bias - bn.running_mean * scale
    shape = (1, -1, 1, 1) if transposed else (-1, 1, 1, 1)
    b = shift if bias is None else bias * scale + shift
    return weight * scale.view(shape), b


def polyphase_weight(weight: torch.Tensor) -> torch.Tensor:
    """A stride-2 transposed conv's ``[C_in, C_out, 4, 4]`` weight as an ordinary conv weight
    ``[4 C_out, C_in, 2, 2]`` (output channel ``4 c + 2 r_y + r_x``: channel ``c``, phase
    ``(r_y, r_x)``, the order ``pixel_shuffle`` expects).

    Without padding, output row ``2 m + r`` of the transposed conv is
    ``x[m] w[r] + x[m - 1] w[r + 2]``: a 2-tap correlation over ``x`` padded by one, taps
    ``(w[r + 2], w[r])``; the same holds per column.
    """
    c_in, c_out, k, k2 = weight.shape
    if (k, k2) != (4, 4):
        raise ValueError(f"polyphase_weight needs a 4x4 kernel, got {k}x{k2}")
    out = weight.new_zeros(c_out, 2, 2, c_in, 2, 2)  # [c, r_y, r_x, C_in, a, b]
    for ry in range(2):
        for rx in range(2):
            for a in range(2):
                for b in range(2):
                    out[:, ry, rx, :, a, b] = weight[:, :, ry + 2 * (1 - a), rx + 2 * (1 - b)].t()
    return out.reshape(c_out * 4, c_in, 2, 2)


def merged_head(conv6: nn.ConvTranspose2d, heads: list[nn.Conv2d]) -> tuple[torch.Tensor, torch.Tensor, int]:
    """``[head(conv6(x)) for head in heads]`` as one conv: (weight ``[n_heads, C, k+1, k+1]``,
    bias, padding). A stride-1 transposed conv is an ordinary conv with the kernel flipped and
    its channel axes swapped (same padding here: ``k - 1 - p`` with ``k = 9``, ``p = 4``); two
    linear convs in a row are one conv whose kernel is their kernels' full convolution."""
    k = conv6.kernel_size[0]
    pad = k - 1 - _first(conv6.padding)
    if conv6.stride != (1, 1) or conv6.output_padding != (0, 0) or conv6.bias is None:
        raise ValueError("merged_head needs a stride-1 transposed conv with bias")
    w6 = conv6.weight.flip(-1, -2).transpose(0, 1)  # [C_out, C_in, k, k] as an ordinary conv
    wh = torch.cat([h.weight for h in heads])  # [n, C_out, 2, 2]
    bh = torch.cat([h.bias if h.bias is not None else h.weight.new_zeros(1) for h in heads])  # [n]
    kh = wh.shape[-1]
    w = w6.new_zeros(wh.shape[0], w6.shape[1], k + kh - 1, k + kh - 1)
    for a in range(kh):
        for b in range(kh):
            w[:, :, a : a + k, b : b + k] += torch.einsum("hc,cikl->hikl", wh[:, :, a, b], w6)
    bias = bh + torch.einsum("hcab,c->h", wh, conv6.bias)
    return w, bias, pad


class _Conv(nn.Module):
    """Conv (+ folded batch norm) (+ ReLU, in place), channels-last."""

    def __init__(self, conv: nn.Conv2d, bn: nn.BatchNorm2d, relu: bool = True) -> None:
        super().__init__()
        w, b = fold_batchnorm(conv.weight, conv.bias, bn)
        self.weight = nn.Parameter(w.contiguous(memory_format=_CL), requires_grad=False)
        self.bias = nn.Parameter(b, requires_grad=False)
        self.stride = conv.stride
        self.padding = conv.padding
        self.relu = relu

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.conv2d(x, self.weight, self.bias, self.stride, self.padding)
        return torch.relu_(y) if self.relu else y


class _Residual(nn.Module):
    """``ResidualBlock``: two folded convs plus the identity (added in place)."""

    def __init__(self, block: ResidualBlock) -> None:
        super().__init__()
        self.conv1 = _Conv(block.conv1, block.bn1)
        self.conv2 = _Conv(block.conv2, block.bn2, relu=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out: torch.Tensor = self.conv2(self.conv1(x)).add_(x)
        return out


class _Up(nn.Module):
    """Stride-2 transposed conv (4x4) + folded batch norm + ReLU, polyphase."""

    def __init__(self, conv: nn.ConvTranspose2d, bn: nn.BatchNorm2d) -> None:
        super().__init__()
        if conv.stride != (2, 2) or conv.kernel_size != (4, 4) or conv.groups != 1:
            raise ValueError("_Up needs a stride-2 4x4 transposed conv")
        w, b = fold_batchnorm(conv.weight, conv.bias, bn, transposed=True)
        self.weight = nn.Parameter(polyphase_weight(w).contiguous(memory_format=_CL), requires_grad=False)
        self.bias = nn.Parameter(b.repeat_interleave(4), requires_grad=False)
        self.padding = _first(conv.padding)
        self.output_padding = _first(conv.output_padding)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        y = F.pixel_shuffle(F.conv2d(x, self.weight, self.bias, padding=1), 2)  # [B, C, 2h+2, 2w+2]
        p = self.padding
        out_h = 2 * h + 2 - 2 * p + self.output_padding  # the transposed conv's output size
        out_w = 2 * w + 2 - 2 * p + self.output_padding
        return torch.relu_(y[..., p : p + out_h, p : p + out_w])


class FusedGenerativeResnet(GraspNet):
    """``GenerativeResnet``'s function for inference (see the module docstring); build it with
    ``from_reference``. Parameters are frozen."""

    input_size: ClassVar[int] = GenerativeResnet.input_size
    modality: ClassVar[Modality] = GenerativeResnet.modality

    def __init__(self, ref: GenerativeResnet) -> None:
        super().__init__()
        self.conv1 = _Conv(ref.conv1, ref.bn1)
        self.conv2 = _Conv(ref.conv2, ref.bn2)
        self.conv3 = _Conv(ref.conv3, ref.bn3)
        self.res = nn.Sequential(*(_Residual(r) for r in (ref.res1, ref.res2, ref.res3, ref.res4, ref.res5)))
        self.conv4 = _Up(ref.conv4, ref.bn4)
        self.conv5 = _Up(ref.conv5, ref.bn5)
        w, b, pad = merged_head(ref.conv6, [ref.pos_output, ref.cos_output, ref.sin_output, ref.width_output])
        self.head_weight = nn.Parameter(w.contiguous(memory_format=_CL), requires_grad=False)
        self.head_bias = nn.Parameter(b, requires_grad=False)
        self.head_padding = pad

    @classmethod
    def from_state_dict(cls, state: Mapping[str, torch.Tensor]) -> FusedGenerativeResnet:
        ref = GenerativeResnet.from_state_dict(state)
        ref.eval()
        return cls.from_reference(ref)

    @classmethod
    def from_reference(cls, ref: GenerativeResnet) -> FusedGenerativeResnet:
        """The fused network of a loaded ``GenerativeResnet`` (in eval mode: batch-norm
        statistics, not batch statistics, are folded)."""
        with torch.no_grad():
            return cls(ref).eval()

    def forward(self, x: torch.Tensor) -> GraspMaps:
        x = self.conv3(self.conv2(self.conv1(x.contiguous(memory_format=_CL))))  # [B, 4C, H/4, W/4]
        x = self.conv5(self.conv4(self.res(x)))  # [B, C, H+1, W+1]
        y = F.conv2d(x, self.head_weight, self.head_bias, padding=self.head_padding).contiguous()  # [B, 4, H, W]
        return GraspMaps(y[:, 0:1], y[:, 1:2], y[:, 2:3], y[:, 3:4])


def fused(model: GraspNet) -> GraspNet:
    """The inference rewrite of ``model`` where there is one (GR-ConvNet), else ``model``."""
    if isinstance(model, GenerativeResnet):
        return FusedGenerativeResnet.from_reference(model)
    return model
