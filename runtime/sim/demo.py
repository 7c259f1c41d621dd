"""Oracle pick episodes with per-phase wall times: the testbed's smoke test and speed check.

``python -m craft_e.runtime.sim.demo mustard_bottle knife --seeds 0 1`` builds a scene per
(target, seed), renders it, segments it, checks that a predicted ROI covers the target, grasps the
target with the oracle grasp and reports the outcome. Wall time is measured for reporting only;
nothing in the episode depends on it.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from dataclasses import dataclass

from ..perception.roi import best_box_matches
from ..perception.segment import segment
from .env import SimEnv
from .episode import Outcome, execute_pick
from .oracle import gt_rois, oracle_grasp
from .scene import SceneSpec

DEFAULT_DISTRACTORS = ("apple", "spoon", "tuna_fish_can", "soap", "fork")


@dataclass(frozen=True)
class PhaseTimes:
    """Seconds of wall time per phase of one episode."""

    reset: float
    capture: float
    segment: float
    grasp: float
    pick: float

    @property
    def total(self) -> float:
        return self.reset + self.capture + self.segment + self.grasp + self.pick


@dataclass(frozen=True)
class DemoRecord:
    """One episode's result."""

    target: str
    seed: int
    outcome: Outcome
    target_box_iou: float  # best predicted-ROI IoU with the target's GT box
    steps: int
    times: PhaseTimes
    detail: str


def run_oracle_episode(env: SimEnv, spec: SceneSpec) -> DemoRecord:
    """Reset → capture → segment → oracle grasp → pick, timing each phase."""
    t0 = time.perf_counter()
    scene = env.reset(spec)
    t1 = time.perf_counter()
    obs = env.capture()
    t2 = time.perf_counter()
    rois = segment(obs).rois
    t3 = time.perf_counter()
    target_gt = [r for r in gt_rois(obs, scene) if r.label == scene.target.body_id]
    iou = best_box_matches(rois, target_gt)[0] if target_gt else 0.0
    grasp = oracle_grasp(scene, scene.target.body_id)
    t4 = time.perf_counter()
    result = execute_pick(env, grasp, scene.target.body_id)
    t5 = time.perf_counter()
    return DemoRecord(
        target=spec.target,
        seed=spec.seed,
        outcome=result.outcome,
        target_box_iou=iou,
        steps=result.steps,
        times=PhaseTimes(t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4),
        detail=result.detail,
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("targets", nargs="+", help="catalog asset ids to pick")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--distractors", nargs="+", default=list(DEFAULT_DISTRACTORS))
    args = parser.parse_args(argv)
    successes = 0
    with SimEnv() as env:
        for target in args.targets:
            distractors = tuple(d for d in args.distractors if d != target)[:4]
            for seed in args.seeds:
                record = run_oracle_episode(env, SceneSpec("demo", target, distractors, seed))
                successes += record.outcome is Outcome.SUCCESS
                t = record.times
                print(
                    f"{target:22s} seed={seed:<3d} {record.outcome.value:22s} "
                    f"roi_iou={record.target_box_iou:.2f} steps={record.steps:5d} "
                    f"wall={t.total:5.2f}s (reset {t.reset:.2f}, capture {t.capture:.2f}, "
                    f"segment {t.segment:.2f}, grasp {t.grasp:.2f}, pick {t.pick:.2f}) "
                    f"{record.detail}"
                )
    print(f"success {successes}/{len(args.targets) * len(args.seeds)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
