"""Frames no camera could have taken, through ``craft perceive`` and ``POST /perceive``.

Why: a new user's first frame is often wrong in one way: depth in millimetres saved as floats,
the depth PNG given as the colour image, a camera file with a typo in a focal length, a pose
in another convention. Each of these used to be perceived into a wrong answer (a grasp from
random depth, a table at -0.7 m), a traceback (a 51 GiB allocation), a 500, or minutes of work;
each must be refused with exit 2 / a 4xx naming the file or field and the fix, before any model
loads. One small synthetic frame (a box on a table, seen from above) serves every check.
"""

from __future__ import annotations

import io
import json
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from frame_bytes import OVERHEAD_POSE, b64, npy_bytes, png_bytes
from typer.testing import CliRunner

from craft_e.paths import KB_DIR
from craft_e.runtime.cli.main import app
from craft_e.runtime.frame import FrameError, FrameTooLargeError, decode_depth, frame_observation
from craft_e.runtime.grasp.geometry import CameraIntrinsics

runner = CliRunner()
W, H = 128, 96
POSE = OVERHEAD_POSE
K = CameraIntrinsics.realsense_d435(W, H)


def _frame() -> tuple[np.ndarray, np.ndarray]:
    """A grey table 0.7 m below the camera with a red 5 cm box in the middle."""
    rgb = np.full((H, W, 3), 130, np.uint8)
    depth = np.full((H, W), 0.7, np.float32)
    rgb[38:58, 54:74] = (200, 30, 30)
    depth[38:58, 54:74] = 0.65
    return rgb, depth




def _png_header_only(width: int, height: int) -> bytes:
    """A 16-bit grayscale PNG that claims ``width`` x ``height`` and holds no pixels: what a
    header check reads, and a decoder would choke on (or, with real pixels, spend gigabytes on)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 16, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b"")


def _rigid_but(**rows: list[float]) -> list[list[float]]:
    pose = [list(r) for r in POSE]
    for i, row in rows.items():
        pose[int(i[1:])] = row
    return pose


def test_the_synthetic_frame_passes_every_check() -> None:
    """The bounds below refuse what no camera gives, not a valid frame: with the pose given and
    with the frame made from the table plane."""
    rgb, depth = _frame()
    _, table_z, from_table = frame_observation(rgb, depth, K, POSE)
    assert not from_table and table_z == pytest.approx(0.0, abs=1e-6)
    _, table_z, from_table = frame_observation(rgb, depth, K)
    assert from_table and table_z == 0.0


def _noise() -> np.ndarray:
    return np.random.default_rng(0).uniform(0.3, 1.5, (H, W)).astype(np.float32)


@pytest.mark.parametrize(("change", "part", "needle"), [
    # millimetres saved as float: the clearance map over a 700 m scene asked for 51 GiB
    ({"depth": _frame()[1] * 1000}, "depth", "median reading is 700 m"),
    ({"depth": _frame()[1] * 1e-6}, "depth", "nearer than a depth camera sees"),
    # random depth: the plane fit "found" a table in 1% of the readings and a grasp on noise
    ({"depth": _noise()}, "depth", "the largest plane holds"),
    ({"k": CameraIntrinsics(W, H, 1e9, 1e9, W / 2, H / 2)}, "camera", "field of view"),  # 106 s, then 2.4 TiB
    ({"k": CameraIntrinsics(W, H, 1e-9, 1e-9, W / 2, H / 2)}, "camera", "field of view"),  # nothing found, no reason
    ({"k": CameraIntrinsics(W, H, K.fx, K.fy, 1e12, H / 2)}, "camera", "cx 1e+12 lies outside the image"),
    ({"pose": [[0.0] * 3 + [r[3]] for r in POSE[:3]] + [POSE[3]]}, "cam_to_world", "no rotation"),  # singular
    ({"pose": [[2 * v for v in r[:3]] + [r[3]] for r in POSE[:3]] + [POSE[3]]}, "cam_to_world", "no rotation"),
    ({"pose": _rigid_but(r0=[0.0, -1.0, 0.5, 0.375])}, "cam_to_world", "no rotation"),  # shear
    ({"pose": _rigid_but(r2=[0.0, 0.0, 1.0, 0.7])}, "cam_to_world", "det -1"),  # a mirror
    ({"pose": _rigid_but(r3=[1.0, 1.0, 1.0, 1.0])}, "cam_to_world", "not [0, 0, 0, 1]"),
    ({"pose": _rigid_but(r0=[0.0, -1.0, 0.0, 1e300])}, "cam_to_world", "beyond 1e+06 m"),
    # a proper rotation whose world z points down: the table was above the camera, nothing pickable
    ({"pose": _rigid_but(r1=[1.0, 0.0, 0.0, 0.0], r2=[0.0, 0.0, 1.0, 0.7])}, "cam_to_world", "z points down"),
])
def test_a_frame_no_camera_could_take_is_refused_naming_the_input(change: dict[str, Any], part: str,
                                                                  needle: str) -> None:
    rgb, depth = _frame()
    with pytest.raises(FrameError) as info:
        frame_observation(rgb, change.get("depth", depth), change.get("k", K), change.get("pose", POSE))
    assert needle in str(info.value) and info.value.part == part


def test_a_frame_of_a_few_pixels_is_refused_as_too_small() -> None:
    """A 2 x 2 frame failed as "need at least 3 valid depth points to fit a plane"."""
    k = CameraIntrinsics.realsense_d435(2, 2)
    with pytest.raises(FrameError, match="the frame is 2x2 pixels, too small") as info:
        frame_observation(np.zeros((2, 2, 3), np.uint8), np.full((2, 2), 0.7, np.float32), k)
    assert info.value.part == "rgb"


def test_a_depth_image_is_refused_before_its_pixels_are_decoded() -> None:
    """A depth PNG's size is read from its header (a 10000 x 10000 one took 7.5 s and 1.5 GB to
    refuse); a palette PNG's indices, and a scale that overflows float32, are no depth."""
    with pytest.raises(FrameTooLargeError, match="depth is 5000x5000 pixels"):
        decode_depth(_png_header_only(5000, 5000), 0.001, max_pixels=4096 * 4096)
    from PIL import Image

    palette = io.BytesIO()
    Image.fromarray(_frame()[0]).convert("P").save(palette, format="PNG")
    with pytest.raises(FrameError, match="palette PNG"):
        decode_depth(palette.getvalue(), 0.01)
    with pytest.raises(FrameError, match="up to 10"):
        decode_depth(png_bytes(np.full((H, W), 700, np.uint16)), 1e300)


# -- craft perceive: each refusal names the file and comes before the bundle (never read) ----------


@pytest.fixture()
def files(tmp_path: Path) -> dict[str, Path]:
    rgb, depth = _frame()
    paths = {"rgb": tmp_path / "rgb.png", "depth": tmp_path / "depth.npy", "camera": tmp_path / "camera.json"}
    paths["rgb"].write_bytes(png_bytes(rgb))
    paths["depth"].write_bytes(npy_bytes(depth))
    paths["camera"].write_text(json.dumps({"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy, "cam_to_world": POSE}),
                               encoding="utf-8")
    return paths


def _bad(files: dict[str, Path], tmp_path: Path, *extra: str, **paths: Path) -> str:
    chosen = {**files, **paths}
    out = tmp_path / "out.json"
    args = ["perceive", "--kb", str(tmp_path / "no-kb"), "--verb", "cut", "--rgb", str(chosen["rgb"]),
            "--depth", str(chosen["depth"]), "--camera", str(chosen["camera"]), "--json", str(out), *extra]
    result = runner.invoke(app, args, env={"COLUMNS": "300"})
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert not out.exists()
    return " ".join(result.output.split())


def test_craft_perceive_refuses_a_depth_png_given_as_the_colour_image(files: dict[str, Path], tmp_path: Path) -> None:
    """RGB conversion clipped the 16-bit image to white, and the frame was perceived into another grasp."""
    depth_png = tmp_path / "depth.png"
    depth_png.write_bytes(png_bytes(np.full((H, W), 700, np.uint16)))
    text = _bad(files, tmp_path, rgb=depth_png)
    assert f"{depth_png}: a single-channel I;16 image, not 8-bit colour (is it the depth image?)" in text


def test_craft_perceive_refuses_a_huge_image_from_its_header(files: dict[str, Path], tmp_path: Path) -> None:
    """5000 x 5000 took 47 s and 4.6 GB; past PIL's bomb limit it was a traceback."""
    from PIL import Image

    big = tmp_path / "big.png"
    Image.new("L", (4097, 4097)).save(big)
    assert f"{big}: the image is 4097x4097 pixels; at most 16777216 are perceived" in _bad(files, tmp_path, rgb=big)


def test_craft_perceive_names_the_depth_file_and_the_scale_for_millimetres(files: dict[str, Path],
                                                                          tmp_path: Path) -> None:
    """Float millimetres were read as metres: a MemoryError traceback (51 GiB) after the models loaded."""
    mm = tmp_path / "mm.npy"
    mm.write_bytes(npy_bytes(_frame()[1] * 1000))
    text = _bad(files, tmp_path, depth=mm)
    assert f"{mm}: the depth's median reading is 700 m" in text and "give --depth-scale 0.001" in text
    noise = tmp_path / "noise.npy"
    noise.write_bytes(npy_bytes(_noise()))
    assert f"{noise}: no table plane in the depth image: the largest plane holds" in _bad(files, tmp_path, depth=noise)
    assert "--depth-scale 20: metres per depth unit must be a positive number up to 10" in _bad(
        files, tmp_path, "--depth-scale", "20")


@pytest.mark.parametrize(("camera", "needle"), [
    ({"fx": 1e9, "fy": 1e9, "cx": W / 2, "cy": H / 2}, "fx 1e+09 gives a"),
    ({"fx": K.fx, "fy": K.fy, "cx": 1e12, "cy": H / 2}, "cx 1e+12 lies outside the image"),
    ({"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy, "cam_to_world": _rigid_but(r2=[0.0, 0.0, -2.0, 0.7])},
     "no rotation"),
    ({"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy,
      "cam_to_world": _rigid_but(r1=[1.0, 0.0, 0.0, 0.0], r2=[0.0, 0.0, 1.0, 0.7])}, "(z points down)"),
    ({"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy, "width": str(W)}, "width must be a number of pixels, got '128'"),
])
def test_craft_perceive_names_the_camera_file(files: dict[str, Path], tmp_path: Path, camera: dict[str, Any],
                                              needle: str) -> None:
    path = tmp_path / "bad_camera.json"
    path.write_text(json.dumps(camera), encoding="utf-8")
    text = _bad(files, tmp_path, camera=path)
    assert f"{path}: " in text and needle in text


def test_craft_perceive_names_a_vocabulary_listing_an_object_twice(files: dict[str, Path], tmp_path: Path) -> None:
    """The grounder's "vocabulary lists knife more than once" named neither the file nor the fix."""
    vocab = tmp_path / "vocab.txt"
    vocab.write_text("knife\nmug\nKnife\n", encoding="utf-8")
    assert f"--vocab {vocab}: lists knife more than once; keep one line for each object" in _bad(
        files, tmp_path, "--vocab", str(vocab))


# -- POST /perceive: a 4xx naming the field, never a 500 or a silently wrong answer ----------------


@pytest.fixture(scope="module")
def client() -> Iterator[Any]:
    from fastapi.testclient import TestClient

    from craft_e.runtime.evaluation.sim_eval import default_encoder
    from craft_e.runtime.serve.app import create_app

    with TestClient(create_app(KB_DIR / "craft-e-default", frame_encoder=default_encoder(1))) as c:
        yield c


def _body(**changes: Any) -> dict[str, Any]:
    rgb, depth = _frame()
    body: dict[str, Any] = {"verb": "cut", "rgb_b64": b64(png_bytes(rgb)), "depth_b64": b64(npy_bytes(depth)),
                            "camera": {"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy, "cam_to_world": POSE}}
    body.update(changes)
    return body


@pytest.mark.parametrize(("changes", "status", "loc", "needle"), [
    # a 500 (MemoryError) on the testbed's frame
    ({"depth_b64": b64(npy_bytes(_frame()[1] * 1000))}, 422, ["depth_b64"], "median reading is 700 m"),
    ({"depth_b64": b64(png_bytes(np.full((H, W), 700, np.uint16))), "depth_scale": 10}, 422, ["depth_b64"],
     "median reading is 7000 m"),
    ({"depth_b64": b64(_png_header_only(5000, 5000)), "depth_scale": 0.001}, 413, None, "depth is 5000x5000 pixels"),
    ({"rgb_b64": b64(png_bytes(np.full((H, W), 700, np.uint16)))}, 422, ["rgb_b64"], "single-channel I;16"),
    ({"depth_b64": b64(npy_bytes(_noise()))}, 422, ["depth_b64"], "the largest plane holds"),
    ({"camera": {"fx": True, "fy": K.fy, "cx": K.cx, "cy": K.cy}}, 422, ["camera", "fx"], "valid number"),  # 1 px
    ({"camera": {"fx": K.fx, "fy": K.fy, "cx": 1e5, "cy": K.cy}}, 422, ["camera"], "cx 100000 lies outside"),
    ({"camera": {"fx": 1e5, "fy": 1e5, "cx": K.cx, "cy": K.cy}}, 422, ["camera"], "field of view"),
    ({"camera": {"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy, "cam_to_world": _rigid_but(r2=[0.0, 0.0, -2.0, 0.7])}},
     422, ["camera", "cam_to_world"], "no rotation"),
    ({"camera": {"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy,
                 "cam_to_world": _rigid_but(r1=[1.0, 0.0, 0.0, 0.0], r2=[0.0, 0.0, 1.0, 0.7])}},
     422, ["camera", "cam_to_world"], "z points down"),
])
def test_perceive_refuses_what_no_camera_sends(client: Any, changes: dict[str, Any], status: int,
                                               loc: list[str] | None, needle: str) -> None:
    r = client.post("/perceive", json=_body(**changes))
    assert r.status_code == status, r.text
    assert needle in r.text
    if loc is not None:
        assert r.json()["detail"][0]["loc"] == ["body", *loc]
