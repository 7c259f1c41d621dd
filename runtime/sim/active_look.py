"""The active look: a second, closer view of the top candidates before the choice (opt-in).

Issue 10 asks for an on-arm camera that moves closer to the top candidates for a sharper view.
``craft eval recognition`` measured the view alone (a camera 0.35 m from the object at 45°, from
the robot's side): fused with the overhead crop it names rendered objects better (Lite1 + size
cue 46.4 / 73.9 top-1/5 against 42.3 / 71.6). Here the robot does it in the loop:

1. ground as usual on the overhead frame;
2. for each of the ``top_k`` lowest-energy ROIs not seen yet, place the look camera by the ROI's
   own depth points (the box centre of those points and of the same points dropped onto the
   table: no simulator identity), render its colour image, and cut the crop around those points
   projected into the view;
3. drop a look whose view of the ROI's top points is mostly hidden by something outside its
   footprint (``occluded_share``), encode the other crops in one batched pass (robot time, with
   the occlusion checks: the ``look_encode`` stage), mix each looked ROI's embedding with its
   overhead one (``weight`` on the look), and ground again.

The second grounding is the choice. ``top_k`` 2, ``scale`` 1 and ``weight`` 0.5 were chosen on
sim-dev by ``benchmarks/bench_active_look.py`` (``docs/results/active_look_settings.md``: the
best Detect of CRAFT-E and direct-LLM together; a sharper 2x render of the look named less). The
render is simulator work and not timed; so is the arm's move to the look pose, which is not
simulated: the camera is placed where a camera on the arm could be, not flown there, so the scene is untouched by the look.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np
import numpy.typing as npt

from .camera import Camera, render
from .stages import timed_stage

if TYPE_CHECKING:
    from ..encoders.image import ImageEncoder, UInt8Image
    from ..grounding.grounder import Grounding
    from ..perception.observation import Observation
    from ..perception.roi import ROI

FloatArray = npt.NDArray[np.float64]

#: fewer raised depth points than this and there is nothing to aim at (the ROI keeps its one view)
MIN_POINTS = 5


@dataclass(frozen=True)
class ActiveLookConfig:
    """Where the look camera goes and how its view enters ``p(o | r)``."""

    enabled: bool = False
    top_k: int = 2  # ROIs looked at per grounding: the lowest-energy ones
    distance: float = 0.35  # m from the ROI's centre (as in ``craft eval recognition``)
    elevation_deg: float = 45.0  # above the table, from the robot's side (-x)
    scale: int = 1  # the look's colour image at this many times the scene camera's resolution
    weight: float = 0.5  # the look's share of the mixed embedding
    #: a look in which more than this share of the ROI's top points is hidden behind something
    #: outside the ROI's own footprint sees the occluder, not the ROI: it is dropped (None)
    max_occluded: float = 0.3
    occlusion_margin: float = 0.02  # m nearer than the point before a pixel counts as hiding it
    self_margin: float = 0.01  # m around the ROI's footprint whose surfaces are its own

    def __post_init__(self) -> None:
        if self.top_k < 1:
            raise ValueError(f"active look top_k {self.top_k}: look at one ROI at least")
        if not 0.0 < self.weight <= 1.0:
            raise ValueError(f"active look weight {self.weight}: choose a share in (0, 1]")
        if not 0.0 <= self.max_occluded <= 1.0:
            raise ValueError(f"active look max_occluded {self.max_occluded}: choose a share in [0, 1]")
        if self.scale < 1 or self.distance <= 0.0:
            raise ValueError(f"active look scale {self.scale} / distance {self.distance}: both must be positive")

    def to_dict(self) -> dict[str, float | int]:
        return {"top_k": self.top_k, "distance_m": self.distance, "elevation_deg": self.elevation_deg,
                "scale": self.scale, "weight": self.weight, "max_occluded": self.max_occluded}


def standing_volume(points: FloatArray, table_z: float) -> FloatArray:
    """An ROI's overhead depth points and the same points dropped onto the table: the overhead
    camera sees only the top, but the object stands on the table, and the look sees its side too
    (aimed at the top alone, the crop cut off the lower 12 % of a standing bottle's pixels)."""
    if len(points) == 0:
        return points
    floor = points.copy()
    floor[:, 2] = table_z
    return np.vstack([points, floor])


def look_camera(points: FloatArray, config: ActiveLookConfig, base: Camera | None = None) -> Camera:
    """The look camera for an ROI's world ``points`` ``[m, 3]``: aimed at their box centre from
    ``config.distance`` away at ``config.elevation_deg``, on the robot's side of it (-x)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2
    e = math.radians(config.elevation_deg)
    eye = centre + config.distance * np.array([-math.cos(e), 0.0, math.sin(e)])
    cam = dataclasses.replace(base or Camera(), eye=(float(eye[0]), float(eye[1]), float(eye[2])),
                              target=(float(centre[0]), float(centre[1]), float(centre[2])), up=(0.0, 0.0, 1.0))
    return cam.scaled(config.scale)


def camera_frame(points: FloatArray, cam_to_world: FloatArray) -> FloatArray:
    """World ``points`` ``[m, 3]`` in the frame of a camera posed at ``cam_to_world`` (OpenCV)."""
    world_to_cam = np.linalg.inv(cam_to_world)
    return np.asarray(points @ world_to_cam[:3, :3].T + world_to_cam[:3, 3], dtype=np.float64)


def projected_box(camera: Camera, points: FloatArray) -> tuple[float, float, float, float] | None:
    """Pixel box ``(x, y, w, h)`` of ``points`` seen by ``camera`` (None: none in front of it)."""
    cam = camera_frame(points, camera.cam_to_world())
    cam = cam[cam[:, 2] > camera.near]
    if len(cam) == 0:
        return None
    k = camera.intrinsics
    u, v = k.project(cam).T
    x0, x1 = float(np.clip(u.min(), 0, k.width - 1)), float(np.clip(u.max(), 0, k.width - 1))
    y0, y1 = float(np.clip(v.min(), 0, k.height - 1)), float(np.clip(v.max(), 0, k.height - 1))
    return x0, y0, x1 - x0 + 1.0, y1 - y0 + 1.0


def occluded_share(view: Observation, top: FloatArray, config: ActiveLookConfig) -> float:
    """Share of an ROI's ``top`` points (its overhead depth points) hidden in the look ``view`` by
    a surface outside the ROI's own footprint (its points' xy box grown by ``self_margin``): a
    bowl's front rim hiding its inside is the ROI itself; a box between it and the camera is not."""
    cam = camera_frame(top, view.cam_to_world)
    k = view.intrinsics
    z = np.where(cam[:, 2] > 1e-6, cam[:, 2], np.nan)
    u, v = np.round(k.project(np.column_stack([cam[:, :2], z]))).T
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
    if not inside.any():
        return 1.0
    ui, vi = u[inside].astype(np.intp), v[inside].astype(np.intp)
    seen = view.depth[vi, ui].astype(np.float64)
    nearer = (seen > 0) & (seen < z[inside] - config.occlusion_margin)
    if not nearer.any():
        return 0.0
    hiders = view.points_world_at(vi[nearer] * k.width + ui[nearer])
    lo, hi = top[:, :2].min(axis=0) - config.self_margin, top[:, :2].max(axis=0) + config.self_margin
    own = np.all((hiders[:, :2] >= lo) & (hiders[:, :2] <= hi), axis=1)
    return float(np.count_nonzero(~own)) / float(len(top))


@dataclass(frozen=True)
class LookView:
    """One look, rendered: the view and where the ROI's standing volume falls in it."""

    view: Observation
    box: tuple[float, float, float, float]


def render_look(client: int, top: FloatArray, table_z: float, config: ActiveLookConfig) -> LookView | None:
    """Render the look at an ROI whose overhead depth points are ``top`` (simulator work); None
    when there are too few points to aim at."""
    if len(top) < MIN_POINTS:
        return None
    volume = standing_volume(top, table_z)
    camera = look_camera(volume, config)
    box = projected_box(camera, volume)
    if box is None:
        return None
    return LookView(render(client, camera), box)


def crop_look(look: LookView, top: FloatArray, config: ActiveLookConfig) -> UInt8Image | None:
    """The robot's part of a look: the crop around the ROI, or None when the view is occluded."""
    from ..encoders.image import crop_box

    if occluded_share(look.view, top, config) > config.max_occluded:
        return None
    return crop_box(look.view.rgb, look.box)


def look_crop(client: int, top: FloatArray, table_z: float, config: ActiveLookConfig) -> UInt8Image | None:
    """``render_look`` then ``crop_look``: the crop of one look, or None."""
    look = render_look(client, top, table_z, config)
    return crop_look(look, top, config) if look is not None else None


class Grounds(Protocol):
    def ground(self, verb: str, rois: Sequence[ROI]) -> Grounding: ...


@dataclass
class ActiveLook:
    """One frame's looks: renders and encodes each ROI at most once, grounds with them.

    ``points[i]`` are ROI ``i``'s raised world points from the overhead depth; the camera aims at
    and frames their ``standing_volume`` on the table at ``table_z``. ``before_render``
    puts the scene back to the frame's state first (the evaluation simulates other methods'
    picks between groundings). ``timings`` receives ``look_encode`` (robot time: the occlusion
    checks, the crops and the encoder batch) and ``look_render`` (the simulator's, for a caller
    that times around the look to take out).
    """

    client: int
    points: Sequence[FloatArray]
    table_z: float
    encoder: ImageEncoder
    config: ActiveLookConfig
    before_render: Callable[[], None] | None = None
    timings: dict[str, float] | None = None
    seen: dict[int, npt.NDArray[np.float32] | None] = field(default_factory=dict)

    def embeddings(self, indices: Sequence[int]) -> dict[int, npt.NDArray[np.float32] | None]:
        """The look's embedding of each ROI in ``indices`` (None: nothing to look at)."""
        new = [i for i in dict.fromkeys(indices) if i not in self.seen]
        if new:
            if self.before_render is not None:
                self.before_render()
            with timed_stage(self.timings, "look_render"):  # simulator work: not robot time
                views = {i: render_look(self.client, self.points[i], self.table_z, self.config) for i in new}
            with timed_stage(self.timings, "look_encode"):  # the robot's: occlusion checks, crops, one batch
                crops = {i: crop_look(v, self.points[i], self.config) if (v := views[i]) is not None else None
                         for i in new}
                wanted = [i for i in new if crops[i] is not None]
                found = self.encoder.embed_images([c for i in wanted if (c := crops[i]) is not None])
            for i in new:
                self.seen[i] = None
            for i, row in zip(wanted, found, strict=True):
                self.seen[i] = np.asarray(row, np.float32)
        return {i: self.seen[i] for i in indices}

    def ground(self, grounder: Grounds, verb: str, rois: Sequence[ROI]) -> tuple[Grounding, tuple[int, ...]]:
        """Ground, look at the top ``top_k`` ROIs, ground again with their mixed embeddings.

        Returns the second grounding and the ROIs looked at (in the first grounding's order)."""
        first = grounder.ground(verb, rois)
        top = tuple(r.index for r in first.ranked[: self.config.top_k])
        if not top:
            return first, ()
        looks = self.embeddings(top)
        w = self.config.weight
        mixed = list(rois)
        for i, emb in looks.items():
            if emb is not None:
                own = np.asarray(rois[i].image_embedding, np.float32)
                mixed[i] = dataclasses.replace(rois[i], image_embedding=np.asarray((1 - w) * own + w * emb, np.float32))
        return grounder.ground(verb, mixed), top


@dataclass(frozen=True)
class LookingGrounder:
    """A grounder whose every ``ground`` call includes the look (for ``choose.ground_lazily``)."""

    grounder: Grounds
    look: ActiveLook

    def ground(self, verb: str, rois: Sequence[ROI]) -> Grounding:
        return self.look.ground(self.grounder, verb, rois)[0]
