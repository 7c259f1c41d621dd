"""``POST /perceive``: a robot posts one RGB-D frame and gets the object, the grasp and why.

Why: robot stacks that are not Python reach CRAFT-E over HTTP. The endpoint must give the same
answer as ``craft perceive`` (``FramePerceiver``) on the same frame, and refuse what is not a
frame with a 4xx naming the field, before any network runs.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from frame_bytes import b64, npy_bytes, png_bytes

from craft_e.paths import KB_DIR, SIM_DEV_LABELS
from craft_e.runtime.perception.observation import Observation


@pytest.fixture(scope="module")
def frame() -> Observation:
    """The first sim-dev scene's camera frame (cut, the knife among four others)."""
    from craft_e.runtime.evaluation.sim_eval import load_sim_labels, make_episode_specs
    from craft_e.runtime.sim.env import SimEnv

    spec = make_episode_specs(load_sim_labels(SIM_DEV_LABELS), layouts=1, max_pairs=1)[0]
    with SimEnv() as env:
        env.reset(spec.scene)
        env.robot.reset_home()
        return env.capture()


@pytest.fixture(scope="module")
def client() -> Iterator[TestClient]:
    from craft_e.runtime.evaluation.sim_eval import default_encoder
    from craft_e.runtime.serve.app import create_app

    with TestClient(create_app(KB_DIR / "craft-e-default", frame_encoder=default_encoder(1))) as c:
        yield c


def _body(obs: Observation, **changes: Any) -> dict[str, Any]:
    from craft_e.runtime.sim.pipeline import sim_vocabulary

    k = obs.intrinsics
    body: dict[str, Any] = {
        "verb": "cut", "rgb_b64": b64(png_bytes(obs.rgb)), "depth_b64": b64(npy_bytes(obs.depth.astype(np.float32))),
        "camera": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy}, "objects": list(sim_vocabulary()),
    }
    body.update(changes)
    return body


def test_perceive_answers_as_craft_perceive_does(client: TestClient, frame: Observation) -> None:
    from craft_e.runtime.frame import FramePerceiver
    from craft_e.runtime.kb.bundle import load_bundle
    from craft_e.runtime.sim.pipeline import sim_vocabulary

    expected = FramePerceiver(load_bundle(KB_DIR / "craft-e-default"), vocabulary=sim_vocabulary()).ground(
        "cut", frame.rgb, frame.depth, frame.intrinsics)
    assert expected.grounding.chosen is not None
    r = client.post("/perceive", json=_body(frame))
    assert r.status_code == 200, r.text
    data = r.json()
    assert data["chosen"] == expected.grounding.chosen.index
    assert data["grasp"] == expected.grasp_dict() and data["relocation"] == expected.relocation
    assert data["size_cue_used"] and data["pose_from_table"] and data["regions"] == len(expected.rois)
    assert data["image"]["width"] == 640 and data["chosen_grasp"]["roi"] == data["chosen"]
    # the same frame as a RealSense saves it: 16-bit millimetres, with the scale
    millimetres = np.round(frame.depth * 1000).astype(np.uint16)
    r = client.post("/perceive", json=_body(frame, depth_b64=b64(png_bytes(millimetres)), depth_scale=0.001))
    assert r.status_code == 200, r.text
    assert r.json()["chosen"] == expected.grounding.chosen.index


@pytest.mark.parametrize(("changes", "status", "needle"), [
    ({"depth_b64": "not base64!"}, 422, "not valid base64"),
    ({"depth_b64": b64(b"plain text")}, 422, "depth must be a .npy array of metres or a 16-bit PNG"),
    ({"depth_b64": b64(npy_bytes(np.full((480, 640), 700, np.uint16)))}, 422, "integer units"),
    ({"depth_b64": b64(npy_bytes(np.full((48, 64), 0.7, np.float32)))}, 422, "send both from one registered frame"),
    ({"depth_b64": b64(npy_bytes(np.zeros((480, 640), np.float32)))}, 422, "no valid reading"),
    ({"rgb_b64": "%%%"}, 422, "not valid base64"),
    ({"camera": {"fx": 600.0, "cx": 320.0, "cy": 240.0}}, 422, "fy"),
    ({"camera": {"fx": 600.0, "fy": 600.0, "cx": 320.0, "cy": 240.0, "cam_to_world": [[1.0, 0.0, 0.0]]}}, 422,
     "cam_to_world must be a 4 x 4 matrix"),
    ({"depth_scale": 0}, 422, "greater than 0"),
    ({"verb": "xyzzy"}, 404, "xyzzy"),
])
def test_perceive_refuses_what_is_not_a_frame(client: TestClient, frame: Observation, changes: dict[str, Any],
                                              status: int, needle: str) -> None:
    r = client.post("/perceive", json=_body(frame, **changes))
    assert r.status_code == status, r.text
    assert needle in r.text


def test_a_server_without_the_robot_encoder_says_so() -> None:
    from craft_e.runtime.serve.app import create_app

    with TestClient(create_app(KB_DIR / "craft-e-default")) as c:
        r = c.post("/perceive", json={"verb": "cut", "rgb_b64": "AA==", "depth_b64": "AA==",
                                      "camera": {"fx": 1.0, "fy": 1.0, "cx": 0.0, "cy": 0.0}})
    assert r.status_code == 503 and "perception_disabled" in r.text


def test_craft_serve_names_an_unknown_hand_before_loading_anything(tmp_path: Any) -> None:
    from typer.testing import CliRunner

    from craft_e.runtime.cli.main import app

    result = CliRunner().invoke(app, ["serve", "--kb", str(tmp_path / "no-kb"), "--gripper", "claw"])
    assert result.exit_code == 2
    assert "--gripper 'claw': use robotiq_2f85 or panda" in " ".join(result.output.split())


def test_an_unknown_verb_is_404_before_the_frame_is_decoded(client: TestClient, frame: Observation,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    service = client.app.state.service  # type: ignore[attr-defined]

    def no_perception(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("the frame was decoded and perceived for a verb the KB lacks")

    monkeypatch.setattr(service, "perceive_frame", no_perception)
    r = client.post("/perceive", json=_body(frame, verb="cutt"))
    assert r.status_code == 404, r.text
    assert "cut" in r.json()["detail"]["close_matches"]


def _jpeg(array: np.ndarray) -> bytes:
    import io

    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(array).save(out, format="JPEG")
    return out.getvalue()


def _posed(frame: Observation) -> dict[str, Any]:
    k = frame.intrinsics
    return {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "cam_to_world": frame.cam_to_world.tolist()}


def test_perceive_within_a_workspace_or_a_mask_answers_as_the_python_api(client: TestClient,
                                                                         frame: Observation) -> None:
    """The request's workspace and mask limit the frame as ``FramePerceiver``'s do: the objects on
    the table's y > 0 half are left out, by the box and by a mask of the same pixels."""
    from craft_e.runtime.frame import FramePerceiver
    from craft_e.runtime.kb.bundle import load_bundle
    from craft_e.runtime.perception.workspace import Workspace
    from craft_e.runtime.sim.pipeline import sim_vocabulary

    half = Workspace(0.14, 0.61, -0.30, 0.0, 0.30)
    expected = FramePerceiver(load_bundle(KB_DIR / "craft-e-default"), vocabulary=sim_vocabulary(),
                              workspace=half).ground("cut", frame.rgb, frame.depth, frame.intrinsics,
                                                     frame.cam_to_world)
    full = client.post("/perceive", json=_body(frame, camera=_posed(frame)))
    r = client.post("/perceive", json=_body(frame, camera=_posed(frame), workspace=dict(zip(
        ("x_min", "x_max", "y_min", "y_max", "z_max"), half.bounds(), strict=True))))
    assert full.status_code == 200 and r.status_code == 200, r.text
    data = r.json()
    assert 0 < data["regions"] == len(expected.rois) < full.json()["regions"]
    assert data["chosen"] == (expected.grounding.chosen.index if expected.grounding.chosen is not None else None)
    assert data["grasp"] == expected.grasp_dict()
    # the same pixels as a mask: white where the frame's points lie in the box
    keep = half.contains(frame.points_world()) & (frame.depth > 0)
    image = np.where(keep[..., None], np.uint8(255), np.uint8(0)).repeat(3, axis=2).astype(np.uint8)
    masked = client.post("/perceive", json=_body(frame, mask_b64=b64(png_bytes(image))))
    assert masked.status_code == 200, masked.text
    assert masked.json()["regions"] == data["regions"]


@pytest.mark.parametrize(("changes", "field", "needle"), [
    ({"workspace": {"x_min": 1.0, "x_max": 0.0, "y_min": 0.0, "y_max": 1.0}}, "workspace",
     "each minimum must lie below its maximum"),
    ({"workspace": {"x_min": 0.0, "x_max": 1.0, "y_min": 0.0, "y_max": 1.0}}, "workspace",
     "give cam_to_world too"),
    ({"mask_b64": b64(png_bytes(np.full((48, 64), 255, np.uint8)))}, "mask_b64", "give a mask of the frame's size"),
    ({"mask_b64": b64(png_bytes(np.zeros((480, 640), np.uint8)))}, "mask_b64", "the mask leaves no depth reading"),
    ({"mask_b64": "%%%"}, "mask_b64", "not valid base64"),
    ({"mask_b64": b64(_jpeg(np.full((480, 640, 3), 255, np.uint8)))}, "mask_b64", "send a PNG"),
])
def test_a_workspace_or_mask_that_does_not_fit_is_422_naming_its_field(client: TestClient, frame: Observation,
                                                                       changes: dict[str, Any], field: str,
                                                                       needle: str) -> None:
    r = client.post("/perceive", json=_body(frame, **changes))
    assert r.status_code == 422, r.text
    assert needle in r.text and field in json.dumps(r.json()["detail"])
