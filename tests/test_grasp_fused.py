"""The fused GR-ConvNet (``grasp.fused``) computes the checkpoint's function.

Why: the robot's path runs the rewritten network (batch norm folded, polyphase transposed
convs, last conv merged with the heads, channels-last); a slip in any rewrite would give
plausible but different grasp maps. The reference input/output file of the original
implementation and random inputs of several window sizes (odd and even multiples of 4, batch 2)
must agree with ``GenerativeResnet`` to float32 rounding.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from craft_e.runtime.grasp import registry
from craft_e.runtime.grasp.base import GraspMaps, GraspNet
from craft_e.runtime.grasp.fused import (
    FusedGenerativeResnet,
    fused,
    merged_head,
    phase_head_weight,
    polyphase_weight,
)
from craft_e.runtime.grasp.grconvnet import GenerativeResnet
from craft_e.runtime.grasp.registry import load, models_dir

MAPS = ("pos", "cos", "sin", "width")
TOL = 1e-5


@pytest.fixture(scope="module")
def nets() -> tuple[GraspNet, GraspNet]:
    ref = load("grconvnet")
    assert isinstance(ref, GenerativeResnet)
    return ref, fused(ref)


def _max_diff(a: GraspMaps, b: GraspMaps) -> float:
    return max(float((x - y).abs().max()) for x, y in zip(a, b, strict=True))


def test_reference_io_file(nets: tuple[GraspNet, GraspNet]) -> None:
    _, fast = nets
    assert isinstance(fast, FusedGenerativeResnet)
    path = models_dir() / registry.get_spec("grconvnet").reference_io
    with np.load(path, allow_pickle=False) as data:
        ref = {k: data[k] for k in data.files}
    with torch.inference_mode():
        out = fast(torch.from_numpy(ref["input"]))
    for key, got in zip(MAPS, out, strict=True):
        assert got.shape == ref[key].shape
        assert float(np.abs(got.numpy() - ref[key]).max()) < TOL, key


@pytest.mark.parametrize("shape", [(1, 4, 224, 224), (1, 4, 228, 300), (2, 4, 96, 132), (1, 4, 100, 64), (1, 4, 97, 61)])
def test_random_inputs(nets: tuple[GraspNet, GraspNet], shape: tuple[int, int, int, int]) -> None:
    ref, fast = nets
    x = torch.randn(*shape, generator=torch.Generator().manual_seed(sum(shape)))
    with torch.inference_mode():
        want, got = ref(x), fast(x)
    for a, b in zip(want, got, strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
    assert _max_diff(want, got) < TOL


def test_polyphase_equals_transposed_conv() -> None:
    gen = torch.Generator().manual_seed(0)
    w = torch.randn(6, 5, 4, 4, generator=gen)
    x = torch.randn(1, 6, 9, 11, generator=gen)
    for padding, output_padding in ((1, 1), (2, 1), (0, 0), (1, 0)):
        want = torch.nn.functional.conv_transpose2d(x, w, stride=2, padding=padding, output_padding=output_padding)
        full = torch.nn.functional.pixel_shuffle(torch.nn.functional.conv2d(x, polyphase_weight(w), padding=1), 2)
        got = full[..., padding : padding + want.shape[-2], padding : padding + want.shape[-1]]
        assert torch.allclose(got, want, atol=1e-5)


def test_merged_head_equals_conv_then_heads() -> None:
    torch.manual_seed(0)
    conv6 = nn.ConvTranspose2d(3, 3, kernel_size=5, padding=2)
    heads = [nn.Conv2d(3, 1, kernel_size=2) for _ in range(4)]
    x = torch.randn(1, 3, 12, 17)
    with torch.no_grad():
        y = conv6(x)
        want = torch.cat([h(y) for h in heads], dim=1)
        w, b, pad = merged_head(conv6, heads)
        got = torch.nn.functional.conv2d(x, w, b, padding=pad)
    assert got.shape == want.shape
    assert torch.allclose(got, want, atol=1e-5)


def test_fused_from_state_dict_is_frozen_and_other_nets_pass_through() -> None:
    ref = load("grconvnet")
    fast = FusedGenerativeResnet.from_state_dict(ref.state_dict())
    assert not fast.training and not any(p.requires_grad for p in fast.parameters())
    ggcnn = load("ggcnn")
    assert fused(ggcnn) is ggcnn


@pytest.mark.parametrize("offset", [-2, -1, 0, 3])
def test_phase_head_equals_the_full_resolution_conv(offset: int) -> None:
    """A conv reading rows ``i + u + offset`` of a map, run on the map's four phases, gives the
    four phases of its output (zero padding beyond the map on both sides)."""
    gen = torch.Generator().manual_seed(offset + 10)
    w = torch.randn(2, 3, 5, 5, generator=gen)
    x = torch.randn(1, 3, 14, 18, generator=gen)  # even sides: 7 x 9 phase pixels
    pad = 12  # enough zeros around x for every tap
    xp = torch.nn.functional.pad(x, [pad] * 4)
    out_h, out_w = 10, 12
    want = torch.nn.functional.conv2d(xp, w)[..., pad + offset : pad + offset + out_h, pad + offset : pad + offset + out_w]
    phases = torch.nn.functional.pixel_unshuffle(x, 2)  # [1, 12, 7, 9]: channel 4c + 2 r_y + r_x
    wp, s_min = phase_head_weight(w, offset)
    p = 8  # output phase row M reads phase rows M + s_min ...: at conv row M + s_min + p
    got = torch.nn.functional.conv2d(phases, wp, padding=p)
    got = got[..., s_min + p : s_min + p + out_h // 2, s_min + p : s_min + p + out_w // 2]
    got = torch.nn.functional.pixel_shuffle(got, 2)
    assert got.shape == want.shape
    assert torch.allclose(got, want, atol=1e-5)
