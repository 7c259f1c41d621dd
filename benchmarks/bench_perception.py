"""Benchmark: robot-side perception + grounding per testbed scene, per stage, against its floor.

Robot-side work is what a real robot computes from one RGB-D frame to the grasp it executes
(rendering, physics, the simulator's ground truth and the evaluation's diagnostics are excluded).
The stages are timed inside the robot's own path, ``sim.choose.perceive_for_pick`` +
``ground_lazily`` (its ``timings`` argument), so the benchmark runs exactly that code:

* ``segment``: class-agnostic RGB-D segmentation into ROIs;
* ``grasp_net``: one grasp-network pass over the crop holding every ROI, then per-ROI peaks;
* ``encode``: ConSE embeddings of the ROI crops (one batched pass);
* ``finger_checks``: the finger check of every grasp candidate, each ROI's extents and (with the
  cavity cue, the default since 2026-12-05; ``--no-cavity-cue``: without) its open cavity;
* ``ground_ik``: ``Grounder.ground`` of the CRAFT-E bundle plus the pick's IK plan of the chosen
  grasp only (again if it is unreachable), ``ground_lazily``, then the chosen pick's clearance
  check and, when its approach is blocked, the search for a clear spot (``relocate_choice``).

Every scene is also run the evaluation's eager way (``perceive``: IK of every ROI's grasps, then
``Grounder.ground``, with the checkpoints' networks), untimed for the total: its choice must equal
the robot's (counted: the same ROI and the same grasp rectangle, whose centre, angle, width and
quality may differ by float rounding, ``GRASP_TOL``, since the robot runs the networks' inference
rewrites; ``_rect_gap``), and its checks' time is printed beside for reference.

The floor is the same grasp-network pass (``predict_frame`` on the same crop: pre-processing,
network, smoothing) plus the same batched encoder pass on the same crops, measured in the same run
on the same scenes, with the networks the robot runs (their inference rewrites, ``fused=True`` and
``inference_encoder``). Timed runs alternate which goes first, the robot's path or the floor
(the first timed run robot first, the next floor first, counted across scenes, so an odd
``--repeats`` alternates too), because the order was measured to matter: with the floor always
second, the robot's ``grasp_net`` stage came out 7, 16 and 23 ms/scene slower than the floor's
grasp-network pass in three runs, and 5, 5 and 7 ms with the floor first (ad-hoc runs on this
2-core host, 2026-12-04). Output: a per-stage table and, with ``--json OUT``,
``{"robot_s_per_scene", "floor_s_per_scene", "ratio", "stages": {...}}``, plus the slowest
scene's robot total: the per-scene cost has a tail (a blocked approach's relocation search, the
antipodal fallback) that the default six scenes barely sample; ``--scenes 35`` covers every
sim-dev pair once.

Run: ``.venv/bin/python benchmarks/bench_perception.py [--scenes 6] [--threads 2] [--json OUT]``.
``--threads`` (default 2: the robot's own two cores, issue 10's budget) sets the torch threads of
both network passes; the evaluation keeps its own default of 1 (``PipelineConfig``). On a host
whose cores are shared with other jobs two threads contend (oneDNN's threads wait for each other
at every layer) and can be several times slower than one: the script says so when the load
average is high at the start, and ``--threads 1`` is then the meaningful measurement.
Wall time is for reporting only; nothing in an episode depends on it. Every scene is perceived
and grounded once untimed first (model loading, caches, and the arm links' hull samples the pick
check builds once per process), then ``--repeats`` times timed, each time from a new
``Observation`` of the same arrays: a frame caches its 3D points (camera and world frame), and a
robot computes them for every frame it captures, so the timed stages pay for them (``segment``
and ``finger_checks``; before this, repeats reused the warm-up's points: ~11 ms/scene unseen).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

from craft_e.arguments import output_file, positive_int
from craft_e.paths import SIM_DEV_LABELS
from craft_e.runtime.encoders.image import ImageEncoder, UInt8Image
from craft_e.runtime.evaluation.sim_eval import (
    build_grounders,
    default_encoder,
    load_methods,
    load_sim_labels,
    make_episode_specs,
    select_methods,
)
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.perception.observation import Observation
from craft_e.runtime.perception.roi import BoolMask
from craft_e.runtime.sim.active_look import (
    ActiveLook,
    ActiveLookConfig,
    LookingGrounder,
)
from craft_e.runtime.sim.candidates import GraspCandidate
from craft_e.runtime.sim.choose import (
    LazyROI,
    ground_lazily,
    perceive_for_pick,
    pick_reachable,
    relocate_choice,
)
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.episode import PlanCache
from craft_e.runtime.sim.fallback import FallbackConfig
from craft_e.runtime.sim.perceive import frame_look, grounding_rois, perceive, torch_threads
from craft_e.runtime.sim.pipeline import PipelineConfig, relocated_grasp, sim_vocabulary

GRASP_TOL = 1e-4  # the robot's networks equal the evaluation's to float rounding (~1e-6)


def _cpu_model() -> str:
    """The host CPU's model name and whether it has AMX/AVX-512 (``/proc/cpuinfo``; "" where it
    cannot be read): hosts differ several-fold in the networks' speed and less in numpy's, so
    the ratio depends on the host and the JSON records which."""
    try:
        text = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return platform.processor() or platform.machine()
    model = next((line.split(":", 1)[1].strip() for line in text.splitlines() if line.startswith("model name")), "")
    flags = next((line.split(":", 1)[1].split() for line in text.splitlines() if line.startswith("flags")), [])
    extras = [name for name, flag in (("AVX-512", "avx512f"), ("AMX", "amx_tile")) if flag in flags]
    return f"{model} ({', '.join(extras)})" if extras else model


def _rect_gap(a: object, b: object) -> float:
    """How far two chosen grasps differ: 0 for the same rectangle, inf for another peak (centres
    half a pixel or more apart) or no grasp on one side, else the largest difference of centre
    (px), angle (rad), width, length and quality. The robot's fused networks change these by
    float rounding only; a network grasp's centre is its peak pixel on both paths, while a
    refined grasp's (``sim/refine.py``: a pose moved on the object, projected back) carries
    that rounding too (~1e-5 px)."""
    if not (isinstance(a, GraspCandidate) and isinstance(b, GraspCandidate)):
        return 0.0 if a is None and b is None else math.inf
    ra, rb = a.rect, b.rect
    centre = max(abs(ra.center_xy[0] - rb.center_xy[0]), abs(ra.center_xy[1] - rb.center_xy[1]))
    if centre >= 0.5:
        return math.inf
    return max(centre, abs(ra.angle_rad - rb.angle_rad), abs(ra.width_px - rb.width_px),
               abs(ra.length_px - rb.length_px), abs(ra.quality - rb.quality))


def _time_floor(cfg: PipelineConfig, obs: Observation, masks: list[BoolMask], crops: list[UInt8Image],
                encoder: ImageEncoder, threads: int) -> tuple[float, float]:
    """The floor's two passes on one scene: (grasp-network seconds, encoder seconds)."""
    from craft_e.runtime.grasp.predict import predict_frame

    with torch_threads(threads):
        t1 = time.perf_counter()
        if masks:
            predict_frame(cfg.grasp, obs.rgb, obs.depth, masks, fused=True)
        t2 = time.perf_counter()
        if crops:
            encoder.embed_images(crops)
        t3 = time.perf_counter()
    return t2 - t1, t3 - t2


def looking(grounder: Grounder, env: SimEnv, cfg: PipelineConfig, rois: list[LazyROI], encoder: ImageEncoder,
            timings: dict[str, float] | None) -> Grounder | LookingGrounder:
    """``grounder``, or with ``--active-look`` the same grounder looking again at its top ROIs on
    this frame (the robot's fast encoder, as in ``perceive_for_pick``)."""
    if not cfg.active_look.enabled:
        return grounder
    from craft_e.runtime.encoders.image import inference_encoder

    points = [r.material if r.material is not None else np.zeros((0, 3)) for r in rois]
    return LookingGrounder(grounder, ActiveLook(env.client, points, env.scene.layout.table_z,
                                                inference_encoder(encoder), cfg.active_look, timings=timings))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--labels", type=Path, default=SIM_DEV_LABELS)
    parser.add_argument("--scenes", type=positive_int, default=6)
    parser.add_argument("--repeats", type=positive_int, default=2)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("--active-look", action="store_true",
                        help="with the opt-in active look (sim/active_look.py): its encoder pass is the "
                             "look_encode stage, its renders are left out")
    parser.add_argument("--no-cavity-cue", action="store_true",
                        help="ground without the cavity cue (and measure no cavities), as before 2026-12-05")
    parser.add_argument("--no-grasp-fallback", action="store_true",
                        help="without the antipodal fallback (sim/fallback.py): what it costs")
    args = parser.parse_args()

    import torch

    from craft_e.runtime.encoders.image import crop_box, inference_encoder

    cfg = PipelineConfig(torch_threads=args.threads, fallback=FallbackConfig(enabled=not args.no_grasp_fallback),
                         active_look=ActiveLookConfig(enabled=args.active_look))
    specs = make_episode_specs(load_sim_labels(args.labels), layouts=1, max_pairs=args.scenes, min_gap=None)
    enc = default_encoder(args.threads)
    fast_enc = inference_encoder(enc)  # the robot's encoder (perceive_for_pick): the floor's too
    runnable, _ = load_methods(select_methods(["CRAFT-E"]), enc.text_encoder_id)
    grounder = build_grounders(runnable, GroundingSettings(cavity_cue=False if args.no_cavity_cue else None),
                               sim_vocabulary())["CRAFT-E"]
    cavity = grounder.cavity_cue_active  # measured in the finger_checks stage when the grounder reads it
    stages = {k: 0.0 for k in ("segment", "grasp_net", "encode", "finger_checks", "ground_ik")
              + (("look_encode",) if args.active_look else ())}
    floor = {"grasp_net_frame": 0.0, "encode": 0.0}
    rois_total, plans, agree, eager_checks, worst_gap = 0, 0, 0, 0.0, 0.0
    relocated, blocked, same_move = 0, 0, 0
    scene_totals: list[tuple[float, str]] = []  # each scene's robot total, mean over its repeats
    timed_runs = 0  # robot first on even counts, floor first on odd: see the module docstring
    load = os.getloadavg()
    if args.threads > 1 and load[0] > 1.0:
        print(f"note: load average {load[0]:.1f} at the start: other jobs share the cores, so "
              f"{args.threads} torch threads contend; --threads 1 measures more reliably here")
    for spec in specs:
        scene_total = 0.0
        with SimEnv() as env:
            env.reset(spec.scene)
            env.robot.reset_home()
            obs = env.capture()
            sharp = env.capture_rgb(cfg.rgb_scale)
            warm = perceive_for_pick(env, enc, cfg, obs, cavity=cavity)  # warm-up, untimed
            # ... and the grounding with its pick check once: the first relocation check of a
            # process builds the arm links' hull samples (``sim/arm_hull.py``, ~0.2 s, once)
            warm_made: PlanCache = {}
            warm_choice = ground_lazily(looking(grounder, env, cfg, warm, enc, None), spec.verb, warm,
                                        pick_reachable(env, cfg, warm, warm_made))
            if warm_choice.grasp is not None and warm_choice.grounding.chosen is not None:
                relocate_choice(env, cfg, obs, warm[warm_choice.grounding.chosen.index], warm_choice.grasp, warm_made)
            eager_t: dict[str, float] = {}
            eager = perceive(env, enc, cfg, obs, timings=eager_t, cavity=cavity)  # the evaluation's path
            eager_choice = (frame_look(env, eager, enc, cfg.active_look).ground(grounder, spec.verb,
                                                                                 grounding_rois(eager))[0].chosen
                            if args.active_look else grounder.ground(spec.verb, grounding_rois(eager)).chosen)
            masks = [r.roi.mask for r in eager.rois]
            crops = [crop_box(sharp, tuple(v * cfg.rgb_scale for v in r.roi.box_xywh)) for r in eager.rois]
            for _ in range(args.repeats):
                robot_first = timed_runs % 2 == 0
                timed_runs += 1
                if not robot_first:
                    floor_net, floor_enc = _time_floor(cfg, obs, masks, crops, fast_enc, args.threads)
                timings: dict[str, float] = {}
                frame = dataclasses.replace(obs)  # a new frame: its 3D points are computed in the timed stages
                lazy = perceive_for_pick(env, enc, cfg, frame, timings=timings, cavity=cavity)
                t0 = time.perf_counter()
                made: PlanCache = {}  # the IK plans of this scene, reused by the relocation check
                choice = ground_lazily(looking(grounder, env, cfg, lazy, enc, timings), spec.verb, lazy,
                                       pick_reachable(env, cfg, lazy, made))
                picked = choice.grasp
                if picked is not None and choice.grounding.chosen is not None:
                    picked, why = relocate_choice(env, cfg, frame, lazy[choice.grounding.chosen.index], picked,
                                                  made)
                    relocated += int(why.startswith("approach blocked") and "kept" not in why)
                    blocked += int(why.startswith("approach blocked"))
                # the look's renders are the simulator's and its encoder pass is its own stage
                timings["ground_ik"] = (time.perf_counter() - t0 - timings.get("look_render", 0.0)
                                        - timings.get("look_encode", 0.0))
                plans += choice.plans
                chosen = choice.grounding.chosen
                same_roi = (chosen is None) == (eager_choice is None) and (
                    chosen is None or eager_choice is None or chosen.index == eager_choice.index)
                grasp = choice.grasp
                gap = _rect_gap(grasp, eager_choice.grasp) if eager_choice is not None else 0.0
                worst_gap = max(worst_gap, gap)
                agree += int(same_roi and gap <= GRASP_TOL)
                if eager_choice is not None and eager_choice.grasp is not None and picked is not None:
                    eager_moved, _ = relocated_grasp(env, obs, eager.rois[eager_choice.index], eager_choice.grasp, cfg)
                    same_move += int(_rect_gap(picked, eager_moved) <= GRASP_TOL)
                if robot_first:
                    floor_net, floor_enc = _time_floor(cfg, obs, masks, crops, fast_enc, args.threads)
                for k in stages:
                    stages[k] += timings.get(k, 0.0)
                scene_total += sum(timings.get(k, 0.0) for k in stages) / args.repeats
                floor["grasp_net_frame"] += floor_net
                floor["encode"] += floor_enc
                rois_total += len(lazy)
                eager_checks += eager_t["grasp_checks"]
        scene_totals.append((scene_total, spec.id))
    n = len(specs) * args.repeats
    load_after = os.getloadavg()
    per_stage = {k: v / n for k, v in stages.items()}
    robot = sum(per_stage.values())
    floor_s = sum(floor.values()) / n
    print(f"{len(specs)} scenes x {args.repeats}, {rois_total / n:.1f} ROIs/scene, torch threads {args.threads}, "
          f"{os.cpu_count()} CPUs ({_cpu_model()}), "
          f"load average {load[0]:.1f} before / {load_after[0]:.1f} after")
    print("| stage | s / scene | share |\n|---|---:|---:|")
    for k, v in per_stage.items():
        print(f"| {k} | {v:.3f} | {100 * v / robot:.0f} % |")
    print(f"| **robot total** | **{robot:.3f}** | |")
    print(f"| floor: the grasp-network pass over the frame | {floor['grasp_net_frame'] / n:.3f} | |")
    print(f"| floor: the batched encoder pass | {floor['encode'] / n:.3f} | |")
    print(f"| **floor** | **{floor_s:.3f}** | |\nratio {robot / floor_s:.2f}")
    print(f"IK plans per scene {plans / n:.2f}; robot choice = eager choice in {agree}/{n} (same ROI, same "
          f"peak, centre/angle/width/quality within {GRASP_TOL:g}; largest difference {worst_gap:.1e}); "
          f"eager grasp checks (IK of every ROI, the evaluation's path) {eager_checks / n:.3f} s/scene")
    print(f"approach blocked: {blocked}/{n}, relocated (moved along the object): {relocated}/{n}; relocated "
          f"grasp = the evaluation's in {same_move}/{n}")
    slowest, slowest_id = max(scene_totals)
    print(f"slowest scene: {slowest_id}, robot total {slowest:.3f} s (a blocked approach's relocation search "
          f"and the antipodal fallback are the tail: run more --scenes to see it)")
    if args.json is not None:
        args.json.write_text(json.dumps({
            "robot_s_per_scene": round(robot, 4), "floor_s_per_scene": round(floor_s, 4),
            "ratio": round(robot / floor_s, 3), "stages": {k: round(v, 4) for k, v in per_stage.items()},
            "floor": {k: round(v / n, 4) for k, v in floor.items()}, "scenes": len(specs),
            "repeats": args.repeats, "order": "alternating (robot first, then floor first)",
            "rois_per_scene": rois_total / n, "torch_threads": args.threads,
            "grasp_fallback": cfg.uses_fallback, "active_look": args.active_look, "cavity_cue": cavity,
            "torch_version": torch.__version__, "cpus": os.cpu_count(), "cpu_model": _cpu_model(),
            "image_encoder": fast_enc.id,
            "load_average": [round(load[0], 2), round(load_after[0], 2)],
            "ik_plans_per_scene": plans / n, "choice_equals_eager": f"{agree}/{n}",
            "chosen_grasp_max_difference": worst_gap,
            "eager_grasp_checks_s_per_scene": round(eager_checks / n, 4),
            "relocated": f"{relocated}/{n}", "relocated_equals_eager": f"{same_move}/{n}",
            "approach_blocked": f"{blocked}/{n}",
            "slowest_scene": {"id": slowest_id, "robot_s": round(slowest, 4)},
        }, indent=1) + "\n")


if __name__ == "__main__":
    main()
