"""GG-CNN and GG-CNN2 (Morrison, Corke, Leitner, RSS 2018 / IJRR 2019), depth-only.

Re-implementations with the original parameter names, so the Cornell-trained checkpoints load
unchanged. Input: a ``[B, 1, 300, 300]`` depth crop in metres minus its mean, clipped to ±1.
Channel counts (and GG-CNN2's dilated kernel size) are read from the checkpoint; strides,
paddings and GG-CNN2's dilations (2, 4) are not stored in a state dict and follow the originals.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import torch
import torch.nn.functional as F
from torch import nn

from .base import GraspMaps, GraspNet, Modality, shape_of

_GGCNN_KERNELS = (9, 5, 3, 3, 5, 9)
_GGCNN_STRIDES = (3, 2, 2, 2, 2, 3)


class GGCNN(GraspNet):
    """Three strided convs down, three transposed convs up, four 2×2 heads."""

    input_size: ClassVar[int] = 300
    modality: ClassVar[Modality] = "depth"

    def __init__(
        self, input_channels: int = 1, filter_sizes: tuple[int, ...] = (32, 16, 8, 8, 16, 32)
    ) -> None:
        super().__init__()
        f, k, s = filter_sizes, _GGCNN_KERNELS, _GGCNN_STRIDES
        self.conv1 = nn.Conv2d(input_channels, f[0], k[0], stride=s[0], padding=3)
        self.conv2 = nn.Conv2d(f[0], f[1], k[1], stride=s[1], padding=2)
        self.conv3 = nn.Conv2d(f[1], f[2], k[2], stride=s[2], padding=1)
        self.convt1 = nn.ConvTranspose2d(f[2], f[3], k[3], stride=s[3], padding=1, output_padding=1)
        self.convt2 = nn.ConvTranspose2d(f[3], f[4], k[4], stride=s[4], padding=2, output_padding=1)
        self.convt3 = nn.ConvTranspose2d(f[4], f[5], k[5], stride=s[5], padding=3, output_padding=1)
        self.pos_output = nn.Conv2d(f[5], 1, kernel_size=2)
        self.cos_output = nn.Conv2d(f[5], 1, kernel_size=2)
        self.sin_output = nn.Conv2d(f[5], 1, kernel_size=2)
        self.width_output = nn.Conv2d(f[5], 1, kernel_size=2)

    def forward(self, x: torch.Tensor) -> GraspMaps:
        # x: [B, 1, 300, 300]; default filter sizes shown
        x = F.relu(self.conv1(x))  # [B, 32, 100, 100]
        x = F.relu(self.conv2(x))  # [B, 16, 50, 50]
        x = F.relu(self.conv3(x))  # [B, 8, 25, 25]
        x = F.relu(self.convt1(x))  # [B, 8, 50, 50]
        x = F.relu(self.convt2(x))  # [B, 16, 100, 100]
        x = F.relu(self.convt3(x))  # [B, 32, 301, 301]
        return GraspMaps(  # each [B, 1, 300, 300]
            self.pos_output(x), self.cos_output(x), self.sin_output(x), self.width_output(x)
        )

    @classmethod
    def from_state_dict(cls, state: Mapping[str, torch.Tensor]) -> GGCNN:
        src = "GG-CNN"
        in_ch = shape_of(state, "conv1.weight", src)[1]
        filters = tuple(
            shape_of(state, f"{name}.weight", src)[0] for name in ("conv1", "conv2", "conv3")
        ) + tuple(  # ConvTranspose2d weights are [in, out, k, k]
            shape_of(state, f"{name}.weight", src)[1] for name in ("convt1", "convt2", "convt3")
        )
        model = cls(input_channels=in_ch, filter_sizes=filters)
        model.load_state_dict(dict(state), strict=True)
        return model


class GGCNN2(GraspNet):
    """Conv pairs with max-pooling, two dilated convs, bilinear upsampling, four 1×1 heads.

    Layer indices inside ``features`` must match the original ``nn.Sequential`` (ReLU and
    pooling layers included) because they are part of the parameter names.
    """

    input_size: ClassVar[int] = 300
    modality: ClassVar[Modality] = "depth"

    def __init__(
        self,
        input_channels: int = 1,
        filter_sizes: tuple[int, int, int, int] = (16, 16, 32, 16),
        l3_k_size: int = 5,
        dilations: tuple[int, int] = (2, 4),
    ) -> None:
        super().__init__()
        f = filter_sizes
        self.features = nn.Sequential(
            nn.Conv2d(input_channels, f[0], kernel_size=11, stride=1, padding=5),  # 0
            nn.ReLU(inplace=True),
            nn.Conv2d(f[0], f[0], kernel_size=5, stride=1, padding=2),  # 2
            nn.ReLU(inplace=True),
            nn.MaxPool2d(kernel_size=2, stride=2),
            nn.Conv2d(f[0], f[1], kernel_size=5, stride=1, padding=2),  # 5
            nn.ReLU(inplace=True),
            nn.Conv2d(f[1], f[1], kernel_size=5, stride=1, padding=2),  # 7
            nn.ReLU(inplace=True),
            nn.MaxPool2d(kernel_size=2, stride=2),
            nn.Conv2d(  # 10
                f[1], f[2], l3_k_size, dilation=dilations[0], padding=l3_k_size // 2 * dilations[0]
            ),
            nn.ReLU(inplace=True),
            nn.Conv2d(  # 12
                f[2], f[2], l3_k_size, dilation=dilations[1], padding=l3_k_size // 2 * dilations[1]
            ),
            nn.ReLU(inplace=True),
            nn.UpsamplingBilinear2d(scale_factor=2),
            nn.Conv2d(f[2], f[3], 3, padding=1),  # 15
            nn.ReLU(inplace=True),
            nn.UpsamplingBilinear2d(scale_factor=2),
            nn.Conv2d(f[3], f[3], 3, padding=1),  # 18
            nn.ReLU(inplace=True),
        )
        self.pos_output = nn.Conv2d(f[3], 1, kernel_size=1)
        self.cos_output = nn.Conv2d(f[3], 1, kernel_size=1)
        self.sin_output = nn.Conv2d(f[3], 1, kernel_size=1)
        self.width_output = nn.Conv2d(f[3], 1, kernel_size=1)

    def forward(self, x: torch.Tensor) -> GraspMaps:
        # x: [B, 1, 300, 300] → two poolings ([B, 16, 75, 75]) → dilated convs ([B, 32, 75, 75])
        # → two ×2 bilinear upsamplings
        x = self.features(x)  # [B, 16, 300, 300]
        return GraspMaps(  # each [B, 1, 300, 300]
            self.pos_output(x), self.cos_output(x), self.sin_output(x), self.width_output(x)
        )

    @classmethod
    def from_state_dict(cls, state: Mapping[str, torch.Tensor]) -> GGCNN2:
        src = "GG-CNN2"
        f0, in_ch, _, _ = shape_of(state, "features.0.weight", src)
        f1 = shape_of(state, "features.5.weight", src)[0]
        f2, _, l3_k, _ = shape_of(state, "features.10.weight", src)
        f3 = shape_of(state, "features.15.weight", src)[0]
        model = cls(input_channels=in_ch, filter_sizes=(f0, f1, f2, f3), l3_k_size=l3_k)
        model.load_state_dict(dict(state), strict=True)
        return model
