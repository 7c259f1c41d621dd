"""A real camera's frame through the robot's own perception (``runtime/frame.py``, ``craft perceive``).

Why: the testbed's robot perceives with ``sim.choose.perceive_frame``, which reads the frame
alone; a robot with a RealSense must get the same regions, cues and choice from its own frame,
with no simulator behind it. Checked on testbed frames saved as files (``save_frame``), with the
camera's pose given and with heights measured from the table plane instead.
"""

from __future__ import annotations

import dataclasses
import json
import os
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import episode_spec
from typer.testing import CliRunner

from craft_e.paths import KB_DIR, SIM_DEV_LABELS, VOCAB_DIR
from craft_e.runtime.cli.main import app
from craft_e.runtime.frame import FrameError, frame_observation, pose_from_plane, save_frame
from craft_e.runtime.grasp.geometry import CameraIntrinsics
from craft_e.runtime.perception.observation import Observation
from craft_e.runtime.perception.plane import Plane

runner = CliRunner()
SIM_VOCAB = VOCAB_DIR / "sim_objects.txt"


def flat(text: str) -> str:
    return " ".join(text.replace("│", " ").split())


def test_the_pose_from_a_plane_puts_the_plane_at_zero_height_below_the_camera() -> None:
    normal = np.array([0.1, -0.8, -0.5])
    normal /= np.linalg.norm(normal)
    plane = Plane(normal, 0.7).facing(np.zeros(3))
    pose = pose_from_plane(plane)
    rotation = pose[:3, :3]
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    # points of the plane: any point less its distance along the normal
    points = rng.normal(size=(50, 3))
    points -= np.outer(plane.distance(points), plane.normal)
    world = points @ pose[:3, :3].T + pose[:3, 3]
    np.testing.assert_allclose(world[:, 2], 0.0, atol=1e-12)
    camera = pose[:3, 3]  # the camera's centre in the world
    assert camera[2] == pytest.approx(0.7)  # its distance from the plane, above it
    np.testing.assert_allclose(camera[:2], 0.0, atol=1e-12)  # the origin lies under the camera


@pytest.fixture(scope="module")
def testbed_frames() -> Iterator[list[tuple[str, Observation, list[Any]]]]:
    """Three sim-dev scenes: (verb, the camera's frame, the robot path's choice at 1x with every
    grasp reachable: ``perceive_for_pick`` + ``ground_lazily``, what ``ground_frame`` must equal)."""
    from craft_e.runtime.evaluation.sim_eval import (
        default_encoder,
        load_sim_labels,
        make_episode_specs,
    )
    from craft_e.runtime.grounding.grounder import Grounder
    from craft_e.runtime.grounding.settings import GroundingSettings
    from craft_e.runtime.kb.bundle import load_bundle
    from craft_e.runtime.sim.choose import ground_lazily, perceive_for_pick
    from craft_e.runtime.sim.env import SimEnv
    from craft_e.runtime.sim.pipeline import PipelineConfig, sim_vocabulary

    encoder = default_encoder(1)
    grounder = Grounder(load_bundle(KB_DIR / "craft-e-default"), GroundingSettings(vocabulary=sim_vocabulary()))
    config = PipelineConfig(rgb_scale=1, ik_filter=False)
    specs = make_episode_specs(load_sim_labels(SIM_DEV_LABELS), layouts=1, max_pairs=3)
    frames = []
    for spec in specs:
        with SimEnv() as env:
            env.reset(spec.scene)
            env.robot.reset_home()
            obs = env.capture()
            lazy = perceive_for_pick(env, encoder, config, obs, cavity=grounder.cavity_cue_active)
            choice = ground_lazily(grounder, spec.verb, lazy, lambda _grasp: True)
            frames.append((spec.verb, dataclasses.replace(obs, seg=None), [choice, lazy]))
    yield frames


def test_a_testbed_frame_is_perceived_and_grounded_as_the_robot_does(
    testbed_frames: list[tuple[str, Observation, list[Any]]],
) -> None:
    """``ground_frame`` equals the testbed robot's path (no IK either way) in every scene: the same
    regions, extents and cavities, the same choice and grasp, whether the camera's pose is given
    or the frame is made from the table plane (heights agree to the plane fit's error)."""
    from craft_e.runtime.evaluation.sim_eval import default_encoder
    from craft_e.runtime.frame import ground_frame
    from craft_e.runtime.grounding.grounder import Grounder
    from craft_e.runtime.grounding.settings import GroundingSettings
    from craft_e.runtime.kb.bundle import load_bundle
    from craft_e.runtime.sim.pipeline import PipelineConfig, sim_vocabulary

    encoder = default_encoder(1)
    grounder = Grounder(load_bundle(KB_DIR / "craft-e-default"), GroundingSettings(vocabulary=sim_vocabulary()))
    for verb, obs, (reference, lazy) in testbed_frames:
        for pose in (obs.cam_to_world, None):
            found = ground_frame(grounder, encoder, PipelineConfig(), verb, obs.rgb, obs.depth, obs.intrinsics, pose)
            assert found.pose_from_table == (pose is None)
            assert [r.box_xywh for r in found.rois] == [r.box_xywh for r in lazy]
            for mine, theirs in zip(found.rois, lazy, strict=True):
                assert (mine.extents_m is None) == (theirs.extents_m is None)
                if mine.extents_m is not None and theirs.extents_m is not None:
                    np.testing.assert_allclose(mine.extents_m, theirs.extents_m, atol=2e-3)
                assert mine.cavity_m == pytest.approx(theirs.cavity_m, abs=2e-3)
            assert found.grounding.chosen is not None and reference.grounding.chosen is not None
            assert found.grounding.chosen.index == reference.grounding.chosen.index
            assert found.grasp is not None and found.grasp.rect == reference.grasp.rect


def test_a_frame_fits_its_table_plane_once(
    testbed_frames: list[tuple[str, Observation, list[Any]]], monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The frame's check (``observe_frame``) fits the table plane and segmentation reads that
    plane rather than fitting it again: one RANSAC fit per frame, the regions those of a fresh fit."""
    from craft_e.runtime.evaluation.sim_eval import default_encoder
    from craft_e.runtime.frame import perceive
    from craft_e.runtime.perception import segment as segment_module
    from craft_e.runtime.sim.pipeline import PipelineConfig

    _, obs, (_, lazy) = testbed_frames[0]
    fits: list[int] = []
    real_fit = segment_module.fit_plane

    def counted(*args: Any, **kwargs: Any) -> Any:
        fits.append(1)
        return real_fit(*args, **kwargs)

    monkeypatch.setattr(segment_module, "fit_plane", counted)
    frame = perceive(default_encoder(1), PipelineConfig(), obs.rgb, obs.depth, obs.intrinsics, obs.cam_to_world)
    assert len(fits) == 1
    assert [r.box_xywh for r in frame.rois] == [r.box_xywh for r in lazy]


def test_craft_perceive_reads_a_saved_frame_and_writes_the_choice(
    testbed_frames: list[tuple[str, Observation, list[Any]]], tmp_path: Path,
) -> None:
    verb, obs, (reference, _) = testbed_frames[0]
    old = os.umask(0o022)
    try:
        rgb, depth, camera = save_frame(tmp_path, "scene", obs)
    finally:
        os.umask(old)
    assert {stat.S_IMODE(p.stat().st_mode) for p in (rgb, depth, camera)} == {0o644}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene_camera.json", "scene_depth.npy", "scene_rgb.png"]
    out = tmp_path / "out" / "choice.json"
    result = runner.invoke(app, ["perceive", "--kb", str(KB_DIR / "craft-e-default"), "--verb", verb,
                                 "--rgb", str(rgb), "--depth", str(depth), "--camera", str(camera),
                                 "--vocab", str(SIM_VOCAB), "--json", str(out)], env={"COLUMNS": "300"})
    assert result.exit_code == 0, result.output
    text = flat(result.output)
    assert "size cue, cavity cue" in text and "grasp: centre" in text and "no IK" in text
    data = json.loads(out.read_text(encoding="utf-8"))
    assert data["chosen"] == reference.grounding.chosen.index
    assert data["size_cue_used"] and data["pose_from_table"] is False
    assert data["grasp"]["center_px"] == [round(v, 1) for v in reference.grasp.rect.center_xy]
    assert 0 < data["grasp"]["opening_m"] <= 0.08
    np.testing.assert_allclose(data["cam_to_world"], obs.cam_to_world, atol=1e-6)


def _bad(args: list[str]) -> str:
    result = runner.invoke(app, ["perceive", *args], env={"COLUMNS": "300"})
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    return flat(result.output)


@pytest.fixture()
def small_frame(tmp_path: Path) -> tuple[Path, Path]:
    from PIL import Image

    rgb = tmp_path / "rgb.png"
    Image.fromarray(np.zeros((48, 64, 3), np.uint8)).save(rgb)
    depth = tmp_path / "depth.npy"
    np.save(depth, np.full((48, 64), 0.7, np.float32))
    return rgb, depth


def test_craft_perceive_names_each_bad_input_before_loading_anything(
    small_frame: tuple[Path, Path], tmp_path: Path,
) -> None:
    rgb, depth = small_frame
    kb = tmp_path / "no-kb"  # never read: every refusal below comes first
    out = tmp_path / "o.json"
    base = ["--kb", str(kb), "--verb", "cut", "--rgb", str(rgb), "--json", str(out)]
    millimetres = tmp_path / "mm.npy"
    np.save(millimetres, np.full((48, 64), 700, np.uint16))
    assert "depth is in integer units (uint16)" in _bad([*base, "--depth", str(millimetres)])
    assert "--depth-scale 0.001 for millimetres" in _bad([*base, "--depth", str(millimetres)])
    assert "--depth-scale -1: metres per depth unit must be a positive number" in _bad(
        [*base, "--depth", str(millimetres), "--depth-scale", "-1"])
    small = tmp_path / "small.npy"
    np.save(small, np.full((24, 32), 0.7, np.float32))
    assert "depth is 32x24 pixels" in _bad([*base, "--depth", str(small)])
    assert "depth image not found" in _bad([*base, "--depth", str(tmp_path / "none.npy")])
    text = tmp_path / "depth.txt"
    text.write_text("0.7\n", encoding="utf-8")
    assert "depth must be a .npy array of metres or a 16-bit PNG" in _bad([*base, "--depth", str(text)])
    camera = tmp_path / "camera.json"
    assert "camera.json: camera file (JSON: fx, fy, cx, cy, optional cam_to_world) not found" in _bad(
        [*base, "--depth", str(depth), "--camera", str(camera)])
    camera.write_text('{"fx": 600,', encoding="utf-8")
    assert "camera.json: not JSON (Expecting" in _bad([*base, "--depth", str(depth), "--camera", str(camera)])
    camera.write_text(json.dumps({"fx": 600, "fy": 600, "cx": 32}), encoding="utf-8")
    assert "the camera file lacks cy" in _bad([*base, "--depth", str(depth), "--camera", str(camera)])
    camera.write_text(json.dumps({"fx": 600, "fy": 0, "cx": 32, "cy": 24}), encoding="utf-8")
    assert "fx and fy must be positive" in _bad([*base, "--depth", str(depth), "--camera", str(camera)])
    camera.write_text(json.dumps({"fx": 600, "fy": 600, "cx": 32, "cy": 24, "cam_to_world": [[1, 0, 0]]}),
                      encoding="utf-8")
    assert "cam_to_world must be a 4 x 4 list" in _bad([*base, "--depth", str(depth), "--camera", str(camera)])
    camera.write_text(json.dumps({"fx": 600, "fy": 600, "cx": 32, "cy": 24, "width": 640}), encoding="utf-8")
    assert "width 640 is not the image's 64" in _bad([*base, "--depth", str(depth), "--camera", str(camera)])
    assert "--grasp 'antipodal': choose one of grconvnet, ggcnn, ggcnn2" in _bad(
        [*base, "--depth", str(depth), "--grasp", "antipodal"])
    assert not out.exists()


def test_a_frame_without_depth_or_with_mismatched_shapes_is_refused() -> None:
    k = CameraIntrinsics.realsense_d435(64, 48)
    rgb = np.zeros((48, 64, 3), np.uint8)
    with pytest.raises(FrameError, match="no valid reading"):
        frame_observation(rgb, np.zeros((48, 64), np.float32), k)
    with pytest.raises(FrameError, match="no valid reading"):
        frame_observation(rgb, np.full((48, 64), np.nan, np.float32), k)
    with pytest.raises(FrameError, match="one registered frame"):
        frame_observation(rgb, np.ones((24, 32), np.float32), k)
    with pytest.raises(FrameError, match="camera model is 640x480"):
        frame_observation(rgb, np.ones((48, 64), np.float32), CameraIntrinsics.realsense_d435())
    with pytest.raises(FrameError, match="finite 4 x 4"):
        frame_observation(rgb, np.ones((48, 64), np.float32), k, np.eye(3))


def test_a_flat_frame_is_a_table_with_nothing_on_it(tmp_path: Path) -> None:
    """A real camera looking at an empty table: the plane is found and no region is chosen; the
    command says so and exits 0 (nothing to pick is an answer, not an error)."""
    from craft_e.runtime.evaluation.sim_eval import default_encoder
    from craft_e.runtime.frame import ground_frame
    from craft_e.runtime.grounding.grounder import Grounder
    from craft_e.runtime.grounding.settings import GroundingSettings
    from craft_e.runtime.kb.bundle import load_bundle
    from craft_e.runtime.sim.pipeline import PipelineConfig

    k = CameraIntrinsics.realsense_d435(64, 48)
    rgb = np.full((48, 64, 3), 120, np.uint8)
    depth = np.full((48, 64), 0.7, np.float32)
    grounder = Grounder(load_bundle(KB_DIR / "craft-e-default"), GroundingSettings())
    found = ground_frame(grounder, default_encoder(1), PipelineConfig(), "cut", rgb, depth, k)
    assert found.rois == [] and found.grounding.chosen is None and found.grasp is None
    assert found.pose_from_table and found.cam_to_world[2, 3] == pytest.approx(0.7)


def test_the_figure_names_the_object_its_paths_explain(
    testbed_frames: list[tuple[str, Observation, list[Any]]],
) -> None:
    """The reasoning panel drew the top hypothesis's name at the end of paths that belong to a
    lower one (the demo's knife: "marker" at the end of "has a sharp cutting edge -(1.00)->"), while
    the terminal said "why 'knife' (hypothesis 3; no path for 'marker')". It names the paths' object."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from craft_e.runtime.grounding.grounder import ObjectHypothesis
    from craft_e.runtime.grounding.plotting import _draw_path

    _, _, (reference, _) = testbed_frames[0]
    grounding = reference.grounding
    chosen = grounding.chosen
    assert chosen is not None and chosen.paths
    explained = chosen.paths[0].obj
    probability = next(h.probability for h in chosen.hypotheses if h.name == explained)
    # the same grounding with an unexplained name on top (a name the KB has no path for)
    unexplained = dataclasses.replace(chosen, hypotheses=[ObjectHypothesis("zzz gadget", 0.5), *chosen.hypotheses])
    for ranked, top in ((chosen, chosen.hypotheses[0].name), (unexplained, "zzz gadget")):
        figure, ax = plt.subplots()
        try:
            _draw_path(ax, dataclasses.replace(grounding, ranked=[ranked, *grounding.ranked[1:]]), 5)
            labels = [t.get_text() for t in ax.texts]
            title = ax.get_title()
        finally:
            plt.close(figure)
        assert explained in labels and "zzz gadget" not in labels
        assert f"({explained}, p={probability:.2f}" in title
        assert ("which has no path" in title) == (top != explained)


def test_a_frame_perceiver_is_built_once_and_grounds_each_frame(
    testbed_frames: list[tuple[str, Observation, list[Any]]],
) -> None:
    """The robot's-process API (``FramePerceiver``): the same choice as the robot path, and bad
    choices named before any model loads."""
    from craft_e.runtime.frame import FramePerceiver
    from craft_e.runtime.kb.bundle import load_bundle
    from craft_e.runtime.sim.pipeline import sim_vocabulary

    bundle = load_bundle(KB_DIR / "craft-e-default")
    with pytest.raises(ValueError, match="grasp network 'antipodal'"):
        FramePerceiver(bundle, grasp="antipodal")
    with pytest.raises(ValueError, match="robotiq"):
        FramePerceiver(bundle, gripper="claw")
    perceiver = FramePerceiver(bundle, vocabulary=sim_vocabulary())
    assert perceiver.grounder.size_cue_active and perceiver.grounder.cavity_cue_active
    for verb, obs, (reference, _) in testbed_frames:
        found = perceiver.ground(verb, obs.rgb, obs.depth, obs.intrinsics)
        assert found.grounding.chosen is not None
        assert found.grounding.chosen.index == reference.grounding.chosen.index
    wide = FramePerceiver(bundle, vocabulary=sim_vocabulary(), gripper="robotiq_2f85")
    assert wide.config.fingers.half_opening > perceiver.config.fingers.half_opening


def test_the_hand_check_sees_a_neighbour_beside_the_grasp() -> None:
    """``hand_problems``: the Franka hand's body is 21 cm along its closing axis; a 10 cm block
    8 cm from the grasp along that axis is under it, the same block across the axis is not, and
    a leaned hand needs the arm's model."""
    from craft_e.runtime.frame import hand_problems
    from craft_e.runtime.grasp.geometry import TopDownGrasp
    from craft_e.runtime.sim.clearance import HeightMap
    from craft_e.runtime.sim.episode import PickConfig
    from craft_e.runtime.sim.hands import hand_spec

    xs, ys = np.meshgrid(np.linspace(-0.02, 0.02, 9), np.linspace(-0.02, 0.02, 9))
    block = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.10)], axis=1)
    check = hand_problems(0.0, PickConfig(), hand_spec("panda").clearance_boxes)
    grasp = TopDownGrasp(np.array([0.0, 0.0, 0.02]), 0.0, 0.04)  # closing along world x
    along = HeightMap(block + np.array([0.08, 0.0, 0.0]), 0.005, 0.0)
    across = HeightMap(block + np.array([0.0, 0.08, 0.0]), 0.005, 0.0)
    unreachable, blocked = check(grasp, along)
    assert unreachable is None and blocked is not None and "the hand would touch" in blocked
    assert check(grasp, across) == (None, None)
    assert check(grasp._replace(lean=0.3), across)[0] == "a leaned hand needs the arm's model"


def test_a_frame_moves_a_blocked_grasp_as_the_testbed_robot_does() -> None:
    """sim-dev ``eat/peach/1``: at the chosen grasp a finger would come down on a neighbour. The
    frame's hand check finds the same contact as the testbed robot's whole-pick check and moves
    the grasp to the same spot (the testbed's also plans the arm, which this frame cannot)."""
    from craft_e.runtime.evaluation.sim_eval import (
        default_encoder,
    )
    from craft_e.runtime.frame import FramePerceiver
    from craft_e.runtime.kb.bundle import load_bundle
    from craft_e.runtime.sim.candidates import GraspCandidate
    from craft_e.runtime.sim.choose import (
        ground_lazily,
        perceive_for_pick,
        pick_reachable,
        relocate_choice,
    )
    from craft_e.runtime.sim.env import SimEnv
    from craft_e.runtime.sim.pipeline import PipelineConfig, sim_vocabulary

    spec = episode_spec(SIM_DEV_LABELS, "eat/peach/1")
    perceiver = FramePerceiver(load_bundle(KB_DIR / "craft-e-default"), vocabulary=sim_vocabulary())
    config = PipelineConfig(rgb_scale=1)
    with SimEnv() as env:
        env.reset(spec.scene)
        env.robot.reset_home()
        obs = env.capture()
        lazy = perceive_for_pick(env, default_encoder(1), config, obs, cavity=True)
        made: dict[Any, Any] = {}
        choice = ground_lazily(perceiver.grounder, "eat", lazy, pick_reachable(env, config, lazy, made))
        assert choice.grounding.chosen is not None
        moved, why = relocate_choice(env, config, obs, lazy[choice.grounding.chosen.index], choice.grasp, made)
    found = perceiver.ground("eat", obs.rgb, obs.depth, obs.intrinsics, obs.cam_to_world)
    assert found.grounding.chosen is not None and found.grounding.chosen.index == choice.grounding.chosen.index
    assert why.startswith("approach blocked: a finger would touch") and found.relocation == why
    assert isinstance(moved, GraspCandidate) and found.grasp is not None and found.grasp.pose is not None
    np.testing.assert_allclose(found.grasp.pose.position, moved.pose.position, atol=1e-9)
    assert found.grasp.pose.yaw == pytest.approx(moved.pose.yaw)


def test_the_figure_draws_a_checked_grasp_through_its_rectangle() -> None:
    """``craft perceive --plot`` drew no grasp: the chosen grasp is a checked candidate, whose
    image rectangle is its ``rect``."""
    from craft_e.runtime.grasp.geometry import Grasp2D
    from craft_e.runtime.grounding.plotting import _grasp_segment
    from craft_e.runtime.sim.candidates import GraspCandidate

    rect = Grasp2D((100.0, 50.0), 0.0, 40.0, 20.0, 0.9)
    assert _grasp_segment(rect) == ((80.0, 50.0), (120.0, 50.0))
    assert _grasp_segment(GraspCandidate(rect, None)) == _grasp_segment(rect)
    assert _grasp_segment(None) is None


def test_an_unknown_verb_is_named_before_the_frame_is_perceived(monkeypatch: pytest.MonkeyPatch) -> None:
    """``craft perceive --verb xyzzy`` ran both network passes (about 4 s) before the grounder
    refused the verb; ``ground_frame`` asks the grounder first."""
    import craft_e.runtime.frame as frame_module
    from craft_e.runtime.grounding.grounder import Grounder, UnknownVerbError
    from craft_e.runtime.grounding.settings import GroundingSettings
    from craft_e.runtime.kb.bundle import load_bundle
    from craft_e.runtime.sim.pipeline import PipelineConfig

    def no_perception(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("the frame was perceived for a verb the KB lacks")

    monkeypatch.setattr(frame_module, "perceive", no_perception)
    grounder = Grounder(load_bundle(KB_DIR / "craft-e-default"), GroundingSettings())
    k = CameraIntrinsics.realsense_d435(64, 48)
    with pytest.raises(UnknownVerbError) as caught:
        frame_module.ground_frame(grounder, None, PipelineConfig(), "cutt",  # type: ignore[arg-type]
                                  np.zeros((48, 64, 3), np.uint8), np.full((48, 64), 0.7, np.float32), k)
    assert "cut" in caught.value.close_matches


def test_craft_perceive_maps_a_free_request_with_open_vocab(
    testbed_frames: list[tuple[str, Observation, list[Any]]], tmp_path: Path,
) -> None:
    """The unknown-verb message names ``--open-vocab``; ``craft perceive`` has it, as ``craft
    ground`` does: a free request is mapped to properties and grounded on the frame."""
    verb, obs, (reference, _) = testbed_frames[0]
    assert verb == "cut"
    rgb, depth, camera = save_frame(tmp_path, "scene", obs)
    args = ["perceive", "--kb", str(KB_DIR / "craft-e-default"), "--rgb", str(rgb), "--depth", str(depth),
            "--camera", str(camera), "--vocab", str(SIM_VOCAB), "--json", str(tmp_path / "o.json")]
    refused = runner.invoke(app, [*args, "--verb", "something to slice bread"], env={"COLUMNS": "300"})
    assert refused.exit_code == 2 and "--open-vocab" in flat(refused.output)
    result = runner.invoke(app, [*args, "--verb", "something to slice bread", "--open-vocab"], env={"COLUMNS": "300"})
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "o.json").read_text(encoding="utf-8"))
    assert data["request"] is not None and data["chosen"] == reference.grounding.chosen.index
