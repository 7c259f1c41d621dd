"""Benchmark: robot-side perception + grounding per testbed scene, per stage, against its floor.

Robot-side work is what a real robot would compute from one RGB-D frame (rendering, physics and
the 3D metric are simulator work and excluded):

* ``segment``: class-agnostic RGB-D segmentation into ROIs;
* ``grasp_net``: the grasp network, as the pipeline runs it (once per ROI, on the ROI mask);
* ``grasp_checks``: finger fit + IK of the pick for candidates until one passes;
* ``encode``: ConSE embeddings of the ROI crops (one batched pass);
* ``ground``: ``Grounder.ground`` of the CRAFT-E bundle.

The floor is one grasp-network pass over the whole frame plus one batched encoder pass over the
scene's crops, measured in the same run on the same scenes. Output: a per-stage table and, with
``--json OUT``, ``{"robot_s_per_scene", "floor_s_per_scene", "ratio", "stages": {...}}``.

Run: ``.venv/bin/python benchmarks/bench_perception.py [--scenes 6] [--threads 1] [--json OUT]``.
Wall time is for reporting only; nothing in an episode depends on it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from craft_e.paths import SIM_DEV_LABELS
from craft_e.runtime.evaluation.sim_eval import (
    build_grounders,
    default_encoder,
    load_methods,
    load_sim_labels,
    make_episode_specs,
    select_methods,
)
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.pipeline import (
    PipelineConfig,
    _raw_candidates,
    _Surfaces,
    _usable,
    grounding_rois,
    torch_threads,
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--labels", type=Path, default=SIM_DEV_LABELS)
    parser.add_argument("--scenes", type=int, default=6)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    import torch

    from craft_e.runtime.encoders.image import crop_box
    from craft_e.runtime.grasp.predict import predict_grasps
    from craft_e.runtime.perception.segment import segment

    cfg = PipelineConfig(torch_threads=args.threads)
    specs = make_episode_specs(load_sim_labels(args.labels), layouts=1, max_pairs=args.scenes, min_gap=None)
    enc = default_encoder(args.threads)
    runnable, _ = load_methods(select_methods(["CRAFT-E"]), enc.text_encoder_id)
    grounder = build_grounders(runnable)["CRAFT-E"]
    stages = {k: 0.0 for k in ("segment", "grasp_net", "grasp_checks", "encode", "ground")}
    floor = {"grasp_net_frame": 0.0, "encode": 0.0}
    rois_total = 0
    for spec in specs:
        with SimEnv() as env:
            env.reset(spec.scene)
            env.robot.reset_home()
            obs = env.capture()
            sharp = env.capture_rgb(cfg.rgb_scale)
            with torch_threads(args.threads):
                t0 = time.perf_counter()
                rois = segment(obs, cfg.segment).rois
                t1 = time.perf_counter()
                raw = [_raw_candidates(env.scene, obs, r, None, cfg) for r in rois]
                t2 = time.perf_counter()
                world = obs.points_world()
                table_z = env.scene.layout.table_z
                raised = np.nan_to_num(world[..., 2], nan=table_z) > table_z + cfg.fingers.height_tolerance
                for r, cands in zip(rois, raw, strict=True):
                    _usable(env, cands, _Surfaces(world[r.mask & raised], table_z), cfg)
                t3 = time.perf_counter()
                crops = [crop_box(sharp, tuple(v * cfg.rgb_scale for v in r.box_xywh)) for r in rois]
                emb = enc.embed_images(crops)
                t4 = time.perf_counter()
            from craft_e.runtime.sim.pipeline import perceive

            per = perceive(env, enc, cfg, obs)  # grounding input as the pipeline builds it
            t5 = time.perf_counter()
            grounder.ground(spec.verb, grounding_rois(per))
            t6 = time.perf_counter()
            with torch_threads(args.threads):
                full = np.ones(obs.depth.shape, dtype=bool)
                t7 = time.perf_counter()
                predict_grasps(cfg.grasp, obs.rgb, obs.depth, full, cfg.max_grasps, intrinsics=obs.intrinsics)
                t8 = time.perf_counter()
                enc.embed_images(crops)
                t9 = time.perf_counter()
            del emb
        rois_total += len(rois)
        for key, dt in (("segment", t1 - t0), ("grasp_net", t2 - t1), ("grasp_checks", t3 - t2),
                        ("encode", t4 - t3), ("ground", t6 - t5)):
            stages[key] += dt
        floor["grasp_net_frame"] += t8 - t7
        floor["encode"] += t9 - t8
    n = len(specs)
    per_stage = {k: v / n for k, v in stages.items()}
    robot = sum(per_stage.values())
    floor_s = sum(floor.values()) / n
    print(f"{n} scenes, {rois_total / n:.1f} ROIs/scene, torch threads {args.threads}, "
          f"{os.cpu_count()} CPUs ({platform.processor() or platform.machine()})")
    print("| stage | s / scene |\n|---|---:|")
    for k, v in per_stage.items():
        print(f"| {k} | {v:.3f} |")
    print(f"| **robot total** | **{robot:.3f}** |")
    print(f"| floor: one grasp-net pass over the frame | {floor['grasp_net_frame'] / n:.3f} |")
    print(f"| floor: one batched encoder pass | {floor['encode'] / n:.3f} |")
    print(f"| **floor** | **{floor_s:.3f}** |\nratio {robot / floor_s:.2f}")
    if args.json is not None:
        args.json.write_text(json.dumps({
            "robot_s_per_scene": round(robot, 4), "floor_s_per_scene": round(floor_s, 4),
            "ratio": round(robot / floor_s, 3), "stages": {k: round(v, 4) for k, v in per_stage.items()},
            "floor": {k: round(v / n, 4) for k, v in floor.items()}, "scenes": n,
            "rois_per_scene": rois_total / n, "torch_threads": args.threads,
            "torch_version": torch.__version__, "cpus": os.cpu_count(),
        }, indent=1) + "\n")


if __name__ == "__main__":
    main()
