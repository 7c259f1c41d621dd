"""Benchmark: how robust ``ground_frame`` is to what a real RGB-D camera does to a frame.

Why: ``runtime/frame.py`` runs the testbed robot's own perception (segmentation on the table
plane, the grasp network, ConSE crops, the size and cavity cues, the finger checks) on one RGB-D
frame, so a robot with a RealSense can use it. The simulator's frames are ideal: float depth
exact to the render, no noise, no missing pixels, and the camera model the image was made with.
A real camera gives depth in whole millimetres (uint16), noise that grows with distance, holes
where the stereo match fails, and intrinsics that are only as good as their calibration. This
benchmark applies each of those to the sim-dev frames and measures what changes downstream:
whether the chosen region is still the target, still the one chosen on the clean frame, whether
it still has a grasp, how many regions are found, and how far its measured extents (the size
cue's input) move.

Each sim-dev scene (``make_episode_specs(..., layouts=1)``, one layout per pair, the arm at home)
is captured once and grounded by CRAFT-E (``craft-e-default``, the sim vocabulary, the default
``PipelineConfig``) on the frame under every setting of ``SETTINGS``: the clean frame with the
camera's pose given (the reference), and without the pose (heights from the fitted table plane),
clean and with each camera effect. Noise and holes touch only pixels with a reading
(depth > 0). Every random draw comes from a numpy ``Generator`` seeded by ``(--seed, scene
index, setting index)``, so two runs give the same numbers and a scene's draws do not depend on
``--scenes``.

Per setting, over the scenes: Detect (the chosen region's box has IoU >= 0.5 with the target's
ground-truth box, ``sim.oracle.gt_rois``); "same as ref." (IoU >= 0.5 with the reference's chosen
box; two empty choices count as the same); the share with a grasp; the mean number of regions;
and the median absolute difference (mm) of the chosen region's three extents (longest first)
from those the reference measured for the same region (the reference region with the highest
box IoU, at least 0.5, with it), pooled over the scenes where both were measured, and their
signed median (noise lifts the height, a high percentile of the region's points). A frame
``ground_frame`` refuses (``FrameError``, e.g. no table plane) is counted as an error with its
message in the JSON; anything else stops the run.

Run: ``.venv/bin/python benchmarks/bench_frame_noise.py [--scenes 35] [--seed 0] [--json OUT]
[--markdown OUT]`` (all 35 sim-dev pairs by default; about 2 min on 2 cores). Results:
``docs/results/frame_noise.md`` and ``.json``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, cast

import numpy as np
import numpy.typing as npt
from frame_bench import FrameRun, options, percent

from craft_e.runtime.grasp.geometry import CameraIntrinsics

Depth = npt.NDArray[np.float32]
Box = tuple[float, float, float, float]
MATCH_IOU = 0.5  # a box "is" another at this IoU (Detect's threshold)
HOLE_BLOCK = 3  # holes are square blocks of this many pixels a side


def quantise_mm(depth: Depth) -> Depth:
    """``depth`` (metres) as a RealSense gives it: a uint16 frame of whole millimetres (its
    default depth scale, 0.001 m per unit; readings past 65.535 m saturate), read back in metres."""
    millimetres = np.clip(np.rint(np.asarray(depth, dtype=np.float64) * 1000.0), 0, np.iinfo(np.uint16).max)
    return (millimetres.astype(np.uint16).astype(np.float32) * np.float32(0.001)).astype(np.float32)


def gaussian_noise(depth: Depth, sigma_m: float, rng: np.random.Generator) -> Depth:
    """``depth`` plus zero-mean Gaussian noise of ``sigma_m`` metres where it has a reading
    (> 0); pixels without one stay 0, and a reading the noise would push to <= 0 becomes none."""
    valid = depth > 0
    noisy = depth + rng.normal(0.0, sigma_m, size=depth.shape).astype(np.float32)
    return np.where(valid & (noisy > 0), noisy, np.float32(0.0)).astype(np.float32)


def drop_blocks(depth: Depth, share: float, rng: np.random.Generator, block: int = HOLE_BLOCK) -> Depth:
    """``depth`` with holes (0: no reading), as a stereo camera's failed matches: random
    ``block`` x ``block`` squares, drawn until ``share`` of the frame's pixels that had a
    reading have none (blocks overlap, so more are drawn until the share is reached)."""
    valid = depth > 0
    target = round(share * depth.size)
    if target > int(valid.sum()):
        raise ValueError(f"{share:.1%} of the frame is more than its {int(valid.sum())} pixels with a reading")
    h, w = depth.shape
    holes = np.zeros(depth.shape, dtype=bool)
    offsets = np.arange(block)
    while int((holes & valid).sum()) < target:
        missing = target - int((holes & valid).sum())
        n = max(1, -(-missing // (block * block)))
        rows = rng.integers(0, h - block + 1, size=n)
        cols = rng.integers(0, w - block + 1, size=n)
        holes[(rows[:, None, None] + offsets[None, :, None]), (cols[:, None, None] + offsets[None, None, :])] = True
    return np.where(holes, np.float32(0.0), depth).astype(np.float32)


@dataclasses.dataclass(frozen=True)
class Setting:
    """One way the frame reaches ``ground_frame``: its name, what it does (for the JSON), whether
    the camera's pose is given, and the change to the depth image and the camera model."""

    name: str
    definition: str
    pose: bool
    apply: Callable[[Depth, CameraIntrinsics, np.random.Generator], tuple[Depth, CameraIntrinsics]]


def _same(depth: Depth, k: CameraIntrinsics, _rng: np.random.Generator) -> tuple[Depth, CameraIntrinsics]:
    return depth, k


def _noise(sigma_m: float) -> Callable[[Depth, CameraIntrinsics, np.random.Generator], tuple[Depth, CameraIntrinsics]]:
    def apply(depth: Depth, k: CameraIntrinsics, rng: np.random.Generator) -> tuple[Depth, CameraIntrinsics]:
        return gaussian_noise(depth, sigma_m, rng), k

    return apply


def _noise_holes(depth: Depth, k: CameraIntrinsics, rng: np.random.Generator) -> tuple[Depth, CameraIntrinsics]:
    return drop_blocks(gaussian_noise(depth, 0.002, rng), 0.02, rng), k


def _focal(depth: Depth, k: CameraIntrinsics, _rng: np.random.Generator) -> tuple[Depth, CameraIntrinsics]:
    return depth, dataclasses.replace(k, fx=k.fx * 1.05, fy=k.fy * 1.05)


SETTINGS: tuple[Setting, ...] = (
    Setting("clean, pose given (ref.)", "the simulator's frame as captured, with the camera's cam_to_world", True,
            _same),
    Setting("clean, no pose", "the same frame; the world frame made from the fitted table plane", False, _same),
    Setting("depth in whole mm", "depth rounded to whole millimetres as a uint16 RealSense frame "
            "(depth scale 0.001), read back as metres; no pose", False, lambda d, k, _r: (quantise_mm(d), k)),
    Setting("noise 1 mm", "zero-mean Gaussian depth noise, sigma 1 mm, where depth > 0; no pose", False,
            _noise(0.001)),
    Setting("noise 2 mm", "zero-mean Gaussian depth noise, sigma 2 mm, where depth > 0; no pose", False,
            _noise(0.002)),
    Setting("noise 4 mm", "zero-mean Gaussian depth noise, sigma 4 mm, where depth > 0; no pose", False,
            _noise(0.004)),
    Setting("noise 2 mm + 2 % holes", "Gaussian noise sigma 2 mm where depth > 0, then 2 % of the frame's "
            "pixels set to 0 in random 3x3 blocks (only pixels with a reading count); no pose", False, _noise_holes),
    Setting("fx, fy 5 % too large", "the image unchanged, the camera model given to ground_frame with fx and fy "
            "5 % too large (a bad calibration); no pose", False, _focal),
)


def _box(box: Box) -> tuple[int, int, int, int]:
    """A region's box as ``box_iou`` types it (regions' boxes are floats; its arithmetic is the
    same on them)."""
    return cast(tuple[int, int, int, int], box)


def _iou(a: Box | None, b: Box | None) -> float:
    from craft_e.runtime.perception.roi import box_iou

    return 0.0 if a is None or b is None else box_iou(_box(a), _box(b))


def run_scene(found: Any, target_box: Box | None) -> dict[str, Any]:
    """What one grounding of one frame leaves for the table: the chosen box, its extents, whether
    it is the target, its grasp, and the regions' boxes and extents (to match the reference's)."""
    chosen = found.grounding.chosen
    roi = found.rois[chosen.index] if chosen is not None else None
    box = tuple(float(v) for v in roi.box_xywh) if roi is not None else None
    return {
        "chosen_box": box,
        "chosen_name": chosen.hypotheses[0].name if chosen is not None and chosen.hypotheses else None,
        "chosen_extents_m": list(roi.extents_m) if roi is not None and roi.extents_m is not None else None,
        "detect": box is not None and _iou(box, target_box) >= MATCH_IOU,
        "grasp": found.grasp is not None,
        "regions": len(found.rois),
        "boxes": [tuple(float(v) for v in r.box_xywh) for r in found.rois],
        "extents_m": [list(r.extents_m) if r.extents_m is not None else None for r in found.rois],
    }


def compare(row: dict[str, Any], ref: dict[str, Any]) -> None:
    """Add to ``row`` whether its choice is the reference's and its extents' signed differences
    (mm, this setting less the reference) from the reference's measurement of the same region
    (best box IoU >= ``MATCH_IOU``): signed, because noise biases them (the height is a high
    percentile of the region's points, which noise lifts) as well as spreading them."""
    if row["chosen_box"] is None or ref["chosen_box"] is None:
        row["same_as_ref"] = row["chosen_box"] is None and ref["chosen_box"] is None
    else:
        row["same_as_ref"] = _iou(row["chosen_box"], ref["chosen_box"]) >= MATCH_IOU
    row["extent_diff_mm"] = None
    if row["chosen_box"] is None or row["chosen_extents_m"] is None or not ref["boxes"]:
        return
    ious = [_iou(row["chosen_box"], b) for b in ref["boxes"]]
    best = int(np.argmax(ious))
    if ious[best] >= MATCH_IOU and ref["extents_m"][best] is not None:
        row["extent_diff_mm"] = [round((a - b) * 1000.0, 3)
                                  for a, b in zip(row["chosen_extents_m"], ref["extents_m"][best], strict=True)]


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """One setting's numbers over the scenes (errors: refused frames, counted as no choice)."""
    n = len(rows)
    errors = [r for r in rows if "error" in r]
    ok = [r for r in rows if "error" not in r]
    signed = [d for r in ok if r["extent_diff_mm"] is not None for d in r["extent_diff_mm"]]
    diffs = [abs(d) for d in signed]
    measured = sum(r["extent_diff_mm"] is not None for r in ok)
    return {
        "scenes": n,
        "detect": sum(r["detect"] for r in ok),
        "same_as_ref": sum(r["same_as_ref"] for r in ok),
        "grasp": sum(r["grasp"] for r in ok),
        "regions_mean": round(float(np.mean([r["regions"] for r in ok])), 3) if ok else None,
        "extent_error_mm_median": round(float(np.median(diffs)), 3) if diffs else None,
        "extent_error_mm_p90": round(float(np.percentile(diffs, 90)), 3) if diffs else None,
        "extent_bias_mm_median": round(float(np.median(signed)), 3) if signed else None,
        "extent_scenes": measured,
        "errors": len(errors),
        "changed_choice": [r["scene"] for r in ok if not r["same_as_ref"]],
        "lost_detect": [r["scene"] for r in ok if not r["detect"] and r["ref_detect"]],
        "gained_detect": [r["scene"] for r in ok if r["detect"] and not r["ref_detect"]],
    }


def table(title: str, summary: dict[str, dict[str, Any]]) -> str:
    """The Markdown table: one row per setting."""
    pct = percent
    lines = [title, "",
             "| setting | Detect % | same choice as ref. % | with a grasp % | regions / scene | "
             "extents: median abs. error (mm) | extents: median signed error (mm) | scenes measured | refused |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, s in summary.items():
        median = "-" if s["extent_error_mm_median"] is None else f"{s['extent_error_mm_median']:.2f}"
        bias = "-" if s["extent_bias_mm_median"] is None else f"{s['extent_bias_mm_median'] + 0.0:+.2f}".replace(
            "-0.00", "+0.00")
        regions = "-" if s["regions_mean"] is None else f"{s['regions_mean']:.2f}"
        lines.append(f"| {name} | {pct(s['detect'], s['scenes'])} | {pct(s['same_as_ref'], s['scenes'])} | "
                     f"{pct(s['grasp'], s['scenes'])} | {regions} | {median} | {bias} | {s['extent_scenes']} | "
                     f"{s['errors']} |")
    changed = [f"{name}: {', '.join(s['changed_choice'])}" for name, s in summary.items() if s["changed_choice"]]
    lines += ["", "Extents: each chosen region's three edges (longest first) against the reference's for the same "
              "region, pooled over the scenes where both were measured (signed: this setting less the reference). "
              "Choice changed from the reference in: "
              + ("; ".join(changed) if changed else "no scene") + "."]
    return "\n".join(lines) + "\n"


def main() -> None:
    args = options(__doc__.split("\n\n")[0], seed=True).parse_args()

    from craft_e.runtime.frame import FrameError, ground_frame
    from craft_e.runtime.sim.env import SimEnv
    from craft_e.runtime.sim.oracle import gt_rois

    run = FrameRun(args)
    rows: dict[str, list[dict[str, Any]]] = {s.name: [] for s in SETTINGS}
    with SimEnv() as env:
        for n, spec in enumerate(run.specs):
            env.reset(spec.scene)
            env.robot.reset_home()
            obs = env.capture()
            target = env.scene.target.body_id
            target_box = next((tuple(float(v) for v in r.box_xywh) for r in gt_rois(obs, env.scene)
                               if r.label == target), None)
            ref: dict[str, Any] | None = None
            for i, setting in enumerate(SETTINGS):
                rng = np.random.default_rng([args.seed, n, i])
                depth, k = setting.apply(np.asarray(obs.depth, dtype=np.float32), obs.intrinsics, rng)
                try:
                    found = ground_frame(run.grounder, run.encoder, run.config, spec.verb, obs.rgb, depth, k,
                                         obs.cam_to_world if setting.pose else None)
                except FrameError as exc:
                    row: dict[str, Any] = {"error": str(exc)}
                else:
                    row = run_scene(found, target_box)
                row.update(scene=spec.id, target_visible=target_box is not None)
                if ref is None:
                    if "error" in row:
                        raise RuntimeError(f"{spec.id}: the reference frame was refused: {row['error']}")
                    ref = row
                if "error" not in row:
                    compare(row, ref)
                    row["ref_detect"] = ref["detect"]
                rows[setting.name].append(row)
            run.progress(n + 1)
    summary = {name: summarise(r) for name, r in rows.items()}
    title = (f"### `ground_frame` under real-camera depth effects, {len(run.specs)} sim-dev scenes, seed {args.seed} "
             f"(`{run.command}`)")
    for setting_rows in rows.values():
        for r in setting_rows:
            r.pop("boxes", None)
            r.pop("extents_m", None)
    run.publish(table(title, summary), {
        "seed": args.seed, "match_iou": MATCH_IOU,
        "settings": {s.name: {"definition": s.definition, "pose_given": s.pose} for s in SETTINGS},
        "summary": summary, "per_scene": rows,
    })


if __name__ == "__main__":
    main()
