"""The antipodal fallback for regions the grasp network offers nothing usable on (``sim/fallback.py``).

Why: a dice or a golf ball gets no GR-ConvNet peak at all, so grounding could not choose it
whatever the knowledge said. The fallback must (1) find grasps on such a region, (2) be asked
for only when the fingers fit around no network grasp, in both the evaluation's and the robot's
path (then each region's list is best first, which the robot's lazy path needs), and (3) give
the same grasps as the sampler on the whole frame though it runs on a crop.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from conftest import episode_spec, load_script

from craft_e.runtime.grasp.antipodal import AntipodalConfig, sample_antipodal_grasps
from craft_e.runtime.grasp.geometry import CameraIntrinsics, Grasp2D, TopDownGrasp
from craft_e.runtime.sim import candidates, grasp_checks, perceive, pipeline
from craft_e.runtime.sim.fallback import FallbackConfig, fallback_grasps

INTR = CameraIntrinsics.realsense_d435()
TABLE_DEPTH = 0.7  # m: a camera straight above the table


def dice_scene(side_m: float = 0.016, centre: tuple[int, int] = (400, 300)) -> tuple[
        npt.NDArray[np.float32], npt.NDArray[np.bool_], tuple[int, int, int, int]]:
    """Depth of a small cube on a table, its mask and box (what segmentation hands over)."""
    depth = np.full((INTR.height, INTR.width), TABLE_DEPTH, np.float32)
    half = round(side_m / 2 * INTR.fx / TABLE_DEPTH)
    cx, cy = centre
    depth[cy - half:cy + half, cx - half:cx + half] = TABLE_DEPTH - side_m
    mask = depth < TABLE_DEPTH - 0.005
    return depth, mask, (cx - half, cy - half, 2 * half, 2 * half)


def test_a_dice_gets_grasps_best_first() -> None:
    depth, mask, box = dice_scene()
    found = fallback_grasps(depth, mask, box, INTR, max_opening_m=0.08, min_clearance_m=0.005, max_grasps=5, config=FallbackConfig())
    assert found, "the sampler should find the cube's faces"
    qualities = [g.quality for g in found]
    assert all(0.0 < q <= 1.0 for q in qualities)
    assert qualities == sorted(qualities, reverse=True)  # best first, as the lazy path needs
    for g in found:
        assert mask[round(g.center_xy[1]), round(g.center_xy[0])]
    scaled = fallback_grasps(depth, mask, box, INTR, max_opening_m=0.08, min_clearance_m=0.005, max_grasps=5,
                             config=FallbackConfig(quality_scale=0.2))
    assert [g.quality for g in scaled] == pytest.approx([0.2 * q for q in qualities])
    with pytest.raises(ValueError, match="quality_scale"):
        FallbackConfig(quality_scale=0.0)


def mug_scene(handle: bool = True) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_], tuple[int, int, int, int]]:
    """Depth of a 10 cm wide round body (wider than the hand opens) with, on its right, a handle
    2 cm wide that stands out 4 cm: the mug or pitcher seen from above. Its mask and box."""
    depth = np.full((INTR.height, INTR.width), TABLE_DEPTH, np.float32)
    px = INTR.fx / TABLE_DEPTH  # pixels per metre at the table
    cx, cy = 300, 240
    vv, uu = np.mgrid[0:INTR.height, 0:INTR.width]
    radius = 0.05 * px
    depth[(uu - cx) ** 2 + (vv - cy) ** 2 <= radius ** 2] = TABLE_DEPTH - 0.10
    if handle:
        depth[(abs(vv - cy) <= 0.01 * px) & (uu > cx) & (uu <= cx + radius + 0.04 * px)] = TABLE_DEPTH - 0.09
    mask = depth < TABLE_DEPTH - 0.005
    ys, xs = np.nonzero(mask)
    return depth, mask, (int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1))


def test_a_handle_on_a_body_too_wide_for_the_hand_gets_a_grasp() -> None:
    """The sampler's centres gather where the region is deepest (the body); without the centres on
    its thin parts the handle, the only part the fingers fit around, got none (the pitcher's and a
    mug's ``no_grasp`` on sim-dev). With them the grasps lie on the handle, across it. They are
    drawn only when the others find nothing, so a region with grasps keeps them."""
    depth, mask, box = mug_scene()
    kwargs = {"max_opening_m": 0.08, "min_clearance_m": 0.003, "max_grasps": 5}
    assert fallback_grasps(depth, mask, box, INTR, config=FallbackConfig(thin_centres=0), **kwargs) == []  # type: ignore[arg-type]
    found = fallback_grasps(depth, mask, box, INTR, config=FallbackConfig(), **kwargs)  # type: ignore[arg-type]
    assert found
    px = INTR.fx / TABLE_DEPTH
    for g in found:
        x, y = g.center_xy
        assert x > 300 + 0.05 * px and abs(y - 240) <= 0.01 * px + 1  # on the handle, beyond the body
        assert abs(math.cos(g.angle_rad)) < 0.5  # closing across the handle (vertical in the image)
    assert fallback_grasps(*mug_scene(handle=False), INTR, config=FallbackConfig(), **kwargs) == []  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="thin_centres"):
        FallbackConfig(thin_centres=-1)


def test_the_thin_parts_are_a_last_resort() -> None:
    """A bottle lying down, 6 cm across, with a 1.5 cm nozzle at one end: the sampler's own
    centres find grasps across the body, and those stand. Its centres on thin parts, asked for
    always, would move the nozzle up the list (a narrow span scores well), far from the body's mass:
    the Windex bottle held there slipped in the carry (``craft eval pickability``, pose 1)."""
    depth = np.full((INTR.height, INTR.width), TABLE_DEPTH, np.float32)
    px = INTR.fx / TABLE_DEPTH
    vv, uu = np.mgrid[0:INTR.height, 0:INTR.width]
    cx, cy = 300, 240
    depth[(abs(vv - cy) <= 0.03 * px) & (abs(uu - cx) <= 0.06 * px)] = TABLE_DEPTH - 0.06
    nozzle = (abs(vv - cy) <= 0.0075 * px) & (uu > cx + 0.06 * px) & (uu <= cx + 0.10 * px)
    depth[nozzle] = TABLE_DEPTH - 0.04
    mask = depth < TABLE_DEPTH - 0.005
    ys, xs = np.nonzero(mask)
    box = (int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1))
    kwargs = {"max_opening_m": 0.08, "min_clearance_m": 0.003, "max_grasps": 5}
    shipped = fallback_grasps(depth, mask, box, INTR, config=FallbackConfig(), **kwargs)  # type: ignore[arg-type]
    assert shipped and shipped == fallback_grasps(depth, mask, box, INTR, config=FallbackConfig(thin_centres=0), **kwargs)  # type: ignore[arg-type]
    always = sample_antipodal_grasps(depth, mask, INTR, 5, AntipodalConfig(max_opening_m=0.08, min_clearance_m=0.003,
                                                                          n_thin_centres=32))
    assert always != shipped  # asked for always, they would change the grasps of a region that has some
    on_nozzle = [i for i, g in enumerate(always) if g.center_xy[0] > cx + 0.06 * px]
    assert on_nozzle and on_nozzle[0] < max(i for i, g in enumerate(shipped) if g.center_xy[0] > cx + 0.06 * px)


def test_the_crop_gives_the_whole_frames_grasps() -> None:
    depth, mask, box = dice_scene(0.04, centre=(150, 120))
    whole = sample_antipodal_grasps(depth, mask, INTR, 5, AntipodalConfig(max_opening_m=0.08))
    cropped = fallback_grasps(depth, mask, box, INTR, max_opening_m=0.08, min_clearance_m=0.005, max_grasps=5, config=FallbackConfig())
    assert whole and len(cropped) == len(whole)
    for c, w in zip(cropped, whole, strict=True):
        assert c.center_xy == pytest.approx(w.center_xy, abs=1e-6)
        assert (c.angle_rad, c.width_px) == pytest.approx((w.angle_rad, w.width_px), abs=1e-9)
        assert c.quality == pytest.approx(w.quality)


def test_a_region_without_pixels_or_depth_gets_nothing() -> None:
    depth, mask, box = dice_scene()
    kwargs = {"max_opening_m": 0.08, "min_clearance_m": 0.005, "max_grasps": 5, "config": FallbackConfig()}
    assert fallback_grasps(depth, np.zeros_like(mask), box, INTR, **kwargs) == []  # type: ignore[arg-type]
    assert fallback_grasps(np.full_like(depth, np.nan), mask, box, INTR, **kwargs) == []  # type: ignore[arg-type]


def test_only_grasp_networks_with_checks_have_a_fallback() -> None:
    assert pipeline.PipelineConfig().uses_fallback
    assert pipeline.PipelineConfig().to_dict()["grasp_fallback"] is True
    assert not pipeline.PipelineConfig(grasp="antipodal").uses_fallback  # the sampler is the source
    assert not pipeline.PipelineConfig(grasp="oracle").uses_fallback
    assert not pipeline.PipelineConfig(fit_filter=False).uses_fallback  # "usable" needs the checks
    assert not pipeline.PipelineConfig(fallback=FallbackConfig(enabled=False)).uses_fallback


def _candidate(i: int, quality: float, fallback: bool = False) -> candidates.GraspCandidate:
    pose = TopDownGrasp(position=np.array([0.4, 0.01 * i, 0.05]), yaw=0.0, width_m=0.04)
    return candidates.GraspCandidate(Grasp2D((10.0 * i, 5.0), 0.0, 20.0, 10.0, quality), pose, fallback=fallback)


def _index(c: candidates.GraspCandidate) -> int:
    assert c.pose is not None
    return round(float(c.pose.position[1]) / 0.01)


def test_the_evaluation_asks_for_the_fallback_only_when_no_network_grasp_fits(
        monkeypatch: pytest.MonkeyPatch) -> None:
    passing: set[int] = {1}
    unreachable: set[int] = set()

    def finger(material: object, pose: TopDownGrasp, *_: object) -> tuple[bool, str]:
        return round(float(pose.position[1]) / 0.01) in passing, "does not fit"

    def problems(env: object, pose: TopDownGrasp, *_: object) -> tuple[str | None, str | None]:
        return ("unreachable" if round(float(pose.position[1]) / 0.01) in unreachable else None), None

    monkeypatch.setattr(grasp_checks, "finger_check", finger)
    monkeypatch.setattr(grasp_checks, "pick_problems", problems)
    config = pipeline.PipelineConfig()
    surfaces = grasp_checks.Surfaces(np.zeros((0, 3)), 0.0)
    asked: list[int] = []

    def more() -> list[candidates.GraspCandidate]:
        asked.append(1)
        return [_candidate(5, 0.15, fallback=True), _candidate(6, 0.1, fallback=True)]

    network = [_candidate(0, 0.9), _candidate(1, 0.5)]
    listed, usable = grasp_checks.usable_grasps(None, list(network), surfaces, config, more=more)  # type: ignore[arg-type]
    assert [_index(c) for c in usable] == [1] and not asked and len(listed) == 2
    unreachable.add(1)  # a network grasp fits but its pick is unreachable: the region has none
    listed, usable = grasp_checks.usable_grasps(None, list(network), surfaces, config, more=more)  # type: ignore[arg-type]
    assert not usable and not asked and len(listed) == 2
    passing.clear()
    passing.add(6)
    listed, usable = grasp_checks.usable_grasps(None, list(network), surfaces, config, more=more)  # type: ignore[arg-type]
    assert asked == [1]
    assert [_index(c) for c in listed] == [0, 1, 5, 6]  # the fallback's grasps are listed after the network's
    assert [(_index(c), c.fallback) for c in usable] == [(6, True)]


def test_in_a_dev_scene_both_paths_give_the_dice_the_same_fallback_grasp() -> None:
    """``pour/cup/2`` (sim-dev): GR-ConvNet finds no peak on the dice among the distractors. The
    evaluation's path lists the fallback's grasps after the (no) network grasps and uses the first
    that passes; the robot's path defers the sampler (``choose.LazyROI``) and, once run, offers the
    same grasp first. Regions whose network grasps fit have no fallback pending."""
    from craft_e.paths import SIM_DEV_LABELS
    from craft_e.runtime.evaluation.sim_eval import (
        default_encoder,
    )
    from craft_e.runtime.sim.choose import perceive_for_pick
    from craft_e.runtime.sim.env import SimEnv

    spec = episode_spec(SIM_DEV_LABELS, "pour/cup/2")
    config = pipeline.PipelineConfig()
    encoder = default_encoder(1)
    with SimEnv() as env:
        env.reset(spec.scene)
        env.robot.reset_home()
        obs = env.capture()
        eager = perceive.perceive(env, encoder, config, obs)
        dice = [i for i, r in enumerate(eager.rois) if r.usable and r.usable[0].fallback]
        assert len(dice) == 1 and env.scene.body_assets[eager.rois[dice[0]].body] == "dice"
        used = eager.rois[dice[0]].usable[0]
        assert used.pose is not None and 0 < used.quality <= 1
        lazy = perceive_for_pick(env, encoder, config, obs)
        no_network_fit = [i for i, r in enumerate(eager.rois)
                          if not any(c.fits and not c.fallback for c in r.candidates)]
        assert dice[0] in no_network_fit
        assert [i for i, r in enumerate(lazy) if r.pending_fallback] == no_network_fit
        assert lazy[dice[0]].as_roi("dice").grasp_scores == [1.0]  # the placeholder, before the sampler
        lazy[dice[0]].run_fallback()
        first = lazy[dice[0]].as_roi("dice").grasps[0]
        assert isinstance(first, candidates.GraspCandidate) and first.fallback and first.pose is not None
        np.testing.assert_allclose(first.pose.position, used.pose.position, atol=1e-9)
        assert (first.pose.yaw, first.quality) == pytest.approx((used.pose.yaw, used.quality))


def test_the_fallback_leaves_the_finger_checks_clearance_so_the_sponge_gets_a_grasp() -> None:
    """``clean/sponge/1`` (sim-val): the sponge is about as wide as the Franka hand's 7.4 cm (the
    opening less the finger check's 3 mm a side; 2 mm when this was written), and no network grasp fits. The sampler's
    own 5 mm a side capped its spans at 7 cm and left the sponge no grasp (the fallback's first
    setting, ``FallbackConfig(min_clearance_m=0.005)``); with the hand's clearance it proposes
    grasps across the sponge, and the finger and IK checks accept one."""
    from craft_e.paths import SIM_VAL_LABELS
    from craft_e.runtime.evaluation.sim_eval import (
        default_encoder,
    )
    from craft_e.runtime.sim.env import SimEnv

    spec = episode_spec(SIM_VAL_LABELS, "clean/sponge/1")
    encoder = default_encoder(1)
    found: dict[str, list[candidates.GraspCandidate]] = {}
    with SimEnv() as env:
        env.reset(spec.scene)
        for name, fallback in (("hand", FallbackConfig()), ("sampler", FallbackConfig(min_clearance_m=0.005))):
            env.robot.reset_home()
            obs = env.capture()
            eager = perceive.perceive(env, encoder, pipeline.PipelineConfig(fallback=fallback), obs)
            sponge = [r for r in eager.rois if r.body is not None and env.scene.body_assets[r.body] == "sponge"]
            assert len(sponge) == 1
            assert not any(c.fits for c in sponge[0].candidates if not c.fallback)  # no network grasp fits
            found[name] = sponge[0].usable
    assert not found["sampler"]
    assert found["hand"] and all(c.fallback and c.fits for c in found["hand"])


def test_bench_pick_settings_reads_the_fallback_setting() -> None:
    """``benchmarks/bench_pick_settings.py --setting C,M[,off|SCALE]``: the fallback comparison's
    command (docs/results/sim_execution.md) must parse what the docs quote, and refuse the rest."""
    bench = load_script(Path(__file__).parents[1] / "benchmarks" / "bench_pick_settings.py")
    assert bench.parse_setting("0.002,-0.002") == {"table_clearance": 0.002, "clearance_margin": -0.002,
                                                   "fallback": 1.0}
    assert bench.parse_setting("0.002,-0.002,off")["fallback"] is None
    assert bench.parse_setting("0.002,-0.002,0.2")["fallback"] == 0.2
    for bad in ("0.002", "0.002,-0.002,0", "0.002,-0.002,maybe", "a,b"):
        with pytest.raises(argparse.ArgumentTypeError, match="TABLE_CLEARANCE"):
            bench.parse_setting(bad)


def test_the_commands_default_is_the_fallbacks_and_zero_turns_the_thin_centres_off() -> None:
    """``--fallback-thin-centres`` (``eval sim``, ``eval pickability``, ``sim demo``) defaults to
    ``FallbackConfig``'s own value, written out in the CLI so that ``--help`` starts without numpy;
    0 gives the fallback of every run before 2026-12-07 (session 43)."""
    import inspect

    from craft_e.runtime.cli import episodes, eval_pickability, eval_sim, sim

    for command in (eval_sim.eval_sim, eval_pickability.eval_pickability, sim.demo):
        assert inspect.signature(command).parameters["fallback_thin_centres"].default == FallbackConfig().thin_centres
    args = ("grconvnet", "predicted", 1, "panda", True, False, True, True, True, True, True)
    assert episodes.pick_pipeline(*args)[1].fallback == FallbackConfig()
    assert episodes.pick_pipeline(*args, fallback_thin_centres=0)[1].fallback.thin_centres == 0
