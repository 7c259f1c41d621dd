"""Lazy IK in grounding (issue 10, item 4): the same choice as checking every grasp up front.

Why: the robot's path plans the pick's IK only for the grasps grounding chooses; that is only
allowed because the choice cannot differ from the eager pipeline's (IK of every ROI's grasps
first, then ground). Checked on random scenes with ties, unreachable grasps and ROIs left with
none, against an energy of the grounder's form (each ROI's own term + ``-log`` best score).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np

from craft_e.runtime.perception.roi import ROI
from craft_e.runtime.sim.choose import LazyROI, ground_lazily


@dataclass(frozen=True)
class _Chosen:
    index: int


@dataclass(frozen=True)
class _Grounding:
    chosen: _Chosen | None


class _Grounder:
    """``Grounder.ground``'s ranking: ROIs without grasps excluded, energy = the ROI's own term
    + alpha * -log(best score), lowest first, stable ties."""

    def __init__(self, own: Sequence[float], alpha: float = 1.0) -> None:
        self.own, self.alpha, self.calls = list(own), alpha, 0

    def ground(self, verb: str, rois: Sequence[ROI]) -> _Grounding:
        self.calls += 1
        usable = [i for i, r in enumerate(rois) if len(r.grasp_scores) and max(r.grasp_scores) > 0]
        if not usable:
            return _Grounding(None)
        total = np.array([self.own[i] - self.alpha * math.log(max(rois[i].grasp_scores)) for i in usable],
                         dtype=np.float32)
        return _Grounding(_Chosen(usable[int(np.argsort(total, kind="stable")[0])]))


def _scene(rng: np.random.Generator) -> tuple[list[list[tuple[str, float]]], set[str], list[float]]:
    """Per ROI its fitting grasps (name, score) best first, the reachable names, own energies."""
    rois, reachable = [], set()
    for i in range(int(rng.integers(1, 7))):
        scores = sorted(np.round(rng.uniform(0.2, 1.0, int(rng.integers(0, 5))), 1).tolist(), reverse=True)
        grasps = [(f"r{i}g{j}", float(s)) for j, s in enumerate(scores)]
        reachable |= {name for name, _ in grasps if rng.random() < 0.6}
        rois.append(grasps)
    own = np.round(rng.uniform(-1.0, 1.0, len(rois)), 1).tolist()  # rounded: ties happen
    return rois, reachable, own


def _eager(rois: list[list[tuple[str, float]]], reachable: set[str], own: list[float]) -> str | None:
    usable = [next(((n, s) for n, s in grasps if n in reachable), None) for grasps in rois]
    views = [ROI((0.0, 0.0, 1.0, 1.0), [u[1]] if u else [], [u[0]] if u else []) for u in usable]
    chosen = _Grounder(own).ground("cut", views).chosen
    if chosen is None:
        return None
    grasp = usable[chosen.index]
    return None if grasp is None else grasp[0]


def test_lazy_choice_equals_the_eager_choice() -> None:
    rng = np.random.default_rng(0)
    saved = 0
    for _ in range(500):
        rois, reachable, own = _scene(rng)
        lazy = [LazyROI((0.0, 0.0, 1.0, 1.0), np.zeros(4, np.float32), [n for n, _ in g], [s for _, s in g])
                for g in rois]
        asked: list[object] = []

        def ik(grasp: object, reachable: set[str] = reachable, asked: list[object] = asked) -> bool:
            asked.append(grasp)
            return grasp in reachable

        choice = ground_lazily(_Grounder(own), "cut", lazy, ik)  # type: ignore[arg-type]
        assert choice.grasp == _eager(rois, reachable, own)
        assert len(asked) == len(set(asked)) == choice.plans  # each grasp planned at most once
        saved += sum(len(g) for g in rois) - choice.plans
    assert saved > 0  # and it does skip IK plans


def test_a_second_grounder_reuses_what_ik_ruled_out() -> None:
    lazy = [LazyROI((0.0, 0.0, 1.0, 1.0), np.zeros(4, np.float32), ["a0", "a1"], [0.9, 0.5]),
            LazyROI((0.0, 0.0, 1.0, 1.0), np.zeros(4, np.float32), ["b0"], [0.8])]
    asked: list[object] = []

    def ik(grasp: object) -> bool:
        asked.append(grasp)
        return grasp != "a0"

    first = ground_lazily(_Grounder([0.0, 0.0]), "cut", lazy, ik)  # type: ignore[arg-type]
    assert first.grasp == "b0" and asked == ["a0", "b0"]  # a0 unreachable: a1 (0.5) loses to b0
    second = ground_lazily(_Grounder([0.0, 5.0]), "cut", lazy, ik)  # type: ignore[arg-type]
    assert second.grasp == "a1" and asked == ["a0", "b0", "a1"] and second.plans == 1


def test_the_fallback_is_deferred_and_the_choice_still_equals_the_eager_one() -> None:
    """ROIs the fingers fit around no network grasp on get the fallback's list (``LazyROI.fallback``),
    scored anywhere in (0, 1]: the eager path uses it whenever the network's list is empty; the lazy
    path ranks such an ROI with a perfect placeholder and runs the sampler only when that wins."""
    rng = np.random.default_rng(1)
    ran = skipped = 0
    for _ in range(500):
        rois, reachable, own = _scene(rng)
        fallbacks: list[list[tuple[str, float]]] = []
        for i, grasps in enumerate(rois):
            scores = sorted(np.round(rng.uniform(0.05, 1.0, int(rng.integers(0, 4))), 1).tolist(), reverse=True)
            extra = [(f"f{i}g{j}", float(s)) for j, s in enumerate(scores)] if not grasps else []
            reachable |= {name for name, _ in extra if rng.random() < 0.6}
            fallbacks.append(extra)
        calls: list[int] = []

        def run(i: int, extra: list[tuple[str, float]], calls: list[int] = calls) -> Iterator[_Fitting]:
            calls.append(i)
            return iter([_Fitting(n, s) for n, s in extra])

        lazy = [LazyROI((0.0, 0.0, 1.0, 1.0), np.zeros(4, np.float32), [n for n, _ in g], [s for _, s in g],
                        fallback=partial(run, i, fallbacks[i]) if not g else None)
                for i, g in enumerate(rois)]

        def ik(grasp: object, reachable: set[str] = reachable) -> bool:
            name = grasp.name if isinstance(grasp, _Fitting) else grasp
            return name in reachable

        choice = ground_lazily(_Grounder(own), "cut", lazy, ik)  # type: ignore[arg-type]
        got = choice.grasp.name if isinstance(choice.grasp, _Fitting) else choice.grasp
        eager_lists = [g or f for g, f in zip(rois, fallbacks, strict=True)]
        assert got == _eager(eager_lists, reachable, own)
        assert len(calls) == len(set(calls))  # the sampler runs once per ROI at most
        ran += len(calls)
        skipped += sum(1 for g in rois if not g) - len(calls)
    assert ran > 0 and skipped > 0  # it runs when needed, and is skipped when it cannot matter


@dataclass(frozen=True)
class _Fitting:
    """A fallback grasp as ``LazyROI`` pulls it from an iterator: named, with its score."""

    name: str
    quality: float
