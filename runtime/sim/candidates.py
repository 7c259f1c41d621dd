"""Grasp candidates of one region: a grasp source's rectangles with their world poses, the
antipodal fallback's, and the refinements that fit them to this hand.

Why a module of its own: both paths list a region's candidates from here, the evaluation's
(``perceive.perceive``, which checks them all up front) and the robot's (``choose``, which checks
them one at a time as grounding asks), so the two lists cannot drift apart. What a candidate
needs from the robot to be usable (IK, clearance) is ``grasp_checks``' business.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from ..grasp.geometry import Grasp2D, TopDownGrasp, pose_to_rect, rect_to_pose
from ..perception.observation import Observation
from ..perception.roi import Region
from .episode import PickConfig
from .fallback import fallback_grasps
from .fingers import SurfacePoints, finger_check
from .oracle import oracle_grasp
from .scene import Scene

if TYPE_CHECKING:
    from .pipeline import PipelineConfig

FloatArray = npt.NDArray[np.float64]
BoolMask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class GraspCandidate:
    """One raw grasp of an ROI: the image rectangle, its world pose, and the robot's checks.

    ``fits``/``reachable`` are None when not checked (checks stop at the first usable grasp).
    """

    rect: Grasp2D
    pose: TopDownGrasp | None  # None: no valid depth under the centre
    fits: bool | None = None
    reachable: bool | None = None
    detail: str = ""
    blocked: str | None = None  # ClearanceConfig.prefer: what the approach of a passing grasp would touch
    fallback: bool = False  # from the antipodal fallback (sim/fallback.py), not the network

    @property
    def quality(self) -> float:
        return float(self.rect.quality)


def tip_height(pose: TopDownGrasp, pick: PickConfig, table_z: float) -> float:
    """Height of the finger tips at the grasp, as ``execute_pick`` will place them."""
    from .robot_urdf import FINGERTIP_BELOW_TCP

    tcp = max(float(pose.position[2]) - pick.insertion_depth,
              table_z + FINGERTIP_BELOW_TCP + pick.table_clearance)
    return tcp - FINGERTIP_BELOW_TCP


def _oracle_rect(
    scene: Scene, obs: Observation, body: int, mask: BoolMask
) -> list[tuple[Grasp2D, TopDownGrasp]]:
    """The oracle grasp of ``body`` as a rectangle (quality 1) if its centre lies on ``mask``."""
    pose = oracle_grasp(scene, body)
    if pose is None:
        return []
    rect = pose_to_rect(pose, obs.intrinsics, obs.cam_to_world, quality=1.0)
    h, w = mask.shape
    col = min(max(round(rect.center_xy[0]), 0), w - 1)
    row = min(max(round(rect.center_xy[1]), 0), h - 1)
    return [(rect, pose)] if mask[row, col] else []


def _with_poses(obs: Observation, rects: Sequence[Grasp2D]) -> list[GraspCandidate]:
    """Candidates with their world poses (None where the centre has no valid depth)."""
    out: list[GraspCandidate] = []
    for rect in rects:
        try:
            pose: TopDownGrasp | None = rect_to_pose(rect, obs.depth, obs.intrinsics, obs.cam_to_world)
        except ValueError:
            pose = None
        out.append(GraspCandidate(rect, pose))
    return out


def raw_candidates(
    scene: Scene | None, obs: Observation, rois: Sequence[Region], bodies: Sequence[int | None],
    config: PipelineConfig, *, fused: bool = False,
) -> list[list[GraspCandidate]]:
    """Grasp candidates of every ROI, best first, with their world poses.

    A grasp network runs once over the crop holding all the ROIs and each ROI takes the peaks
    of the shared maps on its mask (``predict_grasps_rois``; ``fused``: its inference rewrite,
    ``grasp.fused``); the oracle is asked per body (of ``scene``, which only the oracle reads:
    None for a frame without a simulator).
    """
    if config.grasp == "oracle":
        if scene is None:
            raise ValueError("the oracle grasp source reads the simulator's scene; a frame alone has none")
        return [[] if body is None else
                 [GraspCandidate(r, pose) for r, pose in _oracle_rect(scene, obs, body, roi.mask)]
                 for roi, body in zip(rois, bodies, strict=True)]
    from ..grasp.predict import predict_grasps_rois

    rects = predict_grasps_rois(
        config.grasp, obs.rgb, obs.depth, [roi.mask for roi in rois], config.max_grasps,
        intrinsics=obs.intrinsics, min_quality=config.min_quality, fused=fused,
    )
    return [_with_poses(obs, r) for r in rects]


def fallback_candidates(obs: Observation, roi: Region, config: PipelineConfig) -> list[GraspCandidate]:
    """The antipodal fallback's grasps on one region (``sim/fallback.py``), best first; empty when
    the config has no fallback."""
    if not config.uses_fallback:
        return []
    x, y, w, h = roi.box_xywh
    rects = fallback_grasps(obs.depth, roi.mask, (int(x), int(y), int(w), int(h)), obs.intrinsics,
                            max_opening_m=2 * config.fingers.half_opening,
                            min_clearance_m=config.fallback.clearance(config.fingers.clearance),
                            max_grasps=config.max_grasps,
                            config=config.fallback)
    return [replace(c, fallback=True) for c in _with_poses(obs, rects)]


def iter_fallback_fitting(
    obs: Observation, roi: Region, material: FloatArray, table_z: float, config: PipelineConfig,
) -> Iterator[GraspCandidate]:
    """The fallback's grasps on one region that the fingers fit around, with refinements, best
    first (the sampler runs when this is called): the robot's list of a region the fingers fit
    around none of the network's grasps on (``choose.LazyROI.fallback``), as ``fallback_with_refinements``
    continues the evaluation's."""
    return iter_fitting_with_refinements(fallback_candidates(obs, roi, config), material, obs, table_z, config)


def with_refinements(
    candidates: Sequence[GraspCandidate], material: FloatArray, obs: Observation, table_z: float,
    config: PipelineConfig,
) -> list[GraspCandidate]:
    """``candidates`` with, right after each one the fingers do not fit around, its refinement
    (``refine.refine``: turned, or moved onto a wall) if one fits. Both the evaluation's path and
    the robot's (``fitting_with_refinements``) use this one list, so they check the same grasps in
    the same order."""
    return [c for c, _ in _refined(candidates, SurfacePoints(material), obs, table_z, config)]


def fitting_with_refinements(
    candidates: Sequence[GraspCandidate], material: FloatArray, obs: Observation, table_z: float,
    config: PipelineConfig,
) -> list[GraspCandidate]:
    """The grasps of ``with_refinements`` that have a pose and that the fingers fit around
    (every one with a pose when ``config.fit_filter`` is off), in order: the robot's list."""
    return list(iter_fitting_with_refinements(candidates, material, obs, table_z, config))


def iter_fitting_with_refinements(
    candidates: Sequence[GraspCandidate], material: FloatArray, obs: Observation, table_z: float,
    config: PipelineConfig,
) -> Iterator[GraspCandidate]:
    """``fitting_with_refinements`` one grasp at a time: a grasp is checked (and refined) only
    when the one before it has been taken, so the robot, which needs each ROI's first fitting
    grasp, checks one or two grasps per ROI instead of all of them.

    Each grasp is checked once, on one ``SurfacePoints``: a network grasp's check is the one that
    decided whether to refine it, and a refinement fits by construction (``refine`` returns only
    grasps ``finger_check`` accepts at the same tip height)."""
    surface = SurfacePoints(material)

    def fits(c: GraspCandidate, known: bool | None) -> bool:
        if c.pose is None:
            return False
        if not config.fit_filter:
            return True
        if known is not None:
            return known
        return finger_check(surface, c.pose, tip_height(c.pose, config.pick, table_z), config.fingers)[0]

    return (c for c, known in _refined(candidates, surface, obs, table_z, config) if fits(c, known))


def _refined(
    candidates: Sequence[GraspCandidate], surface: SurfacePoints, obs: Observation, table_z: float,
    config: PipelineConfig,
) -> Iterator[tuple[GraspCandidate, bool | None]]:
    """``with_refinements``' grasps in order, each with whether the fingers fit around it, or
    None where that was not checked (refinement off, or no pose); lazily."""
    from .refine import refine

    if not (config.refine.enabled and config.fit_filter):
        yield from ((c, None) for c in candidates)
        return

    def tip_z_of(pose: TopDownGrasp) -> float:
        return tip_height(pose, config.pick, table_z)

    for c in candidates:
        if c.pose is None:
            yield c, None
            continue
        fits = finger_check(surface, c.pose, tip_z_of(c.pose), config.fingers)[0]
        yield c, fits
        if fits:
            continue
        better = refine(c.pose, surface, tip_z_of, config.fingers, config.refine)
        if better is None:
            continue
        try:
            rect = pose_to_rect(better, obs.intrinsics, obs.cam_to_world, quality=c.quality,
                                length_px=c.rect.length_px)
        except ValueError:
            continue
        yield GraspCandidate(rect, better, fallback=c.fallback), True


def fallback_with_refinements(
    obs: Observation, roi: Region, material: FloatArray, table_z: float, config: PipelineConfig,
) -> list[GraspCandidate]:
    """The fallback's grasps of one region with their refinements: the evaluation's list
    continued (and the robot's relocation spots), as ``iter_fallback_fitting`` is the robot's."""
    return with_refinements(fallback_candidates(obs, roi, config), material, obs, table_z, config)
