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
  composed into one 16 -> 4 conv with a 10x10 kernel: a third of the multiply-adds;
* that merged head run on the four phases of the polyphase conv5 (a 64 -> 16 6x6 conv at half
  resolution, which oneDNN runs much closer to peak than 4 output channels), so the
  full-resolution 16-channel feature map is never shuffled together.

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


def _phase_taps(offset: int, kernel: int) -> tuple[int, list[tuple[int, int, int, int]]]:
    """For a ``kernel``-tap correlation reading full-resolution row ``i + u + offset`` (tap
    ``u``), written per output phase ``q`` (``i = 2 M + q``) over the two input phases
    (row ``2 m + r``): the first low-resolution offset ``s_min`` and, per ``(q, u)``, the tuple
    ``(q, u, r, s - s_min)`` with ``m = M + s``."""
    taps = []
    for q in range(2):
        for u in range(kernel):
            t = q + u + offset
            taps.append((q, u, t % 2, t // 2))
    s_min = min(s for *_, s in taps)
    return s_min, [(q, u, r, s - s_min) for q, u, r, s in taps]


def phase_head_weight(weight: torch.Tensor, offset: int) -> tuple[torch.Tensor, int]:
    """A conv weight ``[n, C, K, K]`` applied to a full-resolution map as a conv over its four
    phases (channel ``4 c + 2 r_y + r_x`` holds ``x[c, 2 m + r_y, 2 n + r_x]``) giving the four
    output phases (channel ``4 o + 2 q_y + q_x``, the ``pixel_shuffle`` order). Tap ``u`` of
    output row ``i`` reads input row ``i + u + offset``. Returns ``([4 n, 4 C, T, T], s_min)``:
    every product of the full-resolution conv appears once, nothing else."""
    n, c, k, k2 = weight.shape
    if k != k2:
        raise ValueError(f"square kernel expected, got {k}x{k2}")
    s_min, taps = _phase_taps(offset, k)
    size = max(s for *_, s in taps) + 1
    out = weight.new_zeros(n, 2, 2, c, 2, 2, size, size)  # [o, q_y, q_x, C, r_y, r_x, a, b]
    for qy, u, ry, a in taps:
        for qx, v, rx, b in taps:
            out[:, qy, qx, :, ry, rx, a, b] = weight[:, :, u, v]
    return out.reshape(4 * n, 4 * c, size, size), s_min


class _UpHead(nn.Module):
    """``merged head(relu(bn5(conv5(x))))`` without the full-resolution feature map: conv5's
    polyphase output is kept as four phases, and the merged 10x10 head runs on the phases
    (``phase_head_weight``: a 6x6 conv, 64 -> 16 channels, which a CPU runs ~1.7x faster than
    the 16 -> 4 one at twice the resolution), then the four maps are pixel-shuffled. Phase
    pixels that conv5's crop drops (or the head's zero padding stands for) are zeroed first."""

    def __init__(self, conv5: nn.ConvTranspose2d, bn5: nn.BatchNorm2d, head_weight: torch.Tensor,
                 head_bias: torch.Tensor, head_padding: int) -> None:
        super().__init__()
        self.up = _Up(conv5, bn5)
        self.crop = self.up.padding  # full-resolution row t of the phases is conv5 row t - crop
        self.kernel = head_weight.shape[-1]
        self.head_padding = head_padding
        w, self.s_min = phase_head_weight(head_weight, self.crop - head_padding)
        self.weight = nn.Parameter(w.contiguous(memory_format=_CL), requires_grad=False)
        self.bias = nn.Parameter(head_bias.repeat_interleave(4), requires_grad=False)
        self.taps = w.shape[-1]

    def _axis(self, size: int) -> tuple[int, int, int, list[int], list[int]]:
        """One axis, ``size`` = conv5's input size: (output length, conv padding, first output,
        phase-0 rows to zero, phase-1 rows to zero)."""
        up = self.up
        kept = 2 * size + 2 - 2 * up.padding + up.output_padding  # conv5's output rows
        length = kept + 2 * self.head_padding - self.kernel + 1  # head output rows
        half = -(-length // 2)  # output rows per phase
        low = size + 1  # input rows per phase
        # output phase row M reads phase rows M + s_min ... M + s_min + taps - 1: a conv with
        # padding ``pad`` gives them at its row M + s_min + pad, all inside its output
        pad = max(-self.s_min, half + self.s_min + self.taps - 1 - low, 0)
        drop = [[m for m in range(low) if not self.crop <= 2 * m + r < self.crop + kept] for r in (0, 1)]
        return length, pad, self.s_min + pad, drop[0], drop[1]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        z = torch.relu_(F.conv2d(x, self.up.weight, self.up.bias, padding=1))  # [B, 4C, h+1, w+1]
        len_y, pad_y, first_y, drop_y0, drop_y1 = self._axis(h)
        len_x, pad_x, first_x, drop_x0, drop_x1 = self._axis(w)
        phases = z.view(z.shape[0], -1, 2, 2, z.shape[2], z.shape[3])  # [B, C, r_y, r_x, h+1, w+1]: a view
        for r, rows in ((0, drop_y0), (1, drop_y1)):
            for m in rows:
                phases[:, :, r, :, m, :] = 0.0
        for r, cols in ((0, drop_x0), (1, drop_x1)):
            for m in cols:
                phases[:, :, :, r, :, m] = 0.0
        y = F.conv2d(z, self.weight, self.bias, padding=(pad_y, pad_x))  # [B, 4n, ., .]
        half_y, half_x = -(-len_y // 2), -(-len_x // 2)
        y = y[..., first_y : first_y + half_y, first_x : first_x + half_x].contiguous()
        return F.pixel_shuffle(y, 2)[..., :len_y, :len_x]  # [B, n, len_y, len_x]


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
        w, b, pad = merged_head(ref.conv6, [ref.pos_output, ref.cos_output, ref.sin_output, ref.width_output])
        self.conv5_head = _UpHead(ref.conv5, ref.bn5, w, b, pad)

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
        y = self.conv5_head(self.conv4(self.res(x)))  # [B, 4, H, W]
        return GraspMaps(y[:, 0:1], y[:, 1:2], y[:, 2:3], y[:, 3:4])


def fused(model: GraspNet) -> GraspNet:
    """The inference rewrite of ``model`` where there is one (GR-ConvNet), else ``model``."""
    if isinstance(model, GenerativeResnet):
        return FusedGenerativeResnet.from_reference(model)
    return model
