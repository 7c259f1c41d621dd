"""Does preemptive RANSAC scoring keep the table plane of the full count, on every dev frame?

``PlaneFitConfig.preemptive_keep`` (default 10) counts every candidate plane on a 2000-point
probe and only the best 10 on all samples; 0 counts all 200 on all samples, as before. This
segments the overhead frame of every dev episode both ways and reports how many frames give the
same plane bit for bit and the same ROIs pixel for pixel, and the segmentation time of each.

Run: ``.venv/bin/python benchmarks/plane_preemption.py [--labels CSV]``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from craft_e.paths import SIM_DEV_LABELS
from craft_e.runtime.evaluation.sim_eval import load_sim_labels, make_episode_specs
from craft_e.runtime.perception.plane import PlaneFitConfig
from craft_e.runtime.perception.segment import SegmentConfig, segment
from craft_e.runtime.sim.env import SimEnv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--labels", type=Path, default=SIM_DEV_LABELS)
    args = parser.parse_args()
    preemptive = SegmentConfig()
    exhaustive = replace(preemptive, plane=replace(PlaneFitConfig(), preemptive_keep=0))
    specs = make_episode_specs(load_sim_labels(args.labels), layouts=3)
    same_plane = same_rois = 0
    seconds = {"exhaustive": 0.0, "preemptive": 0.0}
    for spec in specs:
        with SimEnv() as env:
            env.reset(spec.scene)
            obs = env.capture()
            obs.points_camera()  # computed once per frame, shared by both runs (not timed)
            t0 = time.perf_counter()
            full = segment(obs, exhaustive)
            t1 = time.perf_counter()
            fast = segment(obs, preemptive)
            t2 = time.perf_counter()
        seconds["exhaustive"] += t1 - t0
        seconds["preemptive"] += t2 - t1
        same_plane += int(np.array_equal(full.plane.normal, fast.plane.normal)
                          and full.plane.offset == fast.plane.offset)
        same_rois += int(len(full.rois) == len(fast.rois) and all(
            np.array_equal(a.mask, b.mask) for a, b in zip(full.rois, fast.rois, strict=True)))
    n = len(specs)
    print(f"{n} dev frames: the same plane (bit for bit) in {same_plane}, the same ROIs in {same_rois}")
    print(f"segment, ms / frame: all candidates counted on all samples {1000 * seconds['exhaustive'] / n:.1f}, "
          f"preemptive {1000 * seconds['preemptive'] / n:.1f}")


if __name__ == "__main__":
    main()
