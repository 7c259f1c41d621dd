"""Benchmark: execution alone — pick the *right* object with the robot's own grasp.

``craft eval sim`` mixes choosing the object with picking it. This isolates the pick: for every
episode of a labels file (the same scenes ``craft eval sim`` builds), the ROIs are the
simulator's masks (``rois=oracle``), the target's ROI is taken as chosen, and its best usable
grasp (GR-ConvNet by default, with the grasp checks) is executed, released with the ROI's seen
centre over the drop zone and closed with the hand's gentle grip on an object the depth camera
measures small, as in ``craft eval sim`` (the grip by size since session 42; before it this
benchmark closed every hand at its full force). Outcomes are counted as in
``craft eval sim`` (``no_grasp`` when the target's ROI has no usable grasp).

Run: ``.venv/bin/python benchmarks/bench_execution.py --labels artifacts/labels/sim_dev_labels.csv
[--hand robotiq_2f85|panda] [--force F] [--grasp grconvnet|oracle] [--max-pairs N] [--json OUT]``.
Single attempt per episode, like the headline numbers.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path
from typing import Any

from craft_e.arguments import output_file, positive_int
from craft_e.paths import SIM_DEV_LABELS
from craft_e.runtime.evaluation.sim_eval import default_encoder, load_sim_labels, make_episode_specs
from craft_e.runtime.sim.env import EnvConfig, SimEnv
from craft_e.runtime.sim.episode import execute_pick
from craft_e.runtime.sim.perceive import perceive
from craft_e.runtime.sim.pipeline import PipelineConfig, SavedStart, longest_edge
from craft_e.runtime.sim.surface import object_centre


def _env_config(hand: str | None, force: float | None = None) -> EnvConfig:
    from craft_e.runtime.sim.gripper import GripperConfig

    if hand is None:
        return EnvConfig(gripper=GripperConfig(force=force))
    return EnvConfig(gripper=GripperConfig(hand=hand, force=force))  # type: ignore[arg-type]


def run(
    labels: Path, hand: str | None, grasp: str, max_pairs: int | None, force: float | None = None
) -> dict[str, Any]:
    specs = make_episode_specs(load_sim_labels(labels), layouts=3, seed=0, max_pairs=max_pairs)
    config = PipelineConfig(grasp=grasp, rois="oracle")  # type: ignore[arg-type]
    encoder = default_encoder(1)
    rows: list[dict[str, Any]] = []
    with SimEnv(_env_config(hand, force)) as env:
        for spec in specs:
            env.reset(spec.scene)
            start = SavedStart(env)
            try:
                perception = perceive(env, encoder, config)
                index = perception.target_roi
                usable = perception.rois[index].usable if index is not None else ()
                if not usable or usable[0].pose is None:
                    outcome, detail = "no_grasp", "no usable grasp on the target's ROI"
                else:
                    start.restore()
                    assert index is not None
                    centre = object_centre(perception.raised, perception.rois[index].roi.mask)
                    result = execute_pick(env, usable[0].pose, perception.target_body, config.pick, centre,
                                          longest_edge(perception.rois[index]))
                    outcome, detail = result.outcome.value, result.detail
            finally:
                start.release()
            rows.append({"episode": spec.id, "target": spec.scene.target, "outcome": outcome,
                         "detail": detail})
            print(f"{spec.id:40s} {outcome:22s} {detail}", flush=True)
    counts = Counter(r["outcome"] for r in rows)
    return {"hand": hand or "default", "force": force, "grasp": grasp, "episodes": len(rows),
            "outcomes": dict(sorted(counts.items())), "rows": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--labels", type=Path, default=SIM_DEV_LABELS)
    parser.add_argument("--hand", default=None, help="robotiq_2f85 | panda (default: the env's)")
    parser.add_argument("--grasp", default="grconvnet")
    parser.add_argument("--max-pairs", type=positive_int, default=None)
    parser.add_argument("--force", type=float, default=None,
                        help="gripper effort: N per Franka finger, N·m per Robotiq driven joint "
                             "(default: the hand's)")
    parser.add_argument("--json", type=output_file, default=None)
    args = parser.parse_args()
    report = run(args.labels, args.hand, args.grasp, args.max_pairs, args.force)
    n = report["episodes"]
    print(f"\nhand {report['hand']}, grasp {report['grasp']}, {n} episodes")
    for outcome, count in report["outcomes"].items():
        print(f"  {outcome:22s} {count:4d}  {100 * count / max(n, 1):5.1f} %")
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
