"""The active look (``sim/active_look.py``): where the camera goes, what it crops, how the second
view enters the choice, and that it stays out of runs that do not ask for it."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Sequence
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from craft_e.paths import KB_DIR
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.perception.roi import ROI
from craft_e.runtime.sim.active_look import (
    ActiveLook,
    ActiveLookConfig,
    look_camera,
    look_crop,
    occluded_share,
    projected_box,
    standing_volume,
)
from craft_e.runtime.sim.camera import render
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.pipeline import PipelineConfig, run_episode, sim_vocabulary
from craft_e.runtime.sim.scene import SceneSpec
from craft_e.runtime.sim.surface import RaisedPoints

EASY = SceneSpec(verb="pour", target="mustard_bottle",
                 distractors=("foam_brick", "knife", "apple", "stapler_2"), seed=2)


@pytest.mark.parametrize("bad", [{"top_k": 0}, {"weight": 0.0}, {"weight": 1.5}, {"scale": 0}, {"distance": 0.0},
                                 {"max_occluded": 1.5}])
def test_bad_settings_are_refused_with_the_value(bad: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match="active look"):
        ActiveLookConfig(**bad)


def test_the_camera_sits_at_the_distance_and_elevation_on_the_robot_side() -> None:
    points = np.array([[0.40, 0.10, 0.76], [0.46, 0.14, 0.80]])
    cfg = ActiveLookConfig()
    cam = look_camera(points, cfg)
    centre = np.array([0.43, 0.12, 0.78])
    offset = np.asarray(cam.eye) - centre
    assert np.asarray(cam.target) == pytest.approx(centre)
    assert float(np.linalg.norm(offset)) == pytest.approx(cfg.distance)
    assert math.degrees(math.atan2(offset[2], -offset[0])) == pytest.approx(cfg.elevation_deg)
    assert offset[0] < 0 and offset[1] == pytest.approx(0.0)  # between the object and the robot's base
    assert cam.intrinsics.width == cfg.scale * 640
    assert look_camera(points, ActiveLookConfig(scale=2)).intrinsics.width == 2 * 640  # a sharper image


def test_the_projected_box_holds_the_aimed_at_point_and_nothing_behind_counts() -> None:
    points = np.array([[0.40, 0.10, 0.76], [0.46, 0.14, 0.80]])
    cam = look_camera(points, ActiveLookConfig(scale=1))
    box = projected_box(cam, points)
    assert box is not None
    x, y, w, h = box
    k = cam.intrinsics
    assert x <= k.cx <= x + w and y <= k.cy <= y + h  # the camera looks at the points' centre
    behind = np.asarray(cam.eye) + (np.asarray(cam.eye) - np.asarray(cam.target))
    assert projected_box(cam, behind[None, :]) is None


@dataclasses.dataclass
class _Encoder:
    """Returns a fixed vector per call and counts the crops it was given."""

    vector: np.ndarray
    crops: int = 0
    calls: int = 0

    def embed_images(self, crops: Sequence[Any], batch_size: int = 16) -> np.ndarray:
        self.crops += len(crops)
        self.calls += 1
        return np.tile(self.vector, (len(crops), 1)).astype(np.float32)


@dataclasses.dataclass
class _Grounder:
    """Ranks ROIs by their embedding's first component (higher first); records what it saw."""

    seen: list[list[np.ndarray]] = dataclasses.field(default_factory=list)

    def ground(self, verb: str, rois: Sequence[ROI]) -> Any:
        self.seen.append([np.asarray(r.image_embedding) for r in rois])
        order = sorted(range(len(rois)), key=lambda i: -float(rois[i].image_embedding[0]))
        return SimpleNamespace(ranked=[SimpleNamespace(index=i) for i in order])


def _rois(firsts: Sequence[float]) -> list[ROI]:
    return [ROI(box_xywh=(0.0, 0.0, 1.0, 1.0), grasp_scores=[1.0], image_embedding=np.array([f, 1.0], np.float32),
                label=f"roi{i}") for i, f in enumerate(firsts)]


def test_the_top_k_are_looked_at_once_and_mixed_by_weight(monkeypatch: pytest.MonkeyPatch) -> None:
    import craft_e.runtime.sim.active_look as al

    monkeypatch.setattr(al, "render_look", lambda client, points, table_z, config: "a view")
    monkeypatch.setattr(al, "crop_look", lambda look, points, config: np.zeros((4, 4, 3), np.uint8))
    enc = _Encoder(np.array([0.0, 3.0], np.float32))
    restores: list[int] = []
    points = [np.zeros((10, 3))] * 3
    look = ActiveLook(0, points, 0.0, enc, ActiveLookConfig(top_k=2, weight=0.25),  # type: ignore[arg-type]
                      before_render=lambda: restores.append(1), timings={})
    grounder = _Grounder()
    rois = _rois([0.9, 0.1, 0.5])
    _, looked = look.ground(grounder, "cut", rois)  # type: ignore[arg-type]
    assert looked == (0, 2)
    first, second = grounder.seen
    assert second[1] == pytest.approx(first[1])  # not looked at: its own view only
    for i in looked:
        assert second[i] == pytest.approx(0.75 * first[i] + 0.25 * enc.vector)
    assert (enc.crops, enc.calls, len(restores)) == (2, 1, 1)
    assert look.timings is not None and "look_encode" in look.timings
    look.ground(grounder, "cut", rois)  # the same frame again: nothing new to render or encode
    assert (enc.crops, enc.calls, len(restores)) == (2, 1, 1)


def test_an_roi_with_too_few_points_keeps_its_own_view() -> None:
    enc = _Encoder(np.array([0.0, 3.0], np.float32))
    look = ActiveLook(0, [np.zeros((2, 3))], 0.0, enc, ActiveLookConfig(top_k=1))  # type: ignore[arg-type]
    grounder = _Grounder()
    _, looked = look.ground(grounder, "cut", _rois([0.5]))  # type: ignore[arg-type]
    assert looked == (0,) and look.seen == {0: None} and enc.crops == 0
    assert grounder.seen[1][0] == pytest.approx(grounder.seen[0][0])


@pytest.fixture(scope="module")
def env() -> Iterator[SimEnv]:
    with SimEnv() as sim:
        yield sim


def test_the_crop_frames_each_object_in_the_rendered_look(env: SimEnv) -> None:
    """Aimed by an object's own overhead depth points (dropped to the table too), the look's crop
    box holds the object as the renderer segments it in that view, and little more (the
    segmentation is the test's, never the robot's). Aimed by the top points alone, 12-14 % of two
    standing objects' pixels fell outside."""
    scene = env.reset(EASY)
    obs = env.capture()
    assert obs.seg is not None
    raised = RaisedPoints.of(obs, scene.layout.table_z, 0.003)
    cfg = ActiveLookConfig()
    for body in (o.body_id for o in scene.objects):
        top = raised.within(obs.seg == body)
        points = standing_volume(top, scene.layout.table_z)
        cam = look_camera(points, cfg)
        box = projected_box(cam, points)
        assert box is not None
        view = render(env.client, cam)
        assert view.seg is not None
        ys, xs = np.nonzero(view.seg == body)
        x, y, w, h = box
        inside = (xs >= x - 2) & (xs <= x + w + 2) & (ys >= y - 2) & (ys <= y + h + 2)
        assert inside.mean() > 0.99, body  # its top and the side facing the camera
        assert w * h < 1.3 * (np.ptp(xs) + 1) * (np.ptp(ys) + 1), body  # and not much else
        assert occluded_share(view, top, cfg) < 0.05, body  # nothing stands in front of these
        crop = look_crop(env.client, top, scene.layout.table_z, cfg)
        assert crop is not None and crop.ndim == 3 and min(crop.shape[:2]) > 50


def _top_points(env: SimEnv, spec: SceneSpec) -> tuple[np.ndarray, float]:
    scene = env.reset(spec)
    obs = env.capture()
    assert obs.seg is not None
    raised = RaisedPoints.of(obs, scene.layout.table_z, 0.003)
    return raised.within(obs.seg == scene.target.body_id), scene.layout.table_z


def test_a_box_between_the_look_and_the_object_drops_the_look(env: SimEnv) -> None:
    """The look would see the box, not the object: the ROI keeps its overhead view alone."""
    import pybullet as p

    top, table_z = _top_points(env, EASY)
    cfg = ActiveLookConfig()
    cam = look_camera(standing_volume(top, table_z), cfg)
    assert look_crop(env.client, top, table_z, cfg) is not None
    between = (np.asarray(cam.eye) + np.asarray(cam.target)) / 2
    shape = p.createVisualShape(p.GEOM_BOX, halfExtents=[0.06, 0.06, 0.06], physicsClientId=env.client)
    wall = p.createMultiBody(baseMass=0, baseVisualShapeIndex=shape, basePosition=list(between),
                             physicsClientId=env.client)
    try:
        view = render(env.client, cam)
        assert occluded_share(view, top, cfg) > 0.9
        assert look_crop(env.client, top, table_z, cfg) is None
    finally:
        p.removeBody(wall, physicsClientId=env.client)


def test_a_vessel_hiding_its_own_inside_is_not_occluded(env: SimEnv) -> None:
    """From 45° a mug's front wall hides part of its inside: those surfaces are the mug's own
    (inside its footprint), so the look is kept."""
    spec = SceneSpec(verb="contain", target="mug", distractors=("knife", "apple"), seed=3)
    top, table_z = _top_points(env, spec)
    cfg = ActiveLookConfig()
    view = render(env.client, look_camera(standing_volume(top, table_z), cfg))
    hidden_by_anything = occluded_share(view, top, dataclasses.replace(cfg, self_margin=-1.0))
    assert hidden_by_anything > 0.1  # the inside is partly hidden ...
    assert occluded_share(view, top, cfg) < 0.02  # ... by the mug itself
    assert look_crop(env.client, top, table_z, cfg) is not None


def test_the_standing_volume_adds_the_points_dropped_onto_the_table() -> None:
    top = np.array([[0.4, 0.1, 0.80], [0.5, 0.2, 0.82]])
    volume = standing_volume(top, 0.75)
    assert volume.shape == (4, 3)
    assert volume[2:, :2] == pytest.approx(top[:, :2]) and set(volume[2:, 2]) == {0.75}
    assert standing_volume(np.zeros((0, 3)), 0.75).shape == (0, 3)


def test_an_episode_with_the_look_records_what_it_looked_at_and_the_default_does_not(
    env: SimEnv,
) -> None:
    from craft_e.runtime.encoders.conse import ConSEImageEncoder
    from craft_e.runtime.evaluation.sim_eval import EpisodeSpec, episode_record
    from craft_e.runtime.grounding.grounder import Grounder
    from craft_e.runtime.kb.bundle import load_bundle
    from craft_e.runtime.sim.perceive import grounding_rois

    encoder = ConSEImageEncoder(threads=1)
    grounder = Grounder(load_bundle(KB_DIR / "craft-e-default"),
                        GroundingSettings(vocabulary=list(sim_vocabulary())))
    base = PipelineConfig(grasp="oracle", rois="oracle")
    looking = dataclasses.replace(base, active_look=ActiveLookConfig(enabled=True))
    assert "active_look" not in base.to_dict()
    assert looking.to_dict()["active_look"]["top_k"] == 2
    spec = EpisodeSpec("pour", "mustard_bottle", 0, EASY, 1)
    plain = run_episode(env, EASY, {"CRAFT-E": grounder}, encoder, base)
    assert plain.outcomes["CRAFT-E"].looked is None
    assert "looked_rois" not in episode_record(spec, plain)["methods"]["CRAFT-E"]
    result = run_episode(env, EASY, {"CRAFT-E": grounder}, encoder, looking)
    outcome = result.outcomes["CRAFT-E"]
    first = grounder.ground(EASY.verb, grounding_rois(result.perception))
    assert outcome.looked == tuple(r.index for r in first.ranked[:2])
    assert episode_record(spec, result)["methods"]["CRAFT-E"]["looked_rois"] == list(outcome.looked)
    assert outcome.success  # the look leaves the scene as it was: the pick still lands
    from craft_e.runtime.sim.figures import describe

    said = describe(result, "CRAFT-E")
    assert f"active look: roi{outcome.looked[0]}, roi{outcome.looked[1]} seen again" in said
    assert "active look" not in describe(plain, "CRAFT-E")
