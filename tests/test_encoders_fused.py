"""The fused EfficientNet-Lite (``encoders.fused``) computes the checkpoint's function.

Why: the robot's path embeds ROI crops with the rewritten classifier (batch norm folded,
channels-last, 1x1 convs as matrix products, TF "same" padding of stride-2 convs as a zero
kernel row and column). Its ConSE embeddings must equal the reference encoder's to float32
rounding on real photos, and its logits on random inputs; the batch size must not matter.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from runtime_fixtures import conse_fixture, shared_image  # noqa: F401

from craft_e.runtime.encoders.efficientnet import SameConv2d
from craft_e.runtime.encoders.fused import FusedEfficientNetLite, same_padding
from craft_e.runtime.encoders.image import FusableImageEncoder, inference_encoder, load_image

TOL = 1e-5


def test_fused_embeddings_equal_the_reference(conse: Any) -> None:
    imgs = [load_image(str(shared_image(n))) for n in ("cup", "banana", "drum", "teapot")]
    fast = inference_encoder(conse)
    assert isinstance(conse, FusableImageEncoder)
    assert fast is conse.fused() and fast is not conse and fast.id == f"{conse.id}+fused"
    assert inference_encoder(fast) is fast
    want = conse.embed_images(imgs)
    got = fast.embed_images(imgs)
    assert float(np.abs(got - want).max()) < TOL
    one = np.concatenate([fast.embed_images([i]) for i in imgs])
    assert float(np.abs(one - want).max()) < TOL
    np.testing.assert_allclose(conse.class_probabilities(imgs), fast.class_probabilities(imgs), atol=TOL)  # type: ignore[attr-defined]


@pytest.mark.parametrize("size", [240, 224])
def test_fused_logits_on_random_inputs(conse: Any, size: int) -> None:
    """At the default classifier's own size (Lite1: 240) and at another one (paddings fixed per size)."""
    ref = conse.classifier
    fast = FusedEfficientNetLite.from_reference(ref, size)
    x = torch.rand(3, 3, size, size, generator=torch.Generator().manual_seed(0)) * 2 - 1
    with torch.inference_mode():
        want, got = ref(x), fast(x)
    assert float((want - got).abs().max()) < 1e-4 * max(1.0, float(want.abs().max()))
    assert float((want.softmax(-1) - got.softmax(-1)).abs().max()) < TOL
    with pytest.raises(ValueError, match=f"{size}x{size}"):
        fast(torch.zeros(1, 3, 200, 200))


@pytest.mark.parametrize(("kernel", "size"), [(3, 112), (5, 56), (3, 28), (5, 14)])
def test_stride2_same_padding_as_a_larger_kernel(kernel: int, size: int) -> None:
    """TF "same" pads (lo, lo + 1) for these: a zero first row/column and symmetric padding
    reads the same pixels (a depthwise conv, as in the network)."""
    torch.manual_seed(kernel + size)
    conv = SameConv2d(8, 8, kernel, 2, groups=8)
    x = torch.randn(1, 8, size, size)
    lo, hi = same_padding(size, kernel, 2)
    assert hi == lo + 1
    with torch.no_grad():
        want = conv(x)
        got = F.conv2d(x, F.pad(conv.weight, [1, 0, 1, 0]), None, 2, hi, 1, 8)
    assert got.shape == want.shape
    assert torch.allclose(got, want, atol=1e-5)
