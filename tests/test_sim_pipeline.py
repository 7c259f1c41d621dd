"""The testbed pipeline end to end (perceive once, ground per method, execute), its grasp check,
and ``craft sim demo``."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from craft_e.paths import KB_DIR
from craft_e.runtime.grasp.geometry import TopDownGrasp
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.perception.roi import roi_from_mask
from craft_e.runtime.sim.choice_errors import ChoiceError
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.episode import execute_pick
from craft_e.runtime.sim.fingers import FingerGeometry, finger_check
from craft_e.runtime.sim.perceive import perceive, raster_order
from craft_e.runtime.sim.pipeline import (
    Failure,
    PipelineConfig,
    SavedStart,
    run_episode,
    sim_vocabulary,
)
from craft_e.runtime.sim.scene import SceneSpec

ROOT = Path(__file__).resolve().parents[1]

# The episode test of test_sim_episode.py: the oracle grasp of the bottle is known to succeed.
EASY = SceneSpec(verb="pour", target="mustard_bottle",
                 distractors=("foam_brick", "knife", "apple", "stapler_2"), seed=2)


@pytest.fixture(scope="module")
def encoder() -> Any:
    from craft_e.runtime.encoders.conse import ConSEImageEncoder

    return ConSEImageEncoder(threads=1)


@pytest.fixture(scope="module")
def grounders() -> dict[str, Any]:
    from craft_e.runtime.grounding.grounder import Grounder
    from craft_e.runtime.kb.bundle import load_bundle

    bundle = load_bundle(KB_DIR / "craft-e-default")
    vocabulary = list(sim_vocabulary())
    return {"CRAFT-E": Grounder(bundle, GroundingSettings(vocabulary=vocabulary)),
            "alignment-only": Grounder(bundle, GroundingSettings(beta=0.0, vocabulary=vocabulary))}


@pytest.fixture(scope="module")
def env() -> Iterator[SimEnv]:
    with SimEnv() as sim:
        yield sim


def test_vocabulary_is_the_plain_names_every_bundle_knows() -> None:
    from craft_e.runtime.kb.bundle import load_bundle

    names = sim_vocabulary()
    assert len(names) == 62 and "mustard bottle" in names and "mustard_bottle" not in names
    bundle = load_bundle(KB_DIR / "craft-e-default")
    assert [n for n in names if n not in bundle.object_index] == []


def test_oracle_episode_runs_end_to_end_with_metrics(
    env: SimEnv, grounders: dict[str, Any], encoder: Any
) -> None:
    config = PipelineConfig(grasp="oracle", rois="oracle")
    result = run_episode(env, EASY, grounders, encoder, config)
    per = result.perception
    assert len(per.rois) == 5 and per.target_roi is not None
    assert per.three_d, per.three_d_detail  # the oracle grasp of the bottle is viable
    target = per.rois[per.target_roi]
    assert target.target_iou == 1.0 and target.usable and target.usable[0].reachable
    assert set(result.outcomes) == {"CRAFT-E", "alignment-only"}
    for outcome in result.outcomes.values():
        assert outcome.chosen_roi is not None
        # nothing of the ground truth reaches the grounder: labels are ROI numbers
        assert all(r.roi.label == f"roi{r.index}" for r in outcome.grounding.ranked)
        if outcome.detect:
            assert outcome.pick is not None and outcome.failure is Failure.SUCCESS
            assert outcome.choice_error is None
        else:
            assert outcome.pick is None and outcome.failure is Failure.WRONG_OBJECT
            assert outcome.chosen_iou < 0.5
            # the perception/knowledge/energies split: re-grounded with the true classes
            fixed = outcome.true_class_roi == per.target_roi
            assert (outcome.choice_error is ChoiceError.PERCEPTION) == fixed
        assert outcome.true_class_roi is not None
    chosen = {o.chosen_roi for o in result.outcomes.values()}
    again = run_episode(env, EASY, grounders, encoder, config)
    assert {o.chosen_roi for o in again.outcomes.values()} == chosen
    assert [o.pick for o in again.outcomes.values()] == [o.pick for o in result.outcomes.values()]


def test_true_class_probabilities_are_one_hot_on_the_covered_body(
    env: SimEnv, grounders: dict[str, Any], encoder: Any
) -> None:
    from craft_e.runtime.sim.choice_errors import (
        true_class_choice,
        true_class_grounding,
        true_class_probabilities,
    )

    env.reset(EASY)
    per = perceive(env, encoder, PipelineConfig(grasp="oracle", rois="oracle"))
    grounder = grounders["CRAFT-E"]
    names = {o.body_id: o.name for o in env.scene.objects}
    emb = np.stack([r.embedding for r in per.rois])
    perceived = grounder.energies("pour", emb).p_obj
    p_true = true_class_probabilities(grounder, perceived, per, names)
    for n, r in enumerate(per.rois):
        assert r.body is not None
        assert p_true[n].sum() == pytest.approx(1.0)
        assert grounder.vocabulary[int(np.argmax(p_true[n]))] == names[r.body]
    # with every object named right, CRAFT-E's knowledge picks the bottle to pour from
    assert true_class_choice(grounder, "pour", per, names) == per.target_roi
    assert per.target_roi in true_class_grounding(grounder, "pour", per, names).kb_best
    # nothing on this table affords "read" (every E_aff 0): the KB ranks no ROI first
    assert true_class_grounding(grounder, "read", per, names).kb_best == ()


def _perception_with_targets(ious: list[float]) -> Any:
    """The two fields ``choice_error`` reads: the target's box and each ROI's IoU with it."""
    from types import SimpleNamespace

    return SimpleNamespace(target_box=(0, 0, 10, 10), rois=[SimpleNamespace(target_iou=v) for v in ious])


def test_a_wrong_choice_is_perception_knowledge_or_energies() -> None:
    from craft_e.runtime.sim.choice_errors import TrueClassGrounding, choice_error

    per = _perception_with_targets([0.0, 0.9, 0.0])  # ROI 1 is the target
    # named right, grounding picks the target: the object was not recognised
    assert choice_error(per, TrueClassGrounding(1, (1,)), 0.5) is ChoiceError.PERCEPTION
    # named right, the KB still ranks ROI 2 strictly first: the knowledge is wrong
    assert choice_error(per, TrueClassGrounding(2, (2,)), 0.5) is ChoiceError.KNOWLEDGE
    # the KB ranks the target first (alone or tied) but grasp/alignment energies pick ROI 0
    assert choice_error(per, TrueClassGrounding(0, (1,)), 0.5) is ChoiceError.ENERGIES
    assert choice_error(per, TrueClassGrounding(0, (0, 1)), 0.5) is ChoiceError.ENERGIES
    # no ROI usable under the re-grounding: nothing ranks the target, so it is not the energies
    assert choice_error(per, TrueClassGrounding(None), 0.5) is ChoiceError.KNOWLEDGE


def test_every_pick_restarts_from_the_saved_state(env: SimEnv, encoder: Any) -> None:
    env.reset(EASY)
    start = SavedStart(env)
    try:
        per = perceive(env, encoder, PipelineConfig(grasp="oracle", rois="oracle"))
        assert per.target_roi is not None
        pose = per.rois[per.target_roi].usable[0].pose
        assert pose is not None
        results = []
        for _ in range(2):
            start.restore()
            results.append(execute_pick(env, pose, per.target_body))
        assert results[0] == results[1] and results[0].outcome.value == "success"
    finally:
        start.release()


def _box(cx: float, cy: float, half_x: float, half_y: float, top: float) -> np.ndarray:
    """Surface points (1 mm grid) of a box standing on the table."""
    xs, ys = np.meshgrid(np.arange(cx - half_x, cx + half_x, 0.001), np.arange(cy - half_y, cy + half_y, 0.001))
    return np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, top)], axis=1)


def test_finger_check_fits_narrow_sections_and_rim_grasps() -> None:
    fingers = FingerGeometry()
    bar = _box(0.0, 0.0, 0.015, 0.10, 0.03)  # 3 cm wide, 20 cm long
    across = TopDownGrasp(np.array([0.0, 0.0, 0.03]), 0.0, 0.03)  # closing along x
    along = TopDownGrasp(np.array([0.0, 0.0, 0.03]), math.pi / 2, 0.03)
    assert finger_check(bar, across, 0.005, fingers) == (True, "")
    ok, why = finger_check(bar, along, 0.005, fingers)
    assert not ok and "does not fit" in why
    assert finger_check(bar, across, 0.05, fingers)[0] is False  # nothing above the finger tips
    # a 12 cm cup: across its middle it does not fit; across one wall (a rim grasp) it does,
    # because the cup's inside lies below the finger tips
    radius = np.hypot(*np.meshgrid(np.arange(-0.06, 0.06, 0.001), np.arange(-0.06, 0.06, 0.001)))
    xs, ys = np.meshgrid(np.arange(-0.06, 0.06, 0.001), np.arange(-0.06, 0.06, 0.001))
    z = np.where(radius > 0.055, 0.08, 0.005)
    cup = np.stack([xs[radius < 0.06], ys[radius < 0.06], z[radius < 0.06]], axis=1)
    middle = TopDownGrasp(np.array([0.0, 0.0, 0.005]), 0.0, 0.1)
    rim = TopDownGrasp(np.array([0.0575, 0.0, 0.08]), 0.0, 0.01)
    assert not finger_check(cup, middle, 0.02, fingers)[0]
    assert finger_check(cup, rim, 0.08 - 0.03 - 0.0136, fingers)[0]


def test_oracle_rois_come_in_raster_order_not_target_first() -> None:
    masks = []
    for row in (30, 5, 18):
        m = np.zeros((40, 40), dtype=bool)
        m[row : row + 4, 10:14] = True
        masks.append(m)
    rois = [roi_from_mask(m, label=i) for i, m in enumerate(masks)]
    assert [r.label for r in raster_order(rois)] == [1, 2, 0]


def test_sim_demo_writes_figure_gif_and_explanation(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app

    result = CliRunner().invoke(app, ["sim", "demo", "--verb", "pour", "--target", "mustard_bottle",
                                      "--grasp", "oracle", "--rois", "oracle", "--gif-every", "60",
                                      "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    png, gif = tmp_path / "pour_0.png", tmp_path / "pour_0.gif"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert gif.read_bytes()[:6] == b"GIF89a"
    import imageio.v3 as iio

    frames = iio.imread(gif, index=None)
    assert frames.shape[-3:-1] == (240, 320)
    assert "E_total" in result.output and "outcome:" in result.output
    assert (tmp_path / "pour_0.json").is_file()
    # the camera's frame, as `craft perceive` reads one (tests/test_frame.py grounds such a frame)
    import numpy as np

    assert np.load(tmp_path / "pour_0_depth.npy").shape == (480, 640)
    camera = json.loads((tmp_path / "pour_0_camera.json").read_text(encoding="utf-8"))
    assert (camera["width"], camera["height"]) == (640, 480) and len(camera["cam_to_world"]) == 4
    assert (tmp_path / "pour_0_rgb.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_colours_are_measured_only_for_a_grounder_that_reads_them(env: SimEnv, encoder: Any) -> None:
    """The colour cue is opt-in: perception measures ROI colours only when asked (the robot's
    default path does no work for it), and ``run_episode`` asks when a grounder has the cue."""
    from craft_e.runtime.grounding.grounder import Grounder
    from craft_e.runtime.kb.bundle import load_bundle
    from craft_e.runtime.kb.colours import COLOUR_TERMS
    from craft_e.runtime.sim.perceive import grounding_rois
    from craft_e.runtime.sim.pipeline import run_episode

    env.reset(EASY)
    config = PipelineConfig(grasp="oracle", rois="oracle")
    assert all(r.colours is None for r in perceive(env, encoder, config).rois)
    measured = perceive(env, encoder, config, colours=True).rois
    for r in measured:
        assert r.colours is not None and len(r.colours) == len(COLOUR_TERMS)
        assert sum(r.colours) == pytest.approx(1.0, abs=1e-5)
    bundle = load_bundle(KB_DIR / "craft-e-default")
    coloured = Grounder(bundle, GroundingSettings(vocabulary=list(sim_vocabulary()), colour_cue=True))
    result = run_episode(env, EASY, {"coloured": coloured}, encoder, config)
    assert all(r.colours is not None for r in grounding_rois(result.perception))


def test_sim_demo_replays_an_evaluation_episode_by_its_id(tmp_path: Path) -> None:
    """``--episode cut/knife/1`` rebuilds the scene ``craft eval sim`` ran under that id (the
    committed dev table's distractors and layout seed) and records the same outcome, so a finding
    about one episode can be re-run with a figure and a GIF."""
    import json

    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app

    published = next(e for e in json.loads((ROOT / "docs/results/sim_grconvnet.json").read_text(encoding="utf-8"))["episodes"]
                     if e["id"] == "cut/knife/1")
    result = CliRunner().invoke(app, ["sim", "demo", "--verb", "cut", "--episode", "cut/knife/1",
                                      "--gif-every", "240", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    record = json.loads((tmp_path / "cut_knife_1.json").read_text())
    assert (record["id"], record["scene_seed"], record["distractors"]) == (
        "cut/knife/1", published["scene_seed"], published["distractors"])
    (mine,) = record["methods"].values()
    assert (mine["failure"], mine["relocation"]) == (published["methods"]["CRAFT-E"]["failure"],
                                                      published["methods"]["CRAFT-E"]["relocation"])
    assert "touching the wood block" in result.output  # where the descent ended: the arm met the block


@pytest.mark.parametrize("episode", ["wipe/sponge/2", "contain/pitcher_base/0"])
def test_sim_demo_episode_with_a_seed_is_that_runs_scene(episode: str) -> None:
    """``--episode ID --seed 1`` names the scene ``craft eval sim --seed 1`` ran under that id:
    the committed new-layouts table's target, distractors and layout seed."""
    import json

    from craft_e.paths import SIM_DEV_LABELS
    from craft_e.runtime.cli.sim import _evaluation_episode
    from craft_e.runtime.evaluation.sim_eval import load_sim_labels
    from craft_e.runtime.sim.env import EnvConfig

    published = next(e for e in json.loads((ROOT / "docs/results/sim_dev_seed1.json").read_text(encoding="utf-8"))[
        "episodes"] if e["id"] == episode)
    labels = load_sim_labels(SIM_DEV_LABELS)
    verb = episode.split("/")[0]
    pairs = [p for p in labels.pairs if p.verb == verb]
    spec = _evaluation_episode(episode, verb, pairs, labels, EnvConfig(), seed=1)
    assert (spec.id, spec.scene.target, list(spec.scene.distractors), spec.scene.seed) == (
        episode, published["target"], published["distractors"], published["scene_seed"])
    at_seed_0 = _evaluation_episode(episode, verb, pairs, labels, EnvConfig())
    assert at_seed_0.scene.seed != spec.scene.seed


@pytest.mark.parametrize(("args", "message"), [
    (["--verb", "cut", "--episode", "cut/knife"], "use verb/object/layout"),
    (["--verb", "pour", "--episode", "cut/knife/1"], "pass --verb 'cut'"),
    (["--verb", "cut", "--episode", "cut/teapot/0"], "'teapot' is not among 'cut'"),
    (["--verb", "cut", "--episode", "cut/knife/1", "--target", "knife"], "drop --target"),
])
def test_sim_demo_names_what_is_wrong_with_an_episode_id(args: list[str], message: str) -> None:
    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app

    result = CliRunner().invoke(app, ["sim", "demo", *args])
    assert result.exit_code != 0
    assert message in " ".join(result.output.split())


@pytest.mark.parametrize("name", ["pour_0_rgb.png", "pour_0.png"])
def test_sim_demo_refuses_a_folder_in_the_way_before_the_episode(tmp_path: Path, name: str) -> None:
    """A folder (not ours) where the demo writes one of its files ended the demo in a traceback
    after the figure and GIF were written; now exit 2 naming it, before the episode, nothing written."""
    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app

    (tmp_path / name).mkdir()
    (tmp_path / name / "mine.txt").write_text("keep", encoding="utf-8")
    result = CliRunner().invoke(app, ["sim", "demo", "--verb", "pour", "--target", "mustard_bottle",
                                      "--out", str(tmp_path)], env={"COLUMNS": "300"})
    assert result.exit_code == 2, result.output
    assert f"{tmp_path / name}: is a folder" in " ".join(result.output.split())
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]
    assert (tmp_path / name / "mine.txt").read_text(encoding="utf-8") == "keep"
