"""Benchmark: where a real robot's camera may stand, and what a workspace box changes.

Why: ``craft perceive`` runs the testbed robot's perception on any RGB-D frame, but the testbed's
camera is always straight above the table's middle, 0.70 m up, and sees the table alone. A real
robot's camera is mounted where it fits: tilted, farther away, with the robot's own base, the
table's edge or the floor in view. Segmentation finds everything that stands above the table
plane, so what is not an object becomes a region like any other, and grounding may choose it.
This benchmark renders each sim-dev scene from other camera poses and grounds the frame with the
camera's pose given, four ways: with and without a workspace (``perception/workspace.py``: the
table's box where the testbed places its objects, ``PlacementConfig.bounds``, under a ceiling
``CEILING``), each with and without splitting a region whose raised points stand apart on the
table (``SegmentConfig.split_on_table``, a frame's default since session 40); and counts:

* Detect: the chosen region's box has IoU >= 0.5 with the target's true box (``sim.oracle.gt_rois``,
  from that camera);
* "not an object": fewer than half of the chosen region's pixels show a scene object (in these
  views, the arm and the drop zone's marker);
* regions that are not objects, per scene (the same test on every region); regions per scene;
* the share with a grasp.

Every view looks at the same point (the table's middle, ``TableLayout``'s camera target) from its
own eye; the camera model is the testbed's (640 x 480, fx = fy = 615). The robot stands at its home
posture. Nothing is random: the scenes are ``make_episode_specs(..., layouts=1)``'s.

Run: ``.venv/bin/python benchmarks/bench_frame_views.py [--scenes 35] [--json OUT] [--markdown OUT]``
(all 35 sim-dev pairs by default; about 9 min on 2 cores). Results: ``docs/results/frame_views.md``
and ``.json``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from frame_bench import FrameRun, options, percent

MATCH_IOU = 0.5  # Detect's threshold
OBJECT_SHARE = 0.5  # a region "is" an object when at least this share of its pixels show one
TARGET = (0.375, 0.0, 0.0)  # the testbed camera's target: the middle of the objects' area
DISTANCE = 0.70  # m, the testbed camera's height above it
#: m: the workspace's ceiling, above any sim asset that can stand upright (the spray bottle, 0.28 m
#: along its longest edge; the longer hammer, spatula and chain lie down) and below the arm's
#: links at its home posture (0.34 m and up where they hang over the table)
CEILING = 0.30


@dataclass(frozen=True)
class View:
    """A camera pose: its name, what it is, and its eye's offset from ``TARGET``."""

    name: str
    definition: str
    tilt_deg: float  # from straight down
    towards: str  # "side": the eye moves along +y (across the arm's reach); "far": along +x (away
    # from the arm, looking back at it); "near": along -x (over the arm)
    distance: float = DISTANCE

    def eye(self) -> tuple[float, float, float]:
        t = math.radians(self.tilt_deg)
        horizontal = {"side": (0.0, 1.0), "far": (1.0, 0.0), "near": (-1.0, 0.0)}[self.towards]
        return (TARGET[0] + self.distance * math.sin(t) * horizontal[0],
                TARGET[1] + self.distance * math.sin(t) * horizontal[1],
                TARGET[2] + self.distance * math.cos(t))


VIEWS: tuple[View, ...] = (
    View("overhead (the testbed's)", "0.70 m straight above the objects' area", 0.0, "side"),
    View("tilted 15 deg, side", "0.70 m from the same point, 15 degrees off vertical across the arm's reach", 15.0,
         "side"),
    View("tilted 30 deg, side", "as above, 30 degrees", 30.0, "side"),
    View("tilted 45 deg, side", "as above, 45 degrees", 45.0, "side"),
    View("tilted 30 deg, far side", "30 degrees off vertical from beyond the table, looking back at the arm", 30.0,
         "far"),
    View("tilted 45 deg, far side", "as above, 45 degrees", 45.0, "far"),
    View("tilted 20 deg, over the arm", "20 degrees off vertical from the arm's side, its links in view", 20.0,
         "near"),
    View("0.90 m overhead", "straight above, 0.90 m: the arm's base and the drop zone in view", 0.0, "side", 0.90),
)


def _camera(view: View) -> Any:
    from craft_e.runtime.sim.camera import Camera

    return Camera(eye=view.eye(), target=TARGET, up=(1.0, 0.0, 0.0))


def _is_object(mask: np.ndarray | None, seg: np.ndarray, bodies: set[int], box: tuple[float, ...]) -> bool:
    """Whether at least ``OBJECT_SHARE`` of the region's pixels show a scene object (its mask, or
    its box when it has none)."""
    if mask is None:
        x, y, w, h = (int(v) for v in box)
        pixels = seg[y:y + h, x:x + w].ravel()
    else:
        pixels = seg[mask]
    return pixels.size > 0 and float(np.isin(pixels, list(bodies)).mean()) >= OBJECT_SHARE


def run_view(found: Any, obs: Any, bodies: set[int], target_box: tuple[float, ...] | None) -> dict[str, Any]:
    """One grounded frame's row: the choice, whether it is the target or no object, the regions."""
    from craft_e.runtime.perception.roi import box_iou

    chosen = found.grounding.chosen
    roi = found.rois[chosen.index] if chosen is not None else None
    box = tuple(float(v) for v in roi.box_xywh) if roi is not None else None
    objects = [_is_object(r.mask, obs.seg, bodies, r.box_xywh) for r in found.rois]
    return {
        "chosen_name": chosen.hypotheses[0].name if chosen is not None and chosen.hypotheses else None,
        "detect": box is not None and target_box is not None and box_iou(box, target_box) >= MATCH_IOU,  # type: ignore[arg-type]
        "chosen_not_object": chosen is not None and not objects[chosen.index],
        "regions": len(found.rois),
        "regions_not_object": objects.count(False),
        "grasp": found.grasp is not None,
        "target_visible": target_box is not None,
    }


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    ok = [r for r in rows if "error" not in r]
    return {
        "scenes": len(rows),
        "detect": sum(r["detect"] for r in ok),
        "chosen_not_object": sum(r["chosen_not_object"] for r in ok),
        "grasp": sum(r["grasp"] for r in ok),
        "regions_mean": round(float(np.mean([r["regions"] for r in ok])), 3) if ok else None,
        "regions_not_object_mean": round(float(np.mean([r["regions_not_object"] for r in ok])), 3) if ok else None,
        "target_visible": sum(r["target_visible"] for r in rows),
        "errors": len(rows) - len(ok),
        "chose_not_object_in": [r["scene"] for r in ok if r["chosen_not_object"]],
    }


def table(title: str, summary: dict[str, dict[str, dict[str, Any]]]) -> str:
    """The Markdown table: one row per camera pose and workspace."""
    pct = percent
    lines = [title, "",
             "| camera | workspace, split | Detect % | chose no object | regions / scene | regions not objects / scene | "
             "with a grasp % | refused |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for view, by_limit in summary.items():
        for limit, s in by_limit.items():
            lines.append(f"| {view} | {limit} | {pct(s['detect'], s['scenes'])} | {s['chosen_not_object']} | "
                         f"{s['regions_mean']:.2f} | {s['regions_not_object_mean']:.2f} | "
                         f"{pct(s['grasp'], s['scenes'])} | {s['errors']} |")
    lines += ["", "Detect: the chosen region's box meets the target's true box at IoU >= 0.5. Not an object: under "
              "half of a region's pixels show a scene object (in these views, the arm and the drop zone's marker). "
              f"Workspace: `--workspace 0.14,0.61,-0.30,0.30,{CEILING:g}` (the box where the testbed places objects, "
              f"under a ceiling {CEILING:g} m above the table: the arm's links at home hang higher); none: the whole "
              "frame. Split: a region whose raised points form clusters apart on the table is split "
              "(`SegmentConfig.split_on_table`, on for a camera's frames since session 40); no split: as before."]
    return "\n".join(lines) + "\n"


def main() -> None:
    args = options(__doc__.split("\n\n")[0]).parse_args()

    from craft_e.runtime.frame import FrameError, ground_frame
    from craft_e.runtime.perception.workspace import Workspace
    from craft_e.runtime.sim.camera import render
    from craft_e.runtime.sim.env import SimEnv
    from craft_e.runtime.sim.oracle import gt_rois
    from craft_e.runtime.sim.scene import TableLayout

    bounds = TableLayout().placement.bounds
    area = Workspace(bounds.x_min, bounds.x_max, bounds.y_min, bounds.y_max, CEILING)
    # (workspace, split regions on the table): each frame grounded four ways
    limits: dict[str, tuple[Workspace | None, bool]] = {
        "none, no split": (None, False), "objects' area, no split": (area, False),
        "none (the default)": (None, True), "objects' area": (area, True)}
    run = FrameRun(args)
    configs = {split: dataclasses.replace(run.config, segment=dataclasses.replace(run.config.segment,
                                                                                    split_on_table=split))
               for split in (False, True)}
    rows: dict[str, dict[str, list[dict[str, Any]]]] = {v.name: {k: [] for k in limits} for v in VIEWS}
    cameras = {v.name: _camera(v) for v in VIEWS}
    with SimEnv() as env:
        for n, spec in enumerate(run.specs):
            env.reset(spec.scene)
            env.robot.reset_home()
            bodies = {o.body_id for o in env.scene.objects}
            target = env.scene.target.body_id
            for view in VIEWS:
                camera = cameras[view.name]
                obs = render(env.client, camera)
                target_box = next((tuple(float(v) for v in r.box_xywh) for r in gt_rois(obs, env.scene)
                                   if r.label == target), None)
                for limit, (workspace, split) in limits.items():
                    try:
                        found = ground_frame(run.grounder, run.encoder, configs[split], spec.verb, obs.rgb,
                                             obs.depth, obs.intrinsics, camera.cam_to_world(), workspace=workspace)
                    except FrameError as exc:
                        row: dict[str, Any] = {"error": str(exc), "target_visible": target_box is not None}
                    else:
                        row = run_view(found, obs, bodies, target_box)
                    row["scene"] = spec.id
                    rows[view.name][limit].append(row)
            run.progress(n + 1)
    summary = {view: {limit: summarise(r) for limit, r in by_limit.items()} for view, by_limit in rows.items()}
    title = f"### `ground_frame` from other camera poses, {len(run.specs)} sim-dev scenes (`{run.command}`)"
    run.publish(table(title, summary), {
        "match_iou": MATCH_IOU, "object_share": OBJECT_SHARE,
        "views": {v.name: {"definition": v.definition, "eye_m": [round(c, 4) for c in v.eye()],
                           "target_m": list(TARGET)} for v in VIEWS},
        "settings": {k: {"workspace": None if w is None else w.bounds(), "split_on_table": split}
                     for k, (w, split) in limits.items()},
        "summary": summary, "per_scene": rows,
    })


if __name__ == "__main__":
    main()
