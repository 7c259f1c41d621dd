"""Perceiving a scene once: capture, ROIs, each ROI's grasps checked, crop embeddings and cues.

Why a module of its own: one perception is shared by every grounding method of an episode and
by each retry's fresh frame (``pipeline.run_episode``, ``pipeline.retry_picks``), and the
evaluations and the robot's lazy path (``choose``) reuse its pieces (``raster_order``,
``majority_body``, ``torch_threads``, the cue measurements) without the episode's execution.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from ..encoders.image import ImageEncoder
from ..grasp.geometry import TopDownGrasp
from ..perception.cavity import measure_cavity
from ..perception.colours import measure_colours
from ..perception.extents import measure_extents
from ..perception.observation import Observation
from ..perception.roi import ROI, Region, box_iou
from ..perception.segment import segment
from .active_look import ActiveLook, ActiveLookConfig
from .candidates import GraspCandidate, fallback_with_refinements, raw_candidates, with_refinements
from .clearance import heights_around
from .env import SimEnv
from .grasp_checks import Surfaces, three_d_metric, usable_grasps
from .oracle import gt_rois
from .stages import timed_stage
from .surface import RaisedPoints

if TYPE_CHECKING:
    from .pipeline import PipelineConfig

FloatArray = npt.NDArray[np.float64]
BoolMask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class PerceivedROI:
    """An ROI with its grasps, the grasp the robot would use, and its image embedding."""

    roi: Region
    candidates: tuple[GraspCandidate, ...]  # raw, best first
    usable: tuple[GraspCandidate, ...]  # what grounding sees (best first)
    embedding: npt.NDArray[np.float32]
    body: int | None  # the scene body the mask covers most (diagnostics only, never grounding)
    target_iou: float  # box IoU with the target's ground-truth box
    #: box edges from depth, metres, longest first (``perception/extents.py``; the size cue)
    extents_m: tuple[float, float, float] | None = None
    #: colour shares of its raised pixels (``perception/colours.py``; the colour cue)
    colours: tuple[float, ...] | None = None
    #: the classifier's top ImageNet classes on its crop (``encode_with_classes``; the look-alike cue)
    classes: tuple[tuple[int, float], ...] | None = None
    #: how far its inside lies below its rim, metres (``perception/cavity.py``; the cavity cue)
    cavity_m: float | None = None


@dataclass(frozen=True)
class ScenePerception:
    """Everything perceived once per episode and shared by all methods."""

    obs: Observation
    rois: tuple[PerceivedROI, ...]
    target_body: int
    target_box: tuple[int, int, int, int] | None  # None: the target is not visible
    target_roi: int | None  # index of the ROI that is the target (best IoU >= detect_iou)
    three_d: bool
    three_d_detail: str
    #: the frame's raised pixels and world points, made once here: the grasp checks read them,
    #: and the release aims the chosen region's centre (``surface.object_centre``) at the zone
    raised: RaisedPoints


@contextlib.contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run a block with ``n`` torch intra-op threads (restored afterwards)."""
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def raster_order(rois: Sequence[Region]) -> list[Region]:
    """ROIs sorted by their first pixel in raster order, as the segmenter returns them.

    ``gt_rois`` lists the target first (scene order); grounding must not get that hint, not even
    through the stable tie-breaking of its ranking.
    """
    return sorted(rois, key=lambda r: int(np.argmax(r.mask.reshape(-1))))


def majority_body(obs: Observation, mask: BoolMask, bodies: Sequence[int]) -> int | None:
    """The scene body with the most pixels under ``mask`` (None if it covers none)."""
    if obs.seg is None:
        return None
    labels = obs.seg[mask]
    counts = {b: int(np.count_nonzero(labels == b)) for b in bodies}
    best = max(counts, key=lambda b: (counts[b], -b), default=None)
    return best if best is not None and counts[best] > 0 else None


def raised_mask(world: FloatArray, table_z: float, tolerance: float) -> BoolMask:
    """``[H, W]`` pixels whose point lies more than ``tolerance`` above the table (NaN: not),
    from the whole frame's world points (the evaluations that have them; the grasp checks and
    the size cue read ``RaisedPoints``, the same mask made from the heights alone)."""
    out: BoolMask = np.nan_to_num(world[..., 2], nan=table_z) > table_z + tolerance
    return out


def roi_colours(rgb: npt.NDArray[np.uint8], raised: BoolMask, roi: Region) -> tuple[float, ...] | None:
    """The ROI's colour shares (``perception/colours.py``) over the same raised pixels as
    ``RaisedPoints.within`` gives the grasp checks: the object's own surface, not the table
    around it."""
    x, y, w, h = roi.box_xywh
    box = (slice(y, y + h), slice(x, x + w))
    return measure_colours(rgb[box][roi.mask[box] & raised[box]])


def roi_cavity(obs: Observation, raised: BoolMask, roi: Region, table_z: float) -> float | None:
    """The ROI's open cavity (``perception/cavity.py``) over its raised pixels, the object's own
    surface as the grasp checks see it."""
    x, y, w, h = roi.box_xywh
    box = (slice(y, y + h), slice(x, x + w))
    return measure_cavity(obs.world_z()[box] - table_z, roi.mask[box] & raised[box])


ROBOT_STAGES = ("segment", "grasp_net", "encode", "grasp_checks")


def perceive(
    env: SimEnv, encoder: ImageEncoder, config: PipelineConfig, obs: Observation | None = None,
    *, timings: dict[str, float] | None = None, exclude: Callable[[TopDownGrasp], bool] | None = None,
    colours: bool = False, cavity: bool = False,
) -> ScenePerception:
    """Capture (unless ``obs`` is given), find ROIs and grasps, check them, embed the crops.

    ``env`` holds the built scene with the arm at home; nothing here moves it. ``timings``, if
    given, receives the wall time of the robot-side stages (``ROBOT_STAGES``; rendering and the
    simulator's ground truth excluded) for ``benchmarks/bench_perception.py``. ``exclude`` marks
    grasps grounding must not use (``retry``: those that already failed). ``colours``: measure
    each ROI's colour shares (only a grounder with the opt-in colour cue reads them); ``cavity``:
    each ROI's open cavity (the opt-in cavity cue's). Sets this
    process's numpy BLAS to one thread (``runtime/blas.py``: its spinning threads slow torch).
    """
    from ..blas import single_threaded_blas
    from ..encoders.conse import encode_with_classes
    from ..encoders.image import crop_box

    single_threaded_blas()
    scene = env.scene
    obs = obs if obs is not None else env.capture()
    bodies = [o.body_id for o in scene.objects]
    truth = gt_rois(obs, scene)
    target_body = scene.target.body_id
    target_gt = next((r for r in truth if r.label == target_body), None)
    with timed_stage(timings, "segment"):
        rois = raster_order(truth) if config.rois == "oracle" else segment(obs, config.segment).rois
    owners = [roi.label if config.rois == "oracle" else majority_body(obs, roi.mask, bodies)
              for roi in rois]
    k = config.rgb_scale
    sharp = env.capture_rgb(k) if k > 1 else obs.rgb  # a render: simulator work, not timed
    with torch_threads(config.torch_threads):
        with timed_stage(timings, "grasp_net"):
            raw = raw_candidates(scene, obs, rois, owners, config)
        with timed_stage(timings, "encode"):
            crops = [crop_box(sharp, tuple(v * k for v in roi.box_xywh)) for roi in rois]
            embeddings, classes = encode_with_classes(encoder, crops)
    table_z = scene.layout.table_z
    perceived: list[PerceivedROI] = []
    with timed_stage(timings, "grasp_checks"):
        raised = RaisedPoints.of(obs, table_z, config.fingers.height_tolerance)
        clear = config.pick.clearance
        surfaces = [Surfaces(raised.within(roi.mask), table_z, heights_around(raised, roi.mask, table_z, clear))
                    for roi in rois]
        checked = [usable_grasps(env, with_refinements(raw[i], s.material, obs, table_z, config), s, config, exclude,
                           partial(fallback_with_refinements, obs, rois[i], s.material, table_z, config))
                   for i, s in enumerate(surfaces)]
        extents = [measure_extents(s.material, table_z) for s in surfaces]
        shares = [roi_colours(obs.rgb, raised.mask, roi) if colours else None for roi in rois]
        cavities = [roi_cavity(obs, raised.mask, roi, table_z) if cavity else None for roi in rois]
    for i, (roi, body) in enumerate(zip(rois, owners, strict=True)):
        candidates, usable = checked[i]
        iou = box_iou(roi.box_xywh, target_gt.box_xywh) if target_gt is not None else 0.0
        perceived.append(PerceivedROI(roi, tuple(candidates), usable,
                                      np.asarray(embeddings[i], np.float32), body, iou, extents[i],
                                      shares[i], classes[i], cavities[i]))
    target_roi = None
    if perceived:
        best = max(range(len(perceived)), key=lambda i: (perceived[i].target_iou, -i))
        if perceived[best].target_iou >= config.detect_iou:
            target_roi = best
    assert obs.seg is not None
    target_mask = obs.seg == target_body
    target_surfaces = Surfaces(raised.within(target_mask), table_z,
                                heights_around(raised, target_mask, table_z, config.pick.clearance))
    three_d, why = three_d_metric(env, obs, perceived[target_roi] if target_roi is not None else None,
                            target_body, target_surfaces, config)
    return ScenePerception(
        obs=obs,
        rois=tuple(perceived),
        target_body=target_body,
        target_box=target_gt.box_xywh if target_gt is not None else None,
        target_roi=target_roi,
        three_d=three_d,
        three_d_detail=why,
        raised=raised,
    )


def frame_look(
    env: SimEnv, perception: ScenePerception, encoder: ImageEncoder, config: ActiveLookConfig,
    before_render: Callable[[], None] | None = None,
) -> ActiveLook:
    """The active look for ``perception``'s frame: each ROI aimed at by its raised depth points."""
    return ActiveLook(env.client, [perception.raised.within(r.roi.mask) for r in perception.rois],
                      env.scene.layout.table_z, encoder, config, before_render=before_render)


def grounding_rois(perception: ScenePerception) -> list[ROI]:
    """The grounder's view of the scene: boxes, usable grasps with scores, embeddings.

    Labels are ROI numbers, never object names: the grounder must not see the ground truth.
    """
    return [
        ROI(
            box_xywh=(float(r.roi.box_xywh[0]), float(r.roi.box_xywh[1]),
                      float(r.roi.box_xywh[2]), float(r.roi.box_xywh[3])),
            grasp_scores=[c.quality for c in r.usable],
            grasps=list(r.usable),
            image_embedding=r.embedding,
            mask=r.roi.mask,
            label=f"roi{i}",
            extents_m=r.extents_m,
            colours=r.colours,
            classes=r.classes,
            cavity_m=r.cavity_m,
        )
        for i, r in enumerate(perception.rois)
    ]
