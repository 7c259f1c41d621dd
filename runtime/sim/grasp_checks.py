"""The robot's checks of grasp candidates, and which candidate of a region grounding may use.

A candidate is usable when the object's section fits between the open fingers
(``fingers.finger_check``) and its whole pick has IK solutions (``episode.pick_problems``; with
``ClearanceConfig``, a clear approach too). Why a module of its own: which candidate a region
keeps is one decision, made the same way for every ROI of a frame (``perceive.perceive``) and
for the 3D metric, apart from how candidates are listed (``candidates``); tests replace
``finger_check`` and ``pick_problems`` here to test that decision without building a scene.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from ..grasp.geometry import TopDownGrasp
from ..perception.observation import Observation
from .candidates import GraspCandidate, tip_height
from .clearance import HeightMap
from .env import SimEnv
from .episode import pick_problems
from .fingers import finger_check

if TYPE_CHECKING:
    from .perceive import PerceivedROI
    from .pipeline import PipelineConfig

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Surfaces:
    """Depth points a grasp check needs: one object's surface above the table."""

    material: FloatArray  # [m, 3] world
    table_z: float
    heights: HeightMap | None = None  # the other objects' surfaces, for the clearance check


def check_candidate(
    env: SimEnv, candidate: GraspCandidate, surfaces: Surfaces, config: PipelineConfig,
    fit: bool, ik: bool, prefer: bool = False,
) -> GraspCandidate:
    """Run the requested checks on one candidate (fingers first: cheap; IK costs ~50 ms). With
    ``prefer`` (``ClearanceConfig.prefer``), a candidate that passes also gets ``blocked``: what
    its approach would touch, from the same plan as its IK check."""
    if candidate.pose is None:
        return replace(candidate, fits=False, reachable=False, detail="no valid depth at the centre", blocked=None)
    fits: bool | None = None
    detail = ""
    if fit:
        tip = tip_height(candidate.pose, config.pick, surfaces.table_z)
        fits, detail = finger_check(surfaces.material, candidate.pose, tip, config.fingers)
        if not fits:
            return replace(candidate, fits=False, reachable=None, detail=detail, blocked=None)
    reachable: bool | None = None
    blocked: str | None = None
    if ik or prefer:
        clear = config.pick.clearance
        obstacles = surfaces.heights if clear.enabled or prefer else None
        unreachable, touched = pick_problems(env, candidate.pose, config.pick, obstacles)
        if ik:
            why = unreachable or (touched if clear.enabled else None)
            reachable = why is None
            detail = why or ""
        if prefer and reachable is not False and touched is not None:
            blocked = touched
            detail = f"passes; not preferred: {touched}"
    return replace(candidate, fits=fits, reachable=reachable, detail=detail, blocked=blocked)


def usable_grasps(
    env: SimEnv, candidates: list[GraspCandidate], surfaces: Surfaces, config: PipelineConfig,
    exclude: Callable[[TopDownGrasp], bool] | None = None,
    more: Callable[[], list[GraspCandidate]] | None = None,
) -> tuple[list[GraspCandidate], tuple[GraspCandidate, ...]]:
    """(candidates with check results filled in, the grasps grounding may use).

    With checks on, only the best candidate that passes them is usable: the robot would execute
    exactly that one. With checks off, every candidate with a pose is. Candidates ``exclude``
    says yes to (a retry's grasps that already failed) are never usable. ``more`` gives further
    candidates (the fallback's), asked for and listed only when the fingers fit around none of
    ``candidates`` (an excluded one fitted once: it was executed).
    """
    def excluded(c: GraspCandidate) -> bool:
        return exclude is not None and c.pose is not None and exclude(c.pose)

    if not (config.fit_filter or config.ik_filter):
        return candidates, tuple(c for c in candidates if c.pose is not None and not excluded(c))
    prefer = config.pick.clearance.prefer and surfaces.heights is not None
    checked: list[GraspCandidate] = []
    chosen: GraspCandidate | None = None
    first_blocked: GraspCandidate | None = None  # prefer: the first that passes, if none is clear
    fitted = False  # the fingers fit around some candidate

    def check_all(listed: Iterable[GraspCandidate]) -> None:
        nonlocal chosen, first_blocked, fitted
        for c in listed:
            if chosen is not None:
                checked.append(c)
                continue
            if excluded(c):
                fitted = True
                checked.append(GraspCandidate(c.rect, c.pose, detail="tried before and failed", fallback=c.fallback))
                continue
            c = check_candidate(env, c, surfaces, config, config.fit_filter, config.ik_filter, prefer)
            fitted = fitted or c.fits is True
            if c.pose is not None and c.fits is not False and c.reachable is not False:
                if c.blocked is None:
                    chosen = c
                else:
                    first_blocked = first_blocked or c
            checked.append(c)

    check_all(candidates)
    if not fitted and chosen is None and first_blocked is None and more is not None:
        check_all(more())
    chosen = chosen or first_blocked
    return checked, (() if chosen is None else (chosen,))


def three_d_metric(
    env: SimEnv, obs: Observation, target: PerceivedROI | None, target_body: int,
    surfaces: Surfaces, config: PipelineConfig,
) -> tuple[bool, str]:
    """The 3D metric (see ``pipeline``'s module docstring) and why it failed."""
    if target is None:
        return False, "no ROI matches the target"
    if not target.candidates:
        return False, "no grasp candidate on the target's ROI"
    assert obs.seg is not None
    target_mask = obs.seg == target_body
    h, w = target_mask.shape
    reasons: list[str] = []
    for c in target.candidates:
        col = min(max(round(c.rect.center_xy[0]), 0), w - 1)
        row = min(max(round(c.rect.center_xy[1]), 0), h - 1)
        if not target_mask[row, col]:
            reasons.append("centre off the target")
            continue
        known = c.reachable is not None  # IK does not depend on the surfaces: reuse it
        checked = check_candidate(env, c, surfaces, config, fit=True, ik=not known)
        if checked.fits is False:
            reasons.append(checked.detail)
            continue
        if c.reachable if known else checked.reachable:
            return True, ""
        reasons.append(c.detail if known else checked.detail)
    return False, "; ".join(dict.fromkeys(reasons))
