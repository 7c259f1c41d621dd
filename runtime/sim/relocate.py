"""Move a chosen grasp whose approach the depth frame shows blocked to a nearby spot of the same
object, before the pick is executed (opt-in: ``ClearanceConfig.relocate``, ``--relocate``).

Why: the README demo (`cut`, seed 0) and several dev misses are one failure. The knife lies
beside a tall cracker box; every network grasp of it closes towards the box, and the Franka
hand, 21 cm along its closing axis, comes to rest on the box 14 cm above the knife. As a filter
the clearance check (``sim/clearance.py``) turns such picks into honest ``no_grasp``s and, as a
preference, it has no other grasp to prefer: all of the knife's grasps are blocked. A person
would take the knife a few centimetres further along its handle, where the hand clears the box.

This does that, from the overhead depth frame only: the grasp is turned about its centre
(15°, 30°), then slid along the object, across its closing axis, by 2, 4 and 6 cm each way
(each slide also turned), nearest first; then the region's next network grasps are tried the
same way, best first; last, the grasp is nudged 1 and 2 cm along its closing axis each way
(each nudge also turned), the hand off the object's centre; last of all, the grasp itself and
every spot that fitted the fingers are tried again with the hand leaned 20° about its closing
axis, each way (``RelocateConfig.leans_deg``; the pads stay level, the wrist swings sideways:
beside a tall object a top-down grasp puts the CR3's wrist links on it, whatever the spot). A candidate must stand on the object (its centre has
object points within ``footing_radius``; its height is their highest), the fingers must fit
(``finger_check``) and the whole pick must be reachable with a clear approach
(``episode.pick_problems`` against the same height map). The first that passes replaces the
grasp; when none does the grasp is kept, so a pick is never dropped by this step.

It runs after grounding, on the chosen grasp only: the moved grasp keeps the network grasp's
quality (as a refinement does), so no choice changes; what changes is where the hand goes.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..grasp.geometry import TopDownGrasp, wrap_half_pi
from .clearance import HeightMap
from .fingers import FingerGeometry, SurfacePoints, finger_check

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class RelocateConfig:
    """Which nearby spots a blocked grasp may move to."""

    turns_deg: tuple[float, ...] = (15.0, 30.0)  # about the grasp's own centre, each sign
    shifts: tuple[float, ...] = (0.02, 0.04, 0.06)  # m along the object (across the closing axis), each sign
    # m along the closing axis, each sign (each also turned), tried last, after every other
    # spot and grasp: the hand off the object's centre, which the closing fingers push to the
    # middle. Blocked picks with no other clear spot (sim-val's `use/marker/0`, its hand on a can
    # beside the marker) had clear spots 2 cm along the closing axis, turned 29 degrees.
    nudges: tuple[float, ...] = (0.01, 0.02)
    footing_radius: float = 0.01  # m: object points this close to the new centre carry it
    min_footing_points: int = 5  # fewer: the centre is off the object
    # A slid centre must have object points on both sides along the slide, at least half the
    # footing radius away each: one that reached the object's edge (a ball's rim) leaves the
    # fingers a sliver to close on (sim-val's spin/racquetball/0 closed on nothing after a 4 cm
    # slide on a 5 cm ball).
    interior: bool = True
    # Degrees the hand leans about its closing axis, each sign, tried after every top-down spot
    # (the grasp first, then each spot that fitted the fingers, in the same order). Sim-dev's
    # ``cut/knife/1`` and ``tighten/adjustable_wrench/1`` had no clear top-down spot: the wrist
    # links come down on a 21 cm block beside them in every posture IK finds. Empty: never.
    leans_deg: tuple[float, ...] = (20.0,)

    def __post_init__(self) -> None:
        if any(not 0 < t < 90 for t in self.turns_deg):
            raise ValueError(f"relocation turns {self.turns_deg} must lie strictly between 0 and 90 degrees")
        if any(s <= 0 for s in (*self.shifts, *self.nudges)):
            raise ValueError(f"relocation shifts {self.shifts} and nudges {self.nudges} must be positive "
                             "(both signs are tried)")
        if any(not 0 < a < 45 for a in self.leans_deg):
            raise ValueError(f"relocation leans {self.leans_deg} must lie strictly between 0 and 45 degrees")
        if self.footing_radius <= 0 or self.min_footing_points < 1:
            raise ValueError("footing_radius must be > 0 and min_footing_points >= 1")


def _turns(cfg: RelocateConfig) -> list[float]:
    """Yaw offsets (radians) tried at every spot: none first, then each turn, each sign."""
    return [0.0] + [s * math.radians(t) for t in cfg.turns_deg for s in (1.0, -1.0)]


def _footing(moved: FloatArray, pts: FloatArray, cfg: RelocateConfig) -> FloatArray | None:
    """The object points carrying a centre moved to ``moved`` (within ``footing_radius``), or
    None when there are too few: the centre is off the object."""
    near = pts[np.linalg.norm(pts[:, :2] - moved[:2], axis=1) <= cfg.footing_radius]
    return near if len(near) >= cfg.min_footing_points else None


def relocations(pose: TopDownGrasp, material: FloatArray, cfg: RelocateConfig) -> Iterator[TopDownGrasp]:
    """Candidate spots, nearest first: turns about the centre, then every slide along the object
    (its turns right after it); only spots with object points under the centre, at their top."""
    centre = np.asarray(pose.position, dtype=np.float64)
    along = np.array([-math.sin(pose.yaw), math.cos(pose.yaw), 0.0])  # across the closing axis
    yaws = _turns(cfg)
    pts = np.asarray(material, dtype=np.float64)
    for yaw in yaws[1:]:
        yield TopDownGrasp(centre.copy(), wrap_half_pi(pose.yaw + yaw), pose.width_m)
    for shift in (s * d for d in cfg.shifts for s in (1.0, -1.0)):
        moved = centre + shift * along
        if len(pts) == 0:
            return
        near = _footing(moved, pts, cfg)
        if near is None:
            continue
        if cfg.interior:
            side = (near[:, :2] - moved[:2]) @ along[:2]
            if not (side.min() <= -cfg.footing_radius / 2 and side.max() >= cfg.footing_radius / 2):
                continue
        moved[2] = float(near[:, 2].max())
        for yaw in yaws:
            yield TopDownGrasp(moved.copy(), wrap_half_pi(pose.yaw + yaw), pose.width_m)


def nudged(pose: TopDownGrasp, material: FloatArray, cfg: RelocateConfig) -> Iterator[TopDownGrasp]:
    """``pose`` moved along its closing axis by each nudge, nearest first, each sign, each also
    turned as ``relocations`` turns; only spots with object points under the centre, at their top."""
    centre = np.asarray(pose.position, dtype=np.float64)
    closing = np.array([math.cos(pose.yaw), math.sin(pose.yaw), 0.0])
    pts = np.asarray(material, dtype=np.float64)
    if len(pts) == 0:
        return
    for shift in (s * d for d in cfg.nudges for s in (1.0, -1.0)):
        moved = centre + shift * closing
        near = _footing(moved, pts, cfg)
        if near is None:
            continue
        moved[2] = float(near[:, 2].max())
        for yaw in _turns(cfg):
            yield TopDownGrasp(moved.copy(), wrap_half_pi(pose.yaw + yaw), pose.width_m)


@dataclass(frozen=True)
class Relocation:
    """What ``relocate_if_blocked`` decided: the grasp to execute and why."""

    pose: TopDownGrasp
    moved: bool
    detail: str  # "" when the approach was clear; else what blocked it and what was done


def relocate_if_blocked(
    pose: TopDownGrasp,
    others: Iterable[TopDownGrasp],
    material: FloatArray,
    heights: HeightMap,
    problems: Callable[[TopDownGrasp, HeightMap], tuple[str | None, str | None]],
    tip_z_of: Callable[[TopDownGrasp], float],
    fingers: FingerGeometry,
    cfg: RelocateConfig,
    spot_problems: Callable[[TopDownGrasp, HeightMap], tuple[str | None, str | None]] | None = None,
) -> Relocation:
    """``pose`` if its approach is clear, else the first spot that fits the fingers and whose
    pick is reachable and clear (``problems``: ``episode.pick_problems`` bound to the env and pick
    settings), else ``pose`` unchanged (the detail says so). Spots, in order: ``relocations`` of
    ``pose``, then each of ``others`` (the region's next network grasps, best first; read only
    this far, so the caller may compute them lazily) and its relocations.

    ``spot_problems``: ``problems`` for the spots, where only "both None" counts, so it may stop
    at the first problem it finds (``pick_problems(approach_first=True)``: a blocked approach
    without the rest of the plan); default ``problems``."""
    _, touched = problems(pose, heights)
    if touched is None:
        return Relocation(pose, False, "")
    surface = SurfacePoints(material)

    def spots() -> Iterator[tuple[TopDownGrasp, str]]:
        yield from ((r, "") for r in relocations(pose, material, cfg))
        for k, other in enumerate(others, start=2):
            yield other, f"the region's network grasp #{k}"
            yield from ((r, f"the region's network grasp #{k}") for r in relocations(other, material, cfg))
        yield from ((r, "") for r in nudged(pose, material, cfg))

    def clear(spot: TopDownGrasp) -> bool:
        unreachable, blocked = (spot_problems or problems)(spot, heights)
        return unreachable is None and blocked is None

    def moved(spot: TopDownGrasp, source: str) -> Relocation:
        shift = float(np.linalg.norm(np.asarray(spot.position[:2]) - np.asarray(pose.position[:2])))
        turn = math.degrees(wrap_half_pi(spot.yaw - pose.yaw))
        where = f"took {source}: " if source else ""
        leaned = f", the hand leaned {math.degrees(spot.lean):+.0f}°" if spot.lean else ""
        return Relocation(spot, True, f"{touched}; {where}the grasp moved {100 * shift:.1f} cm on the "
                                      f"object and turned {turn:+.0f}°{leaned}, a clear approach")

    fitted: list[tuple[TopDownGrasp, str]] = [(pose, "")]  # the spots a lean may try, in order
    for spot, source in spots():
        if not finger_check(surface, spot, tip_z_of(spot), fingers)[0]:
            continue
        if clear(spot):
            return moved(spot, source)
        fitted.append((spot, source))
    leans = [s * math.radians(a) for a in cfg.leans_deg for s in (1.0, -1.0)]
    for spot, source in fitted:
        for lean in leans:
            if clear(spot._replace(lean=lean)):
                return moved(spot._replace(lean=lean), source)
    return Relocation(pose, False, f"{touched}; no nearby spot was clear, kept")
