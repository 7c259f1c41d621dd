"""What every grasp network here shares: four output maps and a declared input format.

GG-CNN, GG-CNN2 and GR-ConvNet are all "generative" grasp networks: one forward pass gives, per
pixel of the (square) input, a grasp quality, the grasp angle encoded as (cos 2θ, sin 2θ) — the
doubling makes θ and θ+π the same target — and a normalised opening width.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar, Literal, NamedTuple

import torch
from torch import nn

Modality = Literal["depth", "rgbd"]


class GraspMaps(NamedTuple):
    """Raw network outputs, each ``[B, 1, S, S]``: quality, cos 2θ, sin 2θ, width / scale."""

    pos: torch.Tensor
    cos: torch.Tensor
    sin: torch.Tensor
    width: torch.Tensor


class GraspNet(nn.Module):
    """Base class: subclasses set the class variables and build themselves from a checkpoint."""

    input_size: ClassVar[int]
    modality: ClassVar[Modality]

    def forward(self, x: torch.Tensor) -> GraspMaps:  # pragma: no cover - abstract
        raise NotImplementedError

    def __call__(self, x: torch.Tensor) -> GraspMaps:
        """Typed call (``nn.Module.__call__`` is untyped); hooks still run."""
        out: GraspMaps = super().__call__(x)
        return out

    @classmethod
    def from_state_dict(cls, state: Mapping[str, torch.Tensor]) -> GraspNet:
        """Build with hyperparameters read from the tensor shapes, then load the weights."""
        raise NotImplementedError


def shape_of(state: Mapping[str, torch.Tensor], key: str, source: str) -> tuple[int, ...]:
    """Shape of a checkpoint tensor, with an error that names the checkpoint if it is absent."""
    if key not in state:
        raise KeyError(f"{source}: checkpoint has no tensor {key!r}; is it the right network?")
    return tuple(state[key].shape)
