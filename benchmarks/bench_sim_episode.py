"""Benchmark: wall time of one testbed episode, per phase, with the four methods of ``craft eval sim``.

The performance promise: a sim episode (build + settle, capture, ROIs, grasps with their checks,
embeddings, grounding by four methods, physics of every distinct chosen pick) takes < 10 s on a
2-core host, so the full dev evaluation (105 episodes) stays well under 30 minutes. This script
times the first ``--episodes`` episodes of a labels file and prints the phases:

* ``build``: ``SimEnv.reset`` (load, place, settle) plus the saved start state;
* ``perceive``: capture, segmentation, grasp prediction and checks, crop embeddings, 3D metric;
* ``ground``: every method's ``Grounder.ground``;
* ``execute``: the simulated picks (one per distinct chosen ROI of a detected target).

Run: ``.venv/bin/python benchmarks/bench_sim_episode.py [--labels FILE] [--episodes 6]
[--grasp grconvnet] [--json OUT]``. Wall time is measured for reporting only; nothing in an
episode depends on it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from craft_e.arguments import output_file, positive_int
from craft_e.paths import SIM_DEV_LABELS
from craft_e.runtime.evaluation.methods import build_grounders, load_methods, select_methods
from craft_e.runtime.evaluation.sim_eval import (
    default_encoder,
    load_sim_labels,
    make_episode_specs,
)
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.episode import execute_pick
from craft_e.runtime.sim.perceive import grounding_rois, perceive
from craft_e.runtime.sim.pipeline import PipelineConfig, SavedStart, sim_vocabulary


@dataclass
class EpisodeTiming:
    """Seconds per phase of one episode."""

    episode: str
    build: float
    perceive: float
    ground: float
    execute: float
    picks: int

    @property
    def total(self) -> float:
        return self.build + self.perceive + self.ground + self.execute


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--labels", type=Path, default=SIM_DEV_LABELS)
    parser.add_argument("--episodes", type=positive_int, default=6)
    parser.add_argument("--grasp", default="grconvnet")
    parser.add_argument("--json", type=output_file, default=None)
    args = parser.parse_args()

    config = PipelineConfig(grasp=args.grasp)
    encoder = default_encoder(config.torch_threads)
    runnable, _ = load_methods(select_methods(), encoder.text_encoder_id)
    grounders = build_grounders(runnable, GroundingSettings(), sim_vocabulary())
    labels = load_sim_labels(args.labels)
    specs = make_episode_specs(labels, layouts=3)[: args.episodes]
    timings: list[EpisodeTiming] = []
    cavity = any(g.cavity_cue_active for g in grounders.values())  # measured as ``craft eval sim`` does
    for spec in specs:
        with SimEnv() as env:
            t0 = time.perf_counter()
            env.reset(spec.scene)
            start = SavedStart(env)
            t1 = time.perf_counter()
            per = perceive(env, encoder, config, cavity=cavity)
            rois = grounding_rois(per)
            t2 = time.perf_counter()
            chosen = {name: g.ground(spec.verb, rois).chosen for name, g in grounders.items()}
            t3 = time.perf_counter()
            picks = {c.index for c in chosen.values() if c is not None and per.rois[c.index].target_iou >= 0.5}
            for index in sorted(picks):
                start.restore()
                grasp = per.rois[index].usable[0].pose if per.rois[index].usable else None
                execute_pick(env, grasp, per.target_body)
            t4 = time.perf_counter()
            start.release()
        timings.append(EpisodeTiming(spec.id, t1 - t0, t2 - t1, t3 - t2, t4 - t3, len(picks)))
        t = timings[-1]
        print(f"{t.episode:28s} total {t.total:5.2f}s  build {t.build:4.2f}  perceive {t.perceive:4.2f}  "
              f"ground {t.ground:5.3f}  execute {t.execute:4.2f} ({t.picks} picks)", flush=True)
    mean = sum(t.total for t in timings) / max(len(timings), 1)
    worst = max((t.total for t in timings), default=0.0)
    print(f"mean {mean:.2f} s/episode, worst {worst:.2f} s ({os.cpu_count()} CPUs, {platform.processor() or platform.machine()})")
    if args.json is not None:
        args.json.write_text(json.dumps({"episodes": [asdict(t) for t in timings], "mean_s": mean,
                                         "worst_s": worst, "cpus": os.cpu_count()}, indent=1) + "\n")


if __name__ == "__main__":
    main()
