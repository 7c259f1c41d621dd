"""Named grasp networks with checksum-verified weights (the openai/CLIP ``load()`` pattern).

The weights are the real Cornell-trained checkpoints in ``<shared>/models/grasp``; ``<shared>`` is
``craft_e.paths.shared_dir()`` (``$CRAFT_SHARED``, default ``../shared``). A file that is missing
or differs by one bit is refused with an error that names the file and the fix: a silently wrong
checkpoint would give plausible-looking but meaningless grasps.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors.torch import load_file

from ...files import sha256_file
from ...paths import shared_dir
from .base import GraspNet
from .ggcnn import GGCNN, GGCNN2
from .grconvnet import GenerativeResnet


class GraspWeightsError(RuntimeError):
    """Grasp-network weights missing or not the expected file."""


@dataclass(frozen=True)
class GraspModelSpec:
    """One registered network.

    ``width_scale_px`` turns the width map into pixels of the network input. It is the
    normalisation used in *training*: GG-CNN divided widths by 150 px; GR-ConvNet divided by
    half its output size (224 / 2 = 112 px) — its published inference code multiplies by 150
    anyway (copied from GG-CNN), which overstates openings by 34 %.
    """

    name: str
    filename: str
    sha256: str
    net_class: type[GraspNet]
    width_scale_px: float
    reference_io: str

    @property
    def input_size(self) -> int:
        return self.net_class.input_size


MODELS: dict[str, GraspModelSpec] = {
    spec.name: spec
    for spec in (
        GraspModelSpec(
            name="grconvnet",
            filename="grconvnet3_cornell_rgbd_ch16.safetensors",
            sha256="f3432d2dfb4f8185d1ab4b0dbc417511ee42d9d7c03ccaed58e9d9bd453e7653",
            net_class=GenerativeResnet,
            width_scale_px=112.0,
            reference_io="grconvnet3_reference_io.npz",
        ),
        GraspModelSpec(
            name="ggcnn",
            filename="ggcnn_cornell_depth.safetensors",
            sha256="0b085cb21cec73cdd33a5c3e357975fa3e88196d762f94984207be3882953067",
            net_class=GGCNN,
            width_scale_px=150.0,
            reference_io="ggcnn_cornell_depth_reference_io.npz",
        ),
        GraspModelSpec(
            name="ggcnn2",
            filename="ggcnn2_cornell_depth.safetensors",
            sha256="f81411343d6c56e8c37a8332d4217a058633f797216b7e218765ea7a23bf578e",
            net_class=GGCNN2,
            width_scale_px=150.0,
            reference_io="ggcnn2_cornell_depth_reference_io.npz",
        ),
    )
}


def available_models() -> list[str]:
    """Names accepted by ``load``."""
    return sorted(MODELS)


def get_spec(name: str) -> GraspModelSpec:
    try:
        return MODELS[name]
    except KeyError:
        raise KeyError(
            f"unknown grasp network {name!r}; available: {', '.join(available_models())}"
        ) from None


def models_dir() -> Path:
    """``<shared>/models/grasp`` (resolved at call time, so ``CRAFT_SHARED`` can change)."""
    return shared_dir() / "models" / "grasp"


def verified_weights_path(name: str, root: Path | None = None) -> Path:
    """Path of a network's weights after checking existence and sha256."""
    spec = get_spec(name)
    folder = models_dir() if root is None else root
    path = folder / spec.filename
    if not path.is_file():
        raise GraspWeightsError(
            f"grasp network {name!r}: weights file {path} not found. Fix: point CRAFT_SHARED at "
            f"the shared reference folder that holds models/grasp/{spec.filename} "
            f"(currently resolving to {folder})."
        )
    actual = sha256_file(path)
    if actual != spec.sha256:
        raise GraspWeightsError(
            f"grasp network {name!r}: {path} has sha256 {actual}, expected {spec.sha256}. "
            f"Fix: restore the original {spec.filename} from the shared reference folder; "
            "if the checkpoint was replaced on purpose, register its new sha256 in "
            "craft_e.runtime.grasp.registry.MODELS."
        )
    return path


def load(name: str, device: str | torch.device = "cpu", root: Path | None = None) -> GraspNet:
    """Build a registered network from its verified checkpoint, in eval mode, without gradients.

    Hyperparameters (channel counts, kernel sizes) are read from the checkpoint's tensor shapes.
    """
    spec = get_spec(name)
    path = verified_weights_path(name, root)
    state = load_file(str(path), device="cpu")
    try:
        model = spec.net_class.from_state_dict(state)
    except (KeyError, RuntimeError) as exc:
        raise GraspWeightsError(f"grasp network {name!r}: {path} does not fit: {exc}") from exc
    model.eval()
    model.requires_grad_(False)
    return model.to(device)
