"""One RGB-D frame from a real camera to the object and grasp for a verb, and why.

The testbed's robot perceives with ``sim.choose.perceive_frame``: class-agnostic segmentation
on the table plane, one grasp-network pass, one batched ConSE pass over the crops, the depth
cues (each region's extents for the size cue, its open cavity for the cavity cue) and the
finger check of its grasps. That function reads the frame alone, so a real robot's frame runs
the same code here, with nothing of the simulator: no render, no ground truth, no robot model.

What a frame alone cannot give is left out and said so: there is no arm to plan, so no IK check
of the pick (``ground_lazily`` is told every grasp is reachable) and no check of the arm's links
against what the camera sees. The hand is checked: when the frame's depth shows that the open
hand would come down on a neighbour at the chosen grasp, the grasp is moved along its object
to a clear spot by the testbed's own search (``sim/relocate.py``, with the hand's boxes alone
and no leaned hand, which exists to swing the arm's wrist aside). The grasp returned is top-down
along the table's normal.

Heights need the table. With the camera's pose (``cam_to_world``, z up) the table is the
height of the fitted plane in that frame; without it, the frame is made from the plane itself
(``pose_from_plane``): z along its normal, towards the camera, the table at z = 0. Extents,
cavities and the finger checks measure heights above the table and lengths along it, so either
way they are the same to the plane fit's error.
"""

from __future__ import annotations

import io
import json
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ..files import atomic_write_bytes
from .encoders.image import ImageEncoder
from .grasp.geometry import CameraIntrinsics, TopDownGrasp
from .grounding.grounder import Grounder, Grounding
from .grounding.settings import GroundingSettings
from .kb.bundle import Bundle
from .perception.observation import Observation
from .perception.plane import Plane
from .perception.segment import SegmentConfig, table_plane
from .perception.workspace import Workspace
from .sim.candidates import GraspCandidate
from .sim.choose import LazyROI, ground_lazily, perceive_frame, relocate_lazily
from .sim.clearance import HandBox, HeightMap, hand_hits
from .sim.episode import PickConfig
from .sim.hands import FINGERTIP_BELOW_TCP, hand_spec
from .sim.pipeline import PipelineConfig, relocate_search
from .sim.relocate import RelocateConfig
from .sim.surface import RaisedPoints

FloatArray = npt.NDArray[np.float64]


class FrameError(ValueError):
    """A frame that cannot be perceived (shapes, no depth, no table); the message says which,
    and ``part`` which input is at fault (``rgb``, ``depth``, ``camera``, ``cam_to_world``, ``mask``,
    ``workspace``), so that ``craft perceive`` names the file and ``POST /perceive`` the field."""

    def __init__(self, message: str, part: str = "depth") -> None:
        super().__init__(message)
        self.part = part


class FrameTooLargeError(FrameError):
    """A depth image of more pixels than the caller decodes, judged from its header (a PNG of a
    few KB can claim gigapixels); ``POST /perceive`` answers it with 413."""

    def __init__(self, width: int, height: int, limit: int) -> None:
        super().__init__(f"depth is {width}x{height} pixels; at most {limit} pixels are decoded (downscale "
                         "both images, and the camera's fx, fy, cx, cy with them)")
        self.limit = limit


#: Frames smaller than this on a side hold no object region (``SegmentConfig.min_area`` is 150 px).
MIN_FRAME_SIDE = 32
#: Frames larger than this (4096 x 4096, as ``craft serve`` decodes) take minutes and gigabytes to
#: perceive (5000 x 5000: 47 s, 4.6 GB), and no depth camera sends one.
MAX_FRAME_PIXELS = 4096 * 4096
#: metres per depth unit beyond this are no unit of a depth image (``POST /perceive`` bounds it too)
MAX_DEPTH_SCALE = 10.0
#: The median depth reading a depth camera gives (metres). Outside it the depth is in another unit:
#: millimetres read as metres put the table 700 m away, and the clearance map of a scene that
#: size asked for 51 GiB (a MemoryError, or a 500 from the server).
DEPTH_RANGE_M = (0.02, 20.0)
#: Fields of view (degrees) a pinhole camera may have across the image. A focal length outside
#: gives points kilometres apart or pixels apart: fx = 1e9 ran 106 s into a 2.4 TiB allocation.
FOV_RANGE_DEG = (2.0, 160.0)
#: The least share of the depth readings on the fitted plane for it to be the table: a depth
#: camera's frame of a tabletop has most (the testbed's: 78%; with 2 cm of noise: 9%), random
#: depth about 1%, on which the plane fit still "found" a table and a grasp.
MIN_TABLE_SHARE = 0.05
#: Largest angle between the table's normal and ``cam_to_world``'s z axis (degrees): beyond it
#: the pose is not z up (or the largest plane is a wall), and heights above the table are wrong.
MAX_TABLE_TILT_DEG = 45.0
#: ``cam_to_world``'s rotation may be off orthonormal by this much (rounded calibration files).
RIGID_TOLERANCE = 1e-2
MAX_POSE_M = 1e6  # metres: a camera's distance from its world's origin (as ``POST /perceive``)
#: How a camera's frame is segmented: as the testbed's robot does, and a region whose raised points
#: form clusters apart on the table is split (``segment.split_on_table``): a camera at an angle sees
#: near objects overlap far ones (``benchmarks/bench_frame_views.py``). The testbed's evaluations
#: keep it off, as their published tables were made.
FRAME_SEGMENT = SegmentConfig(split_on_table=True)


@dataclass(frozen=True)
class FrameGrounding:
    """What ``ground_frame`` found: the grounding, the chosen grasp, the regions as perceived,
    and the world frame used (``pose_from_table``: made from the table plane, not given)."""

    grounding: Grounding
    grasp: GraspCandidate | None
    rois: list[LazyROI]
    cam_to_world: FloatArray
    table_z: float
    pose_from_table: bool
    #: "" when the chosen grasp's hand is clear of the other objects (or unchecked), else what it
    #: would touch and where the grasp moved, or that it was kept (``relocate.relocate_if_blocked``)
    relocation: str = ""

    def grasp_dict(self) -> dict[str, Any] | None:
        """The chosen grasp in pixels and in the frame's world (metres, yaw in degrees), for JSON;
        None without one."""
        g = self.grasp
        if g is None or g.pose is None:
            return None
        return {
            "center_px": [round(g.rect.center_xy[0], 1), round(g.rect.center_xy[1], 1)],
            "angle_deg": round(math.degrees(g.rect.angle_rad), 1),
            "width_px": round(g.rect.width_px, 1),
            "quality": round(g.quality, 4),
            "position_m": [round(float(v), 4) for v in g.pose.position],
            "yaw_deg": round(math.degrees(g.pose.yaw), 1),
            "opening_m": round(g.pose.width_m, 4),
            "fallback": g.fallback,
        }

    def frame_dict(self) -> dict[str, Any]:
        """What the frame's perception adds to the grounding's JSON: the grasp, its relocation,
        the regions found and the world frame used."""
        return {"grasp": self.grasp_dict(), "relocation": self.relocation, "regions": len(self.rois),
                "table_z_m": round(self.table_z, 5),
                "cam_to_world": [[round(float(v), 6) for v in row] for row in self.cam_to_world],
                "pose_from_table": self.pose_from_table}


NPY_MAGIC = b"\x93NUMPY"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def decode_depth(data: bytes, scale: float | None = None, max_pixels: int | None = None) -> npt.NDArray[np.float32]:
    """A depth image in metres from a ``.npy`` file's bytes (H x W numbers) or a PNG's (16-bit, as
    a RealSense's raw millimetres are saved); integer depth needs ``scale``, metres per unit.
    ``FrameError`` says what is wrong: another format, another shape, no scale; ``FrameTooLargeError``
    a PNG of more than ``max_pixels``, read from its header before any pixel is decoded."""
    if scale is not None and not (math.isfinite(scale) and 0 < scale <= MAX_DEPTH_SCALE):
        raise FrameError(f"a depth scale of {scale:g}: metres per depth unit must be a positive number up to "
                         f"{MAX_DEPTH_SCALE:g}, e.g. 0.001 for millimetres")
    if data.startswith(NPY_MAGIC):
        try:
            raw = np.load(io.BytesIO(data), allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise FrameError(f"not a readable .npy array ({exc})") from None
    elif data.startswith(PNG_MAGIC):
        from PIL import Image, UnidentifiedImageError

        try:
            with Image.open(io.BytesIO(data)) as img:
                if max_pixels is not None and img.width * img.height > max_pixels:
                    raise FrameTooLargeError(img.width, img.height, max_pixels)
                if img.mode == "P":  # a palette's indices would be read as distances
                    raise FrameError("depth is a palette PNG (colour indices, not distances); save the "
                                     "camera's depth as a 16-bit grayscale PNG")
                raw = np.asarray(img)
        except (OSError, UnidentifiedImageError, Image.DecompressionBombError) as exc:
            raise FrameError(f"not a readable PNG ({exc})") from None
    else:
        raise FrameError("depth must be a .npy array of metres or a 16-bit PNG (with a depth scale)")
    if raw.ndim != 2 or not (np.issubdtype(raw.dtype, np.integer) or np.issubdtype(raw.dtype, np.floating)):
        raise FrameError(f"depth must be an H x W array of numbers, got shape {raw.shape} ({raw.dtype})")
    if max_pixels is not None and raw.size > max_pixels:
        raise FrameTooLargeError(raw.shape[1], raw.shape[0], max_pixels)
    if scale is None:
        if np.issubdtype(raw.dtype, np.integer):
            raise FrameError(f"depth is in integer units ({raw.dtype}); say how many metres one unit is, "
                             "e.g. a depth scale of 0.001 for millimetres")
        scale = 1.0
    with np.errstate(over="ignore"):  # beyond float32: inf, no reading (frame_observation)
        metres: npt.NDArray[np.float32] = (raw.astype(np.float64) * scale).astype(np.float32)
    return metres


def camera_problem(intrinsics: CameraIntrinsics) -> tuple[str, str] | None:
    """(what is wrong, which input: ``camera``) when ``intrinsics`` cannot be the pinhole model
    of a camera that took a frame of its size, else None: a focal length giving a field of view
    outside ``FOV_RANGE_DEG``, or a principal point outside the image. Either spreads the frame's
    points over kilometres or squeezes them into a pixel, and the grasp search then allocates
    terabytes or finds nothing without saying why."""
    k = intrinsics
    typical = CameraIntrinsics.realsense_d435(k.width, k.height)
    for name, focal, side, usual in (("fx", k.fx, k.width, typical.fx), ("fy", k.fy, k.height, typical.fy)):
        if not (math.isfinite(focal) and focal > 0):
            return f"{name} {focal:g}: a focal length is a positive number of pixels", "camera"
        fov = math.degrees(2.0 * math.atan(side / (2.0 * focal)))
        if not FOV_RANGE_DEG[0] <= fov <= FOV_RANGE_DEG[1]:
            return (f"{name} {focal:g} gives a {fov:.3g} degree field of view across the image's {side} pixels, "
                    f"no camera's ({FOV_RANGE_DEG[0]:g} to {FOV_RANGE_DEG[1]:g}): give the focal length in pixels of "
                    f"this image (a RealSense D435's is {usual:g} at this size)"), "camera"
    for name, centre, side in (("cx", k.cx, k.width), ("cy", k.cy, k.height)):
        if not (math.isfinite(centre) and 0.0 <= centre <= side):
            return (f"{name} {centre:g} lies outside the image (0 to {side} pixels): the principal point is in "
                    f"pixels of this image, near its centre ({side / 2:g})"), "camera"
    return None


def pose_problem(pose: FloatArray) -> str | None:
    """What makes the finite 4 x 4 ``pose`` no camera pose (None: it is one): a last row other
    than [0, 0, 0, 1], a rotation part that scales, shears, mirrors or is singular (beyond
    ``RIGID_TOLERANCE``), or a translation beyond ``MAX_POSE_M``. Each used to give heights and a
    grasp position that were silently wrong (a 2x scale put the table at -0.7 m)."""
    if np.abs(pose[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-6:
        return (f"cam_to_world's last row is {[round(float(v), 6) for v in pose[3]]}, not [0, 0, 0, 1]: give "
                "the camera's pose as a rigid transform")
    rotation = pose[:3, :3]
    off = float(np.abs(rotation @ rotation.T - np.eye(3)).max())
    det = float(np.linalg.det(rotation))
    if off > RIGID_TOLERANCE or det < 0:
        return (f"cam_to_world's upper-left 3 x 3 is no rotation (R R^T is off the identity by {off:.3g}, "
                f"det {det:.3g}): give the camera's pose as a rotation and a translation in metres, with no "
                "scale, shear or mirror")
    if np.abs(pose[:3, 3]).max() > MAX_POSE_M:
        return (f"cam_to_world's translation {[float(v) for v in pose[:3, 3]]} lies beyond {MAX_POSE_M:g} m: "
                "give it in metres")
    return None


def pose_from_plane(plane: Plane) -> FloatArray:
    """``cam_to_world`` [4, 4] of a world frame on ``plane`` (camera frame, oriented so the camera
    has positive distance): z along its normal towards the camera, the origin under the camera,
    x the camera's x axis laid on the plane. The plane is z = 0 in it."""
    z = np.asarray(plane.normal, dtype=np.float64)
    origin = -plane.offset * z  # the plane's point nearest the camera's centre
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    if np.linalg.norm(x) < 1e-6:  # the camera's x axis along the normal: use its y axis
        x = np.array([0.0, 1.0, 0.0]) - z[1] * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rotation = np.stack([x, y, z])  # rows: the world axes in camera coordinates
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = -rotation @ origin
    return out


def _table(obs: Observation, config: SegmentConfig) -> Plane:
    """The frame's table plane (``segment.table_plane``), or a ``FrameError`` saying why none."""
    try:
        return table_plane(obs, config)
    except ValueError as exc:
        raise FrameError(f"no table plane in the depth image ({exc})") from exc


def frame_observation(
    rgb: npt.NDArray[np.uint8], depth: npt.NDArray[np.floating], intrinsics: CameraIntrinsics,
    cam_to_world: npt.ArrayLike | None = None, config: SegmentConfig | None = None,
) -> tuple[Observation, float, bool]:
    """(the frame, the table's height in its world frame, whether that frame was made from the
    table plane): ``observe_frame`` without the plane."""
    obs, table_z, from_table, _ = observe_frame(rgb, depth, intrinsics, cam_to_world, config)
    return obs, table_z, from_table


def observe_frame(
    rgb: npt.NDArray[np.uint8], depth: npt.NDArray[np.floating], intrinsics: CameraIntrinsics,
    cam_to_world: npt.ArrayLike | None = None, config: SegmentConfig | None = None,
) -> tuple[Observation, float, bool, Plane]:
    """(the frame, the table's height in its world frame, whether that frame was made from the
    table plane, that plane in the camera frame: segmentation reads it rather than fitting it
    again). Depth is metres along the optical axis; 0, NaN and negative values are no
    reading. With ``cam_to_world`` the table's height is the mean world height of the plane's
    inliers.

    A frame that no camera could have taken is refused with a ``FrameError`` naming the input at
    fault (``FrameError.part``) rather than perceived into a wrong answer: a side under
    ``MIN_FRAME_SIDE``, a camera model outside ``camera_problem``'s bounds, depth whose median
    is outside ``DEPTH_RANGE_M`` (another unit), a non-rigid pose, a plane holding under
    ``MIN_TABLE_SHARE`` of the readings (no table), or one tilted beyond ``MAX_TABLE_TILT_DEG``
    from the pose's z axis (z down, or not the table)."""
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise FrameError(f"the colour image must be H x W x 3, got {rgb.shape}", "rgb")
    if depth.shape != rgb.shape[:2]:
        raise FrameError(f"depth is {depth.shape[0]}x{depth.shape[1]} pixels, the colour image "
                         f"{rgb.shape[0]}x{rgb.shape[1]}: give both from one registered frame")
    if (intrinsics.width, intrinsics.height) != (rgb.shape[1], rgb.shape[0]):
        raise FrameError(f"the camera model is {intrinsics.width}x{intrinsics.height}, the image "
                         f"{rgb.shape[1]}x{rgb.shape[0]}", "camera")
    if min(rgb.shape[:2]) < MIN_FRAME_SIDE:
        raise FrameError(f"the frame is {rgb.shape[1]}x{rgb.shape[0]} pixels, too small to hold a table and an "
                         f"object (at least {MIN_FRAME_SIDE}x{MIN_FRAME_SIDE}): give the camera's whole frame", "rgb")
    problem = camera_problem(intrinsics)
    if problem is not None:
        raise FrameError(*problem)
    metres = np.asarray(depth, dtype=np.float32)
    metres = np.where(np.isfinite(metres) & (metres > 0), metres, np.float32(0.0)).astype(np.float32)
    valid = metres > 0
    if not np.any(valid):
        raise FrameError("the depth image has no valid reading (every pixel is 0, NaN or negative)")
    median = float(np.median(metres[valid]))
    if median > DEPTH_RANGE_M[1]:
        raise FrameError(f"the depth's median reading is {median:g} m, farther than a depth camera sees "
                         f"({DEPTH_RANGE_M[1]:g} m): float depth is read as metres; if it holds millimetres, "
                         "give a depth scale of 0.001")
    if median < DEPTH_RANGE_M[0]:
        raise FrameError(f"the depth's median reading is {median:g} m, nearer than a depth camera sees "
                         f"({DEPTH_RANGE_M[0]:g} m): depth must be metres (times the depth scale, if given); "
                         "check its unit")
    pose: FloatArray | None = None
    if cam_to_world is not None:
        pose = np.asarray(cam_to_world, dtype=np.float64)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise FrameError(f"cam_to_world must be a finite 4 x 4 matrix, got shape {pose.shape}", "cam_to_world")
        why = pose_problem(pose)
        if why is not None:
            raise FrameError(why, "cam_to_world")
    colour = np.ascontiguousarray(rgb, dtype=np.uint8)
    cfg = config or SegmentConfig()
    obs = Observation(colour, metres, intrinsics, np.eye(4) if pose is None else pose)
    plane = _table(obs, cfg)
    on_table = valid & (np.abs(plane.distance(obs.points_camera())) <= cfg.plane.inlier_threshold)
    share = np.count_nonzero(on_table) / np.count_nonzero(valid)
    if share < MIN_TABLE_SHARE:
        raise FrameError(f"no table plane in the depth image: the largest plane holds {share:.1%} of the depth "
                         f"readings (at least {MIN_TABLE_SHARE:.0%} expected): the camera must see the table as "
                         "the largest flat surface, with depth in metres registered to the colour image")
    if pose is None:
        return Observation(colour, metres, intrinsics, pose_from_plane(plane)), 0.0, True, plane
    up = float(pose[:3, :3] @ np.asarray(plane.normal, dtype=np.float64) @ np.array([0.0, 0.0, 1.0]))
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, up))))
    if tilt > MAX_TABLE_TILT_DEG:
        raise FrameError(f"the table plane's normal (towards the camera) is {tilt:.0f} degrees from cam_to_world's z axis"
                         f"{' (z points down)' if up < 0 else ''}: cam_to_world must map the camera frame "
                         "(x right, y down, z forward) to a world frame with z up, or be left out to measure "
                         "heights from the table plane (else the largest flat surface seen is not the table)",
                         "cam_to_world")
    heights = obs.world_z()[on_table]
    if heights.size == 0:
        raise FrameError("no pixel lies on the table plane")
    return obs, float(np.mean(heights)), False, plane


def frame_keep(
    obs: Observation, pose_from_table: bool, mask: npt.NDArray[np.bool_] | None = None,
    workspace: Workspace | None = None,
) -> npt.NDArray[np.bool_] | None:
    """The pixels where objects may be found (``perception/workspace.py``): those of ``mask``
    (H x W, True or non-zero: perceive) whose depth point lies inside ``workspace`` (an x-y box, and a
    ceiling, in the world frame of the camera's given pose); None when neither is given. A
    ``FrameError`` names the ``mask`` or the ``workspace`` when it does not fit the frame, needs
    a pose the frame was not given, or leaves no depth reading.

    Only segmentation reads it: the table is fitted, and the grasp network, the finger checks and
    the hand's approach see, the whole frame, so the robot's base next to an object is still an
    obstacle to the hand, and an object reaching out of the box keeps only its part inside."""
    if mask is None and workspace is None:
        return None
    keep = np.asarray(obs.depth > 0)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.dtype != np.bool_:  # 0/255 or 0/1 numbers, as an image library gives a mask: non-zero perceives
            mask = mask != 0
        if mask.shape != keep.shape:
            raise FrameError(f"the mask is {mask.shape[1] if mask.ndim > 1 else '?'}x{mask.shape[0]} pixels, the "
                             f"frame {keep.shape[1]}x{keep.shape[0]}: give a mask of the frame's size", "mask")
        keep &= mask
        if not keep.any():
            raise FrameError("the mask leaves no depth reading: its non-zero pixels are those perceived", "mask")
    if workspace is not None:
        if pose_from_table:
            raise FrameError("a workspace is an x-y box in the world frame of the camera's pose: give cam_to_world "
                             "too, or limit the frame with a mask instead", "workspace")
        keep &= workspace.contains(obs.points_world())
        if not keep.any():
            raise FrameError(f"no depth reading lies inside the workspace (x {workspace.x_min:g} to "
                             f"{workspace.x_max:g}, y {workspace.y_min:g} to {workspace.y_max:g}"
                             f"{'' if workspace.z_max is None else f', z up to {workspace.z_max:g}'} m in "
                             "cam_to_world's world frame): check its bounds against the pose", "workspace")
    return keep


def hand_problems(
    table_z: float, pick: PickConfig, boxes: Sequence[HandBox],
) -> Callable[[TopDownGrasp, HeightMap], tuple[str | None, str | None]]:
    """The pick check of a frame without a robot model, in ``relocate_if_blocked``'s form
    (unreachable, blocked): would the open hand, at the grasp's depth (the testbed's
    ``episode._approach``: the insertion depth, never below the table clearance), touch what the
    depth frame shows of the other objects? The hand comes straight down, so its boxes are
    lowest at the grasp; a leaned hand needs the arm's model and counts as unreachable."""
    lowest = table_z + FINGERTIP_BELOW_TCP + pick.table_clearance

    def check(pose: TopDownGrasp, heights: HeightMap) -> tuple[str | None, str | None]:
        if pose.lean != 0.0:
            return "a leaned hand needs the arm's model", None
        tcp = np.array([float(pose.position[0]), float(pose.position[1]),
                        max(float(pose.position[2]) - pick.insertion_depth, lowest)])
        why = hand_hits(tcp, float(pose.yaw), boxes, heights, pick.clearance)
        return None, None if why is None else f"approach blocked: {why}"

    return check


@dataclass(frozen=True)
class PerceivedFrame:
    """One frame perceived (``perceive``), ready to ground any verb (``choose``): the frame in
    its world coordinates, the table's height there, whether that frame was made from the table
    plane, the regions, and the configuration they were perceived with."""

    obs: Observation
    table_z: float
    pose_from_table: bool
    rois: list[LazyROI]
    config: PipelineConfig


def perceive(
    encoder: ImageEncoder, config: PipelineConfig, rgb: npt.NDArray[np.uint8], depth: npt.NDArray[np.floating],
    intrinsics: CameraIntrinsics, cam_to_world: npt.ArrayLike | None = None, *, colours: bool = False,
    cavity: bool = False, mask: npt.NDArray[np.bool_] | None = None, workspace: Workspace | None = None,
) -> PerceivedFrame:
    """The torch side of ``ground_frame``: the frame's regions with their grasps (checked as
    grounding asks), embeddings and depth cues (``colours``, ``cavity``: measure them, for a
    grounder that reads them); regions only within ``mask`` and ``workspace`` (``frame_keep``). A
    server runs this in a worker thread and ``choose`` on its event loop, where its grounders live."""
    if config.grasp == "oracle" or config.rois == "oracle":
        raise FrameError("a frame has no ground truth: use predicted ROIs and a grasp backend", "config")
    cfg = replace(config, rgb_scale=1, ik_filter=False)
    obs, table_z, from_table, plane = observe_frame(rgb, depth, intrinsics, cam_to_world, cfg.segment)
    keep = frame_keep(obs, from_table, mask, workspace)
    rois = perceive_frame(obs, obs.rgb, table_z, encoder, cfg, colours=colours, cavity=cavity, keep=keep,
                          plane=plane)
    return PerceivedFrame(obs, table_z, from_table, rois, cfg)


def choose(grounder: Grounder, frame: PerceivedFrame, verb: str, hand_boxes: Sequence[HandBox] = ()) -> FrameGrounding:
    """Ground ``verb`` over a perceived frame's regions; the grasp is the chosen region's first
    that the fingers fit around (no IK: see the module docstring), moved to a clear spot of its
    object when ``hand_boxes`` (the hand's, ``sim.hands.HandSpec.clearance_boxes``; empty:
    unchecked) would touch another object there and the configuration's
    ``pick.clearance.relocate`` is on. Raises the grounder's errors (an unknown verb)."""
    obs, table_z, cfg, rois = frame.obs, frame.table_z, frame.config, frame.rois
    choice = ground_lazily(grounder, verb, rois, lambda _grasp: True)
    grasp = choice.grasp if isinstance(choice.grasp, GraspCandidate) else None
    why = ""
    chosen = choice.grounding.chosen
    if grasp is not None and chosen is not None and hand_boxes:
        check = hand_problems(table_z, cfg.pick, hand_boxes)

        def search(mask: npt.NDArray[np.bool_], raised: RaisedPoints, material: FloatArray,
                   picked: GraspCandidate, others: Iterator[TopDownGrasp]) -> tuple[GraspCandidate, str]:
            return relocate_search(obs, mask, raised, material, picked, others, cfg, table_z, check, check,
                                   RelocateConfig(leans_deg=()))

        moved, why = relocate_lazily(cfg, obs, table_z, rois[chosen.index], grasp, search)
        grasp = moved if isinstance(moved, GraspCandidate) else grasp
    return FrameGrounding(choice.grounding, grasp, rois, obs.cam_to_world, table_z, frame.pose_from_table, why)


def ground_frame(
    grounder: Grounder, encoder: ImageEncoder, config: PipelineConfig, verb: str,
    rgb: npt.NDArray[np.uint8], depth: npt.NDArray[np.floating], intrinsics: CameraIntrinsics,
    cam_to_world: npt.ArrayLike | None = None, hand_boxes: Sequence[HandBox] = (), *,
    mask: npt.NDArray[np.bool_] | None = None, workspace: Workspace | None = None,
) -> FrameGrounding:
    """Perceive one frame as the testbed's robot does (``perceive``: ``perceive_frame``) and
    ground ``verb`` over its regions (``choose``), regions only within ``mask`` and
    ``workspace`` (``frame_keep``). Crops come from ``rgb`` itself (the testbed's are from a
    sharper render: ``PipelineConfig.rgb_scale``)."""
    grounder.check_verb(verb)  # an unknown verb before the two network passes, not after
    frame = perceive(encoder, config, rgb, depth, intrinsics, cam_to_world,
                     colours=grounder.colour_cue_active, cavity=grounder.cavity_cue_active, mask=mask,
                     workspace=workspace)
    return choose(grounder, frame, verb, hand_boxes)


#: the files ``save_frame`` writes after its stem
FRAME_SUFFIXES = ("_rgb.png", "_depth.npy", "_camera.json")


def save_frame(folder: Path, stem: str, obs: Observation) -> tuple[Path, Path, Path]:
    """Write ``obs`` as ``craft perceive`` reads a camera's frame: ``<stem>_rgb.png``,
    ``<stem>_depth.npy`` (metres, float32) and ``<stem>_camera.json`` (the pinhole model and
    ``cam_to_world``), each whole or not at all. The simulator's body ids are not written: a
    camera has none."""
    from PIL import Image

    png = io.BytesIO()
    Image.fromarray(obs.rgb).save(png, format="PNG")
    npy = io.BytesIO()
    np.save(npy, np.asarray(obs.depth, dtype=np.float32), allow_pickle=False)
    k = obs.intrinsics
    camera = {"width": k.width, "height": k.height, "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
              "cam_to_world": [[float(v) for v in row] for row in obs.cam_to_world]}
    rgb_path, depth_path, camera_path = (folder / f"{stem}{suffix}" for suffix in FRAME_SUFFIXES)
    paths = (rgb_path, depth_path, camera_path)
    for path, data in zip(paths, (png.getvalue(), npy.getvalue(), (json.dumps(camera, indent=1) + "\n").encode()),
                          strict=True):
        atomic_write_bytes(path, data)
    return paths


class FramePerceiver:
    """What a robot's process builds once and calls per frame: the bundle's grounder over the
    objects it may meet, the image encoder, the grasp network and the hand's finger geometry.

    ``vocabulary``: the objects (default: the KB's; the size cue needs a typical size for every
    one, as the testbed's 62 names have); ``gripper``: ``panda`` (the Franka hand) or
    ``robotiq_2f85``; ``grasp``: ``grconvnet``, ``ggcnn`` or ``ggcnn2``; ``workspace``: the x-y box
    of the table the robot picks from, in its camera pose's world frame (every frame then needs
    ``cam_to_world``). Bad choices raise ``ValueError`` naming them; a vocabulary the bundle cannot
    read raises the grounder's error.
    """

    def __init__(self, bundle: Bundle, *, vocabulary: Sequence[str] | None = None, gripper: str = "panda",
                 grasp: str = "grconvnet", threads: int = 1, settings: GroundingSettings | None = None,
                 workspace: Workspace | None = None) -> None:
        from .evaluation.sim_eval import default_encoder
        from .sim.episode import sim_configs
        from .sim.pipeline import NETWORK_SOURCES

        if grasp not in NETWORK_SOURCES:
            raise ValueError(f"grasp network {grasp!r}: choose one of {', '.join(NETWORK_SOURCES)}")
        _, pick, fingers = sim_configs(gripper, wrist_look=False)
        self.hand_boxes = hand_spec(gripper).clearance_boxes
        base = settings or GroundingSettings()
        if vocabulary is not None:
            base = base.model_copy(update={"vocabulary": tuple(vocabulary)})
        self.grounder = Grounder(bundle, base)
        self.encoder = default_encoder(threads)
        if self.encoder.text_encoder_id != bundle.manifest.text_encoder.id:
            raise ValueError(f"the bundle's text encoder is {bundle.manifest.text_encoder.id}, the image "
                             f"encoder embeds into {self.encoder.text_encoder_id}; use a matching bundle")
        self.config = PipelineConfig(grasp=grasp, torch_threads=threads, pick=pick, fingers=fingers,  # type: ignore[arg-type]
                                     segment=FRAME_SEGMENT)
        self.workspace = workspace

    def ground(self, verb: str, rgb: npt.NDArray[np.uint8], depth: npt.NDArray[np.floating],
               intrinsics: CameraIntrinsics, cam_to_world: npt.ArrayLike | None = None, *,
               mask: npt.NDArray[np.bool_] | None = None) -> FrameGrounding:
        """``ground_frame`` of one frame (depth in metres, 0 = no reading), the hand's approach checked,
        within the perceiver's workspace and ``mask`` (H x W, True: perceive; e.g. the robot's own body
        filtered out)."""
        return ground_frame(self.grounder, self.encoder, self.config, verb, rgb, depth, intrinsics, cam_to_world,
                            self.hand_boxes, mask=mask, workspace=self.workspace)
