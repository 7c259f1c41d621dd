"""Grasping: Cornell-trained grasp networks, an antipodal sampler, rectangle ↔ pose, the metric.

``predict_grasps(backend, rgb, depth, mask)`` is the entry point (backends: ``grconvnet``,
``ggcnn``, ``ggcnn2``, ``antipodal``); ``load(name)`` gives a checksum-verified network;
``rect_to_pose``/``pose_to_rect`` convert through pinhole intrinsics; ``grasp_success`` is the
Cornell criterion (angle < 30°, Jaccard > 0.25).

Geometry and the metric are imported eagerly; everything that needs torch is imported on first
use, so evaluation code that only scores rectangles does not pay torch's start-up time.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .geometry import CameraIntrinsics, Grasp2D, TopDownGrasp, pose_to_rect, rect_to_pose
from .metrics import grasp_success, load_cornell_rectangles, max_iou, rectangle_iou

if TYPE_CHECKING:
    from .antipodal import AntipodalConfig, estimate_object_mask, sample_antipodal_grasps
    from .base import GraspMaps, GraspNet
    from .postprocess import ProcessedMaps, detect_grasps, post_process
    from .predict import BACKENDS, predict_grasps
    from .registry import GraspWeightsError, available_models, load

_LAZY = {
    "AntipodalConfig": ".antipodal",
    "estimate_object_mask": ".antipodal",
    "sample_antipodal_grasps": ".antipodal",
    "GraspMaps": ".base",
    "GraspNet": ".base",
    "ProcessedMaps": ".postprocess",
    "detect_grasps": ".postprocess",
    "post_process": ".postprocess",
    "BACKENDS": ".predict",
    "predict_grasps": ".predict",
    "GraspWeightsError": ".registry",
    "available_models": ".registry",
    "load": ".registry",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module, __name__), name)


__all__ = [
    "BACKENDS",
    "AntipodalConfig",
    "CameraIntrinsics",
    "Grasp2D",
    "GraspMaps",
    "GraspNet",
    "GraspWeightsError",
    "ProcessedMaps",
    "TopDownGrasp",
    "available_models",
    "detect_grasps",
    "estimate_object_mask",
    "grasp_success",
    "load",
    "load_cornell_rectangles",
    "max_iou",
    "pose_to_rect",
    "post_process",
    "predict_grasps",
    "rect_to_pose",
    "rectangle_iou",
    "sample_antipodal_grasps",
]
