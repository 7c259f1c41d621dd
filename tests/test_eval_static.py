"""``craft eval static``: ground-truth grasp rectangles, the success criterion, the CLI."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from craft_e.runtime.evaluation.static_eval import (
    NoiseLevel,
    gt_grasp_poses,
    gt_grasp_rects,
    parse_noise,
)
from craft_e.runtime.grasp.geometry import Grasp2D
from craft_e.runtime.grasp.metrics import grasp_success
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.scene import Scene, SceneSpec

SPEC = SceneSpec(verb="cut", target="knife",
                 distractors=("apple", "mustard_bottle", "a_cups", "glue_1"), seed=3)


@pytest.fixture(scope="module")
def rendered() -> Iterator[tuple[Scene, Any]]:
    with SimEnv() as env:
        scene = env.reset(SPEC)
        yield scene, env.capture()


def _rotated(rect: Grasp2D, degrees: float) -> Grasp2D:
    return Grasp2D(rect.center_xy, rect.angle_rad + math.radians(degrees), rect.width_px,
                   rect.length_px, rect.quality)


def test_gt_grasp_of_the_target_passes_and_a_45_degree_turn_fails(rendered: tuple[Scene, Any]) -> None:
    scene, obs = rendered
    rects = gt_grasp_rects(scene, obs, scene.target.body_id)
    assert len(rects) >= 5  # a knife is held anywhere along its length
    assert len({round(r.angle_rad, 6) for r in rects}) == 1  # ...but only across it
    best = rects[0]
    assert grasp_success(best, rects)
    assert grasp_success(_rotated(best, 20), rects)  # inside the 30° tolerance
    assert not grasp_success(_rotated(best, 45), rects)
    shifted = Grasp2D((best.center_xy[0] + 200, best.center_xy[1]), best.angle_rad, best.width_px,
                      best.length_px, 1.0)
    assert not grasp_success(shifted, rects)


def test_round_objects_get_grasps_in_every_direction(rendered: tuple[Scene, Any]) -> None:
    scene, _ = rendered
    apple = next(o for o in scene.objects if o.asset_id == "apple")
    yaws = {round(g.yaw, 4) for g in gt_grasp_poses(scene, apple.body_id)}
    assert len(yaws) >= 6
    assert all(g.width_m < 0.08 for g in gt_grasp_poses(scene, apple.body_id))


def test_noise_levels_parse() -> None:
    assert parse_noise("grasp=0.1,box=0.25") == NoiseLevel(0.1, 0.25)
    assert parse_noise("box=0.5").label == "box=0.5"
    assert NoiseLevel().label == "clean"
    for bad in ("grasp", "blur=2", "box=1.5", "grasp=x"):
        with pytest.raises(ValueError):
            parse_noise(bad)


def test_cli_runs_the_three_settings_with_noise(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app

    labels = tmp_path / "labels.csv"
    labels.write_text("cut,knife\n")
    out = tmp_path / "static.json"
    result = CliRunner().invoke(app, ["eval", "static", "--labels", str(labels), "--layouts", "1",
                                      "--grasp", "antipodal", "--noise", "grasp=0.2,box=0.3",
                                      "--methods", "CRAFT-E,alignment-only", "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert "Perfect Grasp & Detect" in result.output and "Full Pipeline" in result.output
    data = json.loads(out.read_text())
    assert set(data["levels"]) == {"clean", "grasp=0.2,box=0.3"}
    clean = data["levels"]["clean"]
    assert set(clean) == {"gt/gt", "gt/predicted", "antipodal/predicted"}
    for level in data["levels"].values():
        for setting in level.values():
            for row in setting["methods"].values():
                assert all(0.0 <= row[k] <= 1.0 for k in ("accuracy", "detect", "grasp"))
                assert row["accuracy"] <= min(row["detect"], 1.0)
    # with ground-truth ROIs and grasps the target's own grasp is always right
    assert clean["gt/gt"]["methods"]["CRAFT-E"]["grasp"] == 1.0
    episode = data["episodes"][0]
    assert episode["target"] == "knife" and episode["target_gt_grasps"] > 0
