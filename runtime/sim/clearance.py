"""Will the arm and hand hit the clutter on the way to a grasp? A check on the overhead depth.

IK says whether the arm can *reach* a grasp, not whether it gets there without touching anything.
On the dev scenes, 4 of the 8 picks that "closed on nothing" had never reached their grasp: the
forearm or the hand had come down on a tall box or bottle next to the target (pybullet contacts
at 21–24 cm), and the fingers closed in the air. A robot plans around what its depth camera
sees; this is that check, on the same overhead frame the ROIs came from:

* a **height map**: the highest surface seen in each 5 mm cell of the table (unseen cells count
  as free);
* the **hand** as boxes in the TCP frame (``HandSpec.clearance_boxes``, measured from the hand
  models by ``tests/test_clearance.py``): a box collides if any surface under its footprint
  rises above its bottom. Only the *other* objects count: how the fingers meet the target is
  ``finger_check``'s business (a first version that counted the target too rejected half of all
  targets, whose grasped point is lower than other parts of them under the 21 cm hand, while
  physics takes most of those grasps fine);
* the **arm** as points on the convex hull of each link's mesh from the upper arm to the flange
  (``arm_hull.py``: what pybullet collides), moved with the links' frames; a point collides if
  a surface within ``arm_spacing`` of it rises above it. (Capsules around the segments joining
  the joint frames, the first model, cut the corner the forearm turns to the wrist and missed a
  forearm coming down on a tall neighbour: ``arm_hull.py``.)

``obstructed`` checks the pre-grasp, the grasp and the joint path from the arm's current posture
to the pre-grasp, as ``execute_pick`` plays them. Nothing here uses the simulator's knowledge of
the objects: only depth pixels and the robot's own geometry.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from .surface import RaisedPoints

FloatArray = npt.NDArray[np.float64]
BoolMask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class HandBox:
    """A box of the hand in the TCP frame: ``|x| <= half_x`` across the closing axis,
    ``y_lo <= y <= y_hi`` along it (and the mirror image if ``mirrored``), ``z_lo..z_hi`` metres
    above the TCP."""

    half_x: float
    y_lo: float
    y_hi: float
    z_lo: float
    z_hi: float
    mirrored: bool = False


@dataclass(frozen=True)
class ClearanceConfig:
    """Resolution and margins of the check."""

    # Off by default, measured on the dev scenes (docs/results/sim_execution.md): as a hard filter it
    # turned the 4 misses it explains into honest ``no_grasp``s, but lost 9 successes (6 grasps it
    # rejected that physics completes, the hand pushing a light neighbour aside; 3 changed
    # choices) against 3 gained: 57 vs 63 successes of 105.
    enabled: bool = False
    # The same check as a preference instead of a filter: a region's grasp is the first that passes
    # the finger and IK checks *and* has a clear approach, else (none clear) the first that passes
    # the others, as without the check (``grasp_checks.usable_grasps``). Never leaves a region without grasp.
    prefer: bool = False
    # After grounding, move the chosen grasp to a nearby spot of the same object when its approach
    # is blocked (``sim/relocate.py``; kept when no spot is clear). On by default: on the 105 dev
    # episodes it moved 14 chosen grasps, turned the README demo's miss into a success and lost
    # no pick (docs/results/sim_execution.md).
    relocate: bool = True
    cell: float = 0.005  # m: height-map resolution
    sample_step: float = 0.01  # m between points sampled on hand boxes
    # m between points sampled on the arm links' hulls; a surface within this distance
    # (horizontally) of a point counts as under it
    arm_spacing: float = 0.01
    # m: surfaces this close below a box's bottom count as touching; negative: surfaces up to
    # this far above it do not (the hand would come down that much short of its planned depth,
    # which is harmless). When the finger tips were lowered from 4 to 2 mm above the table
    # (``PickConfig.table_clearance``), a surface the hand's body had cleared left the README
    # demo's knife without a clear spot for relocation (docs/results/sim_execution.md).
    margin: float = -0.002
    path_samples: int = 8  # configurations checked on the joint path to the pre-grasp
    # the arm links checked (the hand is the boxes): the upper arm, forearm and the wrist links
    arm_links: tuple[str, ...] = ("Link2", "Link3", "Link4", "Link5", "Link6")


class HeightMap:
    """The highest surface seen per cell of a regular xy grid (metres, world frame)."""

    def __init__(self, points: FloatArray, cell: float, floor_z: float) -> None:
        self.cell = cell
        self.floor_z = floor_z
        # a row is finite iff the sum of its columns is (metres: no overflow), without the
        # [n, 3] temporary of isfinite(points).all(axis=1); raised points are all finite: no copy
        finite = np.isfinite(points[:, 0] + points[:, 1] + points[:, 2])
        pts = points if finite.all() else points[finite]
        # column by column (the same values as on [n, 2] slices, which numpy reduces and
        # scatters several times slower: this map is built for every chosen pick's relocation check)
        xs, ys = pts[:, 0], pts[:, 1]
        self.origin: FloatArray = np.array([xs.min(), ys.min()]) if len(pts) else np.zeros(2)
        z: FloatArray = np.full((1, 1), floor_z)
        if len(pts):
            ix = np.floor((xs - self.origin[0]) / cell).astype(np.intp)
            iy = np.floor((ys - self.origin[1]) / cell).astype(np.intp)
            rows, cols = int(ix.max()) + 1, int(iy.max()) + 1
            flat = np.full(rows * cols, floor_z)
            np.maximum.at(flat, ix * cols + iy, pts[:, 2])  # one flat index: ~5x faster than a pair
            z = flat.reshape(rows, cols)
        self.z = z
        self.top = float(z.max())  # the highest surface anywhere (``floor_z`` when none)
        self._dilated: dict[int, FloatArray] = {0: z}

    def dilated(self, radius: float) -> FloatArray:
        """The map after a max filter over a ``2r`` square: the highest surface within ``r``."""
        k = max(0, math.ceil(radius / self.cell))
        if k not in self._dilated:
            self._dilated[k] = ndimage.maximum_filter(self.z, size=2 * k + 1, mode="nearest")
        return self._dilated[k]

    def heights(self, xy: FloatArray, radius: float = 0.0) -> FloatArray:
        """Highest surface within ``radius`` of each point ``[n, 2]`` (``floor_z`` off the map)."""
        grid = self.dilated(radius)
        idx = np.floor((xy - self.origin) / self.cell).astype(np.intp)
        inside = (idx >= 0).all(axis=1) & (idx[:, 0] < grid.shape[0]) & (idx[:, 1] < grid.shape[1])
        out = np.full(len(xy), self.floor_z)
        out[inside] = grid[idx[inside, 0], idx[inside, 1]]
        return out


def heights_around(
    surface: RaisedPoints, target_mask: BoolMask, table_z: float, cfg: ClearanceConfig,
) -> HeightMap | None:
    """The height map of an overhead frame's points above the table (``surface``), the target's
    own pixels (``target_mask``: its ROI) left out; None when the check is off (as a filter and
    as a preference; relocation builds its own for the chosen region only: ``heights_excluding``)."""
    return heights_excluding(surface, target_mask, table_z, cfg) if cfg.enabled or cfg.prefer else None


def heights_excluding(
    surface: RaisedPoints, target_mask: BoolMask, table_z: float, cfg: ClearanceConfig,
) -> HeightMap:
    """The height map of the surfaces above the table outside ``target_mask`` (see
    ``heights_around``), whatever the check's switches say."""
    return HeightMap(surface.outside(target_mask), cfg.cell, table_z)


@functools.cache
def _box_bottom_points(box: HandBox, step: float) -> FloatArray:
    """``[n, 2]`` (x, y) samples of a box's footprint in the TCP frame, both sides if mirrored
    (read-only, made once per box and step: every pose of every check samples the same points)."""
    xs = np.linspace(-box.half_x, box.half_x, max(2, math.ceil(2 * box.half_x / step) + 1))
    ys = np.linspace(box.y_lo, box.y_hi, max(2, math.ceil((box.y_hi - box.y_lo) / step) + 1))
    gx, gy = np.meshgrid(xs, ys)
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    out = np.concatenate([pts, pts * np.array([1.0, -1.0])]) if box.mirrored else pts
    out.flags.writeable = False
    return out


def hand_hits(
    tcp_xyz: FloatArray, yaw: float, boxes: Sequence[HandBox], obstacles: HeightMap, cfg: ClearanceConfig,
) -> str | None:
    """Which hand box a top-down TCP at ``tcp_xyz`` with closing axis ``yaw`` would touch."""
    closing = np.array([math.cos(yaw), math.sin(yaw)])
    across = np.array([-closing[1], closing[0]])
    for box in boxes:
        local = _box_bottom_points(box, cfg.sample_step)  # [n, 2] (x across, y along)
        xy = tcp_xyz[:2] + local[:, :1] * across + local[:, 1:] * closing
        seen = obstacles.heights(xy)
        bottom = float(tcp_xyz[2]) + box.z_lo
        if np.any(seen > bottom - cfg.margin):
            return _hand_message(box, float(seen.max()), bottom)
    return None


def _part(box: HandBox) -> str:
    """What a box of the hand is called in a verdict: a finger (the mirrored boxes) or the hand."""
    return "a finger" if box.mirrored else "the hand"


def _hand_message(box: HandBox, highest: float, bottom: float) -> str:
    return f"{_part(box)} would touch a surface {100 * (highest - bottom):.1f} cm above its bottom"


def _arm_message(link: str, height: float) -> str:
    return f"the arm ({link}) would touch a surface {100 * height:.1f} cm high"


def first_hit(
    tcp_xyz: FloatArray, yaws: Sequence[float], arm_points: FloatArray, arm_parts: Sequence[tuple[str, int]],
    boxes: Sequence[HandBox], obstacles: HeightMap, cfg: ClearanceConfig,
) -> str | None:
    """What the first of several poses would touch: ``hand_hits`` then ``arm_hits`` of each pose
    in order (TCPs ``[C, 3]``, closing axes ``[C]``, the arm links' hull points ``[C, N, 3]``,
    link by link as ``arm_parts`` (name, count) says), the same answer, to the character, as
    calling them pose by pose (``tests/test_clearance.py``).

    Why: a pick's approach is checked at ~9 poses, each with a handful of boxes and arm links,
    and each of those was a height-map lookup of its own: numpy's per-call overhead, not
    arithmetic, was most of the chosen pick's check on the robot's path. Here every box's
    points at every pose are one lookup, and every arm point of every pose another: the same
    elementwise arithmetic on the same points, so the same heights and the same verdict."""
    c = len(yaws)
    if c == 0:
        return None
    tcp = np.asarray(tcp_xyz, dtype=np.float64)
    closing = np.array([[math.cos(y), math.sin(y)] for y in yaws])  # [C, 2]
    across = np.stack([-closing[:, 1], closing[:, 0]], axis=1)  # [C, 2]
    hand_seen: list[tuple[FloatArray, FloatArray]] = []  # per box: heights [C, n], bottoms [C]
    for box in boxes:
        local = _box_bottom_points(box, cfg.sample_step)  # [n, 2]
        xy = tcp[:, None, :2] + local[None, :, :1] * across[:, None, :] + local[None, :, 1:] * closing[:, None, :]
        seen = obstacles.heights(xy.reshape(-1, 2)).reshape(c, len(local))
        hand_seen.append((seen, tcp[:, 2] + box.z_lo))
    arm = np.asarray(arm_points, dtype=np.float64)
    # how far a surface rises above each point; only points below the highest surface on the map
    # (less the margin) can be touched, and most of the arm is above it: only those are looked up
    arm_seen = np.full(arm.shape[:2], obstacles.floor_z)
    arm_over = np.full(arm.shape[:2], -np.inf)
    low = arm[:, :, 2] < obstacles.top - cfg.margin
    if low.any():
        seen_low = obstacles.heights(arm[low][:, :2], cfg.arm_spacing)
        arm_seen[low] = seen_low
        arm_over[low] = seen_low - arm[low][:, 2]
    for i in range(c):
        for box, (seen, bottom) in zip(boxes, hand_seen, strict=True):
            if np.any(seen[i] > bottom[i] - cfg.margin):
                return _hand_message(box, float(seen[i].max()), float(bottom[i]))
        why = _arm_verdict(arm_over[i], arm_seen[i], arm_parts, cfg)
        if why is not None:
            return why
    return None


def _arm_verdict(over: FloatArray, seen: FloatArray, parts: Sequence[tuple[str, int]],
                 cfg: ClearanceConfig) -> str | None:
    """The first link (in ``parts`` order) one of whose points has a surface rising more than
    ``-cfg.margin`` above it, with the highest such surface under that link."""
    start = 0
    for name, count in parts:
        part_over = over[start:start + count]
        if np.any(part_over > -cfg.margin):
            return _arm_message(name, float(seen[start:start + count][part_over > -cfg.margin].max()))
        start += count
    return None


def arm_hits(points: FloatArray, parts: Sequence[tuple[str, int]], obstacles: HeightMap,
             cfg: ClearanceConfig) -> str | None:
    """Would the arm links, sampled at ``points`` ``[N, 3]`` (link by link as ``parts`` says,
    ``arm_hull.hull_points_world``), touch a surface seen under them?"""
    pts = np.asarray(points, dtype=np.float64)
    seen = obstacles.heights(pts[:, :2], cfg.arm_spacing)
    return _arm_verdict(seen - pts[:, 2], seen, parts, cfg)


@functools.cache
def _box_points(box: HandBox, step: float) -> FloatArray:
    """``[n, 3]`` samples of a box's whole volume in the TCP frame (z down the approach axis, as
    the TCP's own frame has it: a box ``z_lo..z_hi`` above the TCP lies at ``-z_hi..-z_lo``),
    both sides if mirrored: the footprint ``_box_bottom_points`` samples, at each height. Read-only,
    made once per box and step."""
    footprint = _box_bottom_points(box, step)  # [n, 2]
    zs = np.linspace(-box.z_lo, -box.z_hi, max(2, math.ceil((box.z_hi - box.z_lo) / step) + 1))
    out = np.concatenate([np.column_stack([footprint, np.full(len(footprint), z)]) for z in zs])
    out.flags.writeable = False
    return out


def leaned_first_hit(
    tcp_xyz: FloatArray, rotations: FloatArray, arm_points: FloatArray, arm_parts: Sequence[tuple[str, int]],
    boxes: Sequence[HandBox], obstacles: HeightMap, cfg: ClearanceConfig,
) -> str | None:
    """``first_hit`` for a hand that is not pointing straight down (a leaned grasp,
    ``robot.tool_quat``): each box's whole volume is sampled and turned with the TCP
    (``rotations`` ``[C, 3, 3]``), and a point touches when a surface seen under it rises above
    it (less the margin). A top-down box's lowest points are its bottom face, so for a top-down
    hand this is ``first_hit``'s verdict; it is only used for leaned picks, whose pads are
    level but whose hand is not."""
    tcp = np.asarray(tcp_xyz, dtype=np.float64)
    for i in range(len(tcp)):
        for box in boxes:
            world = tcp[i] + _box_points(box, cfg.sample_step) @ np.asarray(rotations[i]).T
            over = obstacles.heights(world[:, :2]) - world[:, 2]
            if np.any(over > -cfg.margin):
                return f"{_part(box)} (leaned) would touch a surface {100 * float(over.max()):.1f} cm above it"
        pts = np.asarray(arm_points[i], dtype=np.float64)
        seen = obstacles.heights(pts[:, :2], cfg.arm_spacing)
        why = _arm_verdict(seen - pts[:, 2], seen, arm_parts, cfg)
        if why is not None:
            return why
    return None
