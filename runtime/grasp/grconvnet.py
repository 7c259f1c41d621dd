"""GR-ConvNet (Kumra, Joshi, Sahin, IROS 2020), the ``grconvnet3`` GenerativeResnet.

A re-implementation whose parameter names match the original checkpoints, so the real
Cornell-trained weights load unchanged. RGB-D input ``[B, 4, 224, 224]``, channel order
(depth, r, g, b) as in the original data loaders. The channel size (16 for the shipped
checkpoint, 32 in the paper) and input channels are read from the checkpoint.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import torch
import torch.nn.functional as F
from torch import nn

from .base import GraspMaps, GraspNet, Modality, shape_of


class ResidualBlock(nn.Module):
    """conv-bn-relu-conv-bn plus identity (no activation after the sum, as in the original)."""

    def __init__(self, channels: int, kernel_size: int = 3) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(channels, channels, kernel_size, padding=1)
        self.bn1 = nn.BatchNorm2d(channels)
        self.conv2 = nn.Conv2d(channels, channels, kernel_size, padding=1)
        self.bn2 = nn.BatchNorm2d(channels)

    def forward(self, x_in: torch.Tensor) -> torch.Tensor:
        x = F.relu(self.bn1(self.conv1(x_in)))  # [B, C, H, W]
        x = self.bn2(self.conv2(x))  # [B, C, H, W]
        out: torch.Tensor = x + x_in
        return out


class GenerativeResnet(GraspNet):
    """Encoder (3 convs) → 5 residual blocks → decoder (3 transposed convs) → 4 heads."""

    input_size: ClassVar[int] = 224
    modality: ClassVar[Modality] = "rgbd"

    def __init__(self, input_channels: int = 4, channel_size: int = 32) -> None:
        super().__init__()
        c = channel_size
        self.conv1 = nn.Conv2d(input_channels, c, kernel_size=9, stride=1, padding=4)
        self.bn1 = nn.BatchNorm2d(c)
        self.conv2 = nn.Conv2d(c, c * 2, kernel_size=4, stride=2, padding=1)
        self.bn2 = nn.BatchNorm2d(c * 2)
        self.conv3 = nn.Conv2d(c * 2, c * 4, kernel_size=4, stride=2, padding=1)
        self.bn3 = nn.BatchNorm2d(c * 4)
        self.res1 = ResidualBlock(c * 4)
        self.res2 = ResidualBlock(c * 4)
        self.res3 = ResidualBlock(c * 4)
        self.res4 = ResidualBlock(c * 4)
        self.res5 = ResidualBlock(c * 4)
        self.conv4 = nn.ConvTranspose2d(
            c * 4, c * 2, kernel_size=4, stride=2, padding=1, output_padding=1
        )
        self.bn4 = nn.BatchNorm2d(c * 2)
        self.conv5 = nn.ConvTranspose2d(
            c * 2, c, kernel_size=4, stride=2, padding=2, output_padding=1
        )
        self.bn5 = nn.BatchNorm2d(c)
        self.conv6 = nn.ConvTranspose2d(c, c, kernel_size=9, stride=1, padding=4)
        self.pos_output = nn.Conv2d(c, 1, kernel_size=2)
        self.cos_output = nn.Conv2d(c, 1, kernel_size=2)
        self.sin_output = nn.Conv2d(c, 1, kernel_size=2)
        self.width_output = nn.Conv2d(c, 1, kernel_size=2)

    def forward(self, x: torch.Tensor) -> GraspMaps:
        # x: [B, 4, 224, 224]; C = channel_size
        x = F.relu(self.bn1(self.conv1(x)))  # [B, C, 224, 224]
        x = F.relu(self.bn2(self.conv2(x)))  # [B, 2C, 112, 112]
        x = F.relu(self.bn3(self.conv3(x)))  # [B, 4C, 56, 56]
        x = self.res1(x)
        x = self.res2(x)
        x = self.res3(x)
        x = self.res4(x)
        x = self.res5(x)  # [B, 4C, 56, 56]
        x = F.relu(self.bn4(self.conv4(x)))  # [B, 2C, 113, 113]
        x = F.relu(self.bn5(self.conv5(x)))  # [B, C, 225, 225]
        x = self.conv6(x)  # [B, C, 225, 225]
        return GraspMaps(  # each [B, 1, 224, 224]
            self.pos_output(x), self.cos_output(x), self.sin_output(x), self.width_output(x)
        )

    @classmethod
    def from_state_dict(cls, state: Mapping[str, torch.Tensor]) -> GenerativeResnet:
        c, in_ch, _, _ = shape_of(state, "conv1.weight", "GR-ConvNet")
        model = cls(input_channels=in_ch, channel_size=c)
        model.load_state_dict(dict(state), strict=True)
        return model
