"""Regions of interest: one candidate object in the image.

* ``Region`` — what segmentation finds: a connected mask with its box (the simulator's body id
  for oracle regions).
* ``ROI`` — what ``Grounder.ground`` ranks: a box with grasp candidates and the crop's image
  embedding. :func:`build_rois` is the one way from an image (+ depth) and boxes to ROIs; the
  CLI, the server, the static benchmark and the testbed all call it.

The box is also what the static benchmark scores (IoU >= 0.5 with the target's box).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from ..encoders.base import ImageEncoder

BoolMask = npt.NDArray[np.bool_]
FloatArray = npt.NDArray[np.float32]
Box = tuple[float, float, float, float]


@dataclass
class ROI:
    """A candidate region: box, grasp candidates with scores, and its image embedding.

    ``grasps`` is opaque to the grounder (e.g. ``Grasp2D`` or 6-DoF poses) and parallel to
    ``grasp_scores``; the chosen grasp is returned by index. ``image_embedding`` is ``phi_I(r)``
    (``[d]``, any norm) in the bundle's text space.
    """

    box_xywh: Box
    grasp_scores: Sequence[float] = ()
    grasps: list[Any] = field(default_factory=list)
    image_embedding: FloatArray | None = None
    mask: BoolMask | None = None
    label: str | None = None
    #: the box edges measured from depth, metres, longest first (``perception/extents.py``);
    #: ``None``: not measured (no depth), the size cue is then neutral for this ROI
    extents_m: tuple[float, float, float] | None = None
    #: the share of its pixels in each basic colour term (``perception/colours.py``, the order of
    #: ``kb.colours.COLOUR_TERMS``); ``None``: not measured, the colour cue is then neutral
    colours: tuple[float, ...] | None = None
    #: how far its inside lies below its rim, metres, from depth (``perception/cavity.py``; the
    #: cavity cue); ``None``: not measured, the cavity cue is then neutral
    cavity_m: float | None = None
    #: the image classifier's most probable ImageNet classes on its crop, (class index,
    #: probability) (``encoders.conse.encode_with_classes``); ``None``: not measured (another
    #: encoder), the look-alike cue is then neutral
    classes: tuple[tuple[int, float], ...] | None = None


@dataclass(frozen=True)
class BoxSpec:
    """One box as a caller gives it: pixels ``x, y, w, h``, optional grasp scores and label."""

    box: Box
    grasp_scores: Sequence[float] | None = None
    label: str | None = None


def boxes_past_the_image(boxes: Sequence[Sequence[float]], width: int, height: int) -> list[str]:
    """A note per ``x, y, w, h`` box that reaches past a ``width`` x ``height`` image: its crop
    holds only the part inside, which a caller should know (``craft ground``, ``/ground_image``)."""
    return [f"box {i} {[float(v) for v in b]} reaches past the {width}x{height} image: only the part inside "
            "was embedded"
            for i, b in enumerate(boxes)
            if b[0] < 0 or b[1] < 0 or b[0] + b[2] > width or b[1] + b[3] > height]


class RoiError(ValueError):
    """Box ``index`` cannot become an ROI (outside the image, grasp prediction failed)."""

    def __init__(self, index: int, message: str) -> None:
        self.index = index
        super().__init__(message)


def build_rois(
    rgb: npt.NDArray[np.uint8],
    boxes: Sequence[BoxSpec],
    encoder: ImageEncoder,
    *,
    depth: npt.NDArray[np.floating[Any]] | None = None,
    grasp_backend: str | None = None,
) -> list[ROI]:
    """Crop every box, embed the crops in one batch, and attach grasp candidates.

    Grasps: a box's own ``grasp_scores`` when given; else, with ``depth`` and a
    ``grasp_backend``, the backend's grasps on the object inside the box (its mask above the
    support plane; the whole box when that is empty); else none — an ROI without grasp
    scores, which the caller decides how to treat. ``RoiError`` names the failing box.
    """
    from ..encoders.conse import encode_with_classes
    from ..encoders.image import crop_box

    crops = []
    for i, b in enumerate(boxes):
        try:
            crops.append(crop_box(rgb, b.box))
        except ValueError as exc:
            raise RoiError(i, str(exc)) from None
    embeddings, classes = encode_with_classes(encoder, crops)  # [N, d], the classifier's top classes
    rois: list[ROI] = []
    for i, b in enumerate(boxes):
        grasps: list[Any] = []
        scores: list[float] = [] if b.grasp_scores is None else [float(s) for s in b.grasp_scores]
        if b.grasp_scores is None and depth is not None and grasp_backend is not None:
            try:
                grasps = grasps_in_box(grasp_backend, rgb, depth, b.box)
            except (ValueError, RuntimeError) as exc:
                raise RoiError(i, f"grasp prediction ({grasp_backend}) failed for ROI {i}: {exc}") from None
            scores = [float(g.quality) for g in grasps]
        rois.append(ROI(box_xywh=b.box, grasp_scores=scores, grasps=grasps,
                        image_embedding=embeddings[i], label=b.label, classes=classes[i]))
    return rois


def grasps_in_box(backend: str, rgb: npt.NDArray[np.uint8], depth: npt.NDArray[np.floating[Any]],
                  box: Box) -> list[Any]:
    """Grasp candidates on the object inside ``box`` (``predict_grasps`` of the grasp module).

    The grasp backends want the object's own mask (the fingers need free space beside it), so
    the box is intersected with the pixels standing above the support plane; an empty result
    falls back to the whole box.
    """
    from ..grasp import estimate_object_mask, predict_grasps

    box_mask = np.zeros(depth.shape[:2], dtype=bool)
    x, y, w, h = (round(v) for v in box)
    box_mask[max(0, y) : max(0, y + h), max(0, x) : max(0, x + w)] = True
    mask = estimate_object_mask(depth) & box_mask
    return list(predict_grasps(backend, rgb, depth, mask if mask.any() else box_mask))


@dataclass(frozen=True)
class Region:
    """A connected image region. ``label`` is the simulator body id for oracle ROIs, else None."""

    box_xywh: tuple[int, int, int, int]  # x, y of the top-left pixel, width, height (pixels)
    mask: BoolMask  # [H, W]
    area: int  # pixels in the mask
    centroid: tuple[float, float]  # (x, y) = (column, row) mean of the mask
    label: int | None = None


def roi_from_mask(
    mask: BoolMask, label: int | None = None, *, within: tuple[slice, slice] | None = None
) -> Region:
    """Box, area and centroid of a non-empty mask.

    ``within``: a (row, column) window of the frame known to hold every mask pixel; only it is
    scanned (the same pixels in the same raster order, so the same numbers, without a pass over
    the whole frame per ROI)."""
    if within is None:
        rows, cols = np.nonzero(mask)
    else:
        r, c = within
        rows, cols = np.nonzero(mask[r, c])
        rows, cols = rows + (r.start or 0), cols + (c.start or 0)
    if rows.size == 0:
        raise ValueError("cannot make an ROI from an empty mask")
    x0, x1 = int(cols.min()), int(cols.max())
    y0, y1 = int(rows.min()), int(rows.max())
    return Region(
        box_xywh=(x0, y0, x1 - x0 + 1, y1 - y0 + 1),
        mask=mask,
        area=int(rows.size),
        centroid=(float(cols.mean()), float(rows.mean())),
        label=label,
    )


def box_iou(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    """Intersection over union of two pixel boxes (x, y, w, h)."""
    ax0, ay0, aw, ah = a
    bx0, by0, bw, bh = b
    ix = max(0, min(ax0 + aw, bx0 + bw) - max(ax0, bx0))
    iy = max(0, min(ay0 + ah, by0 + bh) - max(ay0, by0))
    inter = ix * iy
    union = aw * ah + bw * bh - inter
    return inter / union if union > 0 else 0.0


def best_box_matches(predicted: Sequence[Region], reference: Sequence[Region]) -> list[float]:
    """For each reference region, the best box IoU any predicted ROI achieves (0 if none)."""
    return [
        max((box_iou(r.box_xywh, q.box_xywh) for q in predicted), default=0.0) for r in reference
    ]
