"""GR-ConvNet, GG-CNN, GG-CNN2: the real Cornell weights reproduce the original networks' outputs.

The reference inputs/outputs in ``<shared>/models/grasp/*_reference_io.npz`` were produced by the
original implementations; a missing shared folder is a test failure, not a skip.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from craft_e.paths import shared_dir
from craft_e.runtime.grasp import registry
from craft_e.runtime.grasp.base import GraspMaps
from craft_e.runtime.grasp.geometry import Grasp2D
from craft_e.runtime.grasp.ggcnn import GGCNN, GGCNN2
from craft_e.runtime.grasp.grconvnet import GenerativeResnet
from craft_e.runtime.grasp.metrics import angle_difference
from craft_e.runtime.grasp.postprocess import (
    ANGLE_QUANTUM_RAD,
    WIDTH_QUANTUM_PX,
    ProcessedMaps,
    detect_grasps,
    find_peaks,
    post_process,
    snap,
)
from craft_e.runtime.grasp.predict import CropWindow, choose_crop, predict_grasps
from craft_e.runtime.grasp.registry import GraspWeightsError, load, models_dir
from craft_e.runtime.grasp.synthetic import bar_scene

NETS = ("grconvnet", "ggcnn", "ggcnn2")
MAPS = ("pos", "cos", "sin", "width")


@pytest.fixture(scope="module", autouse=True)
def _shared_models_present() -> None:
    folder = models_dir()
    if not folder.is_dir():
        pytest.fail(
            f"shared grasp models not found at {folder} (shared dir {shared_dir()}). "
            "Set CRAFT_SHARED to the read-only shared/ folder that holds models/grasp/."
        )


def _reference(name: str) -> dict[str, np.ndarray]:
    path = models_dir() / registry.get_spec(name).reference_io
    if not path.is_file():
        pytest.fail(f"reference outputs {path} missing; set CRAFT_SHARED to the shared folder")
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


@pytest.mark.parametrize("name", NETS)
def test_matches_reference_outputs(name: str) -> None:
    ref = _reference(name)
    model = load(name)
    assert not model.training
    with torch.inference_mode():
        out = model(torch.from_numpy(ref["input"]))
    assert isinstance(out, GraspMaps)
    for key in MAPS:
        got = getattr(out, key).numpy()
        assert got.shape == ref[key].shape
        diff = float(np.abs(got - ref[key]).max())
        assert diff < 1e-4, f"{name}.{key}: max abs diff {diff}"


def test_hyperparameters_inferred_from_checkpoint() -> None:
    gr = load("grconvnet")
    assert isinstance(gr, GenerativeResnet)
    assert (gr.conv1.in_channels, gr.conv1.out_channels) == (4, 16)  # RGB-D, channel_size 16
    gg = load("ggcnn")
    assert isinstance(gg, GGCNN)
    assert gg.conv1.out_channels == 32 and gg.convt3.out_channels == 32
    gg2 = load("ggcnn2")
    assert isinstance(gg2, GGCNN2)
    assert [gr.input_size, gg.input_size, gg2.input_size] == [224, 300, 300]


def test_corrupt_weights_are_refused_naming_the_file(tmp_path: Path) -> None:
    spec = registry.get_spec("ggcnn")
    copy = tmp_path / spec.filename
    shutil.copyfile(models_dir() / spec.filename, copy)
    copy.chmod(0o644)
    data = bytearray(copy.read_bytes())
    data[-1] ^= 0xFF
    copy.write_bytes(bytes(data))
    with pytest.raises(GraspWeightsError, match="sha256") as err:
        load("ggcnn", root=tmp_path)
    assert spec.filename in str(err.value) and "Fix" in str(err.value)


def test_missing_weights_error_says_how_to_fix(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CRAFT_SHARED", str(tmp_path))
    with pytest.raises(GraspWeightsError, match="CRAFT_SHARED") as err:
        load("grconvnet")
    assert "grconvnet3_cornell_rgbd_ch16.safetensors" in str(err.value)
    with pytest.raises(KeyError, match="available"):
        load("graspnet")


@pytest.mark.parametrize("name", NETS)
def test_reference_maps_give_grasps(name: str) -> None:
    ref = _reference(name)
    outs = GraspMaps(*(torch.from_numpy(ref[k]) for k in MAPS))
    maps = post_process(outs, registry.get_spec(name).width_scale_px)
    size = ref["input"].shape[-1]
    grasps = detect_grasps(maps, max_grasps=5)
    assert grasps, "the reference scene holds graspable objects"
    qualities = [g.quality for g in grasps]
    assert qualities == sorted(qualities, reverse=True)
    for g in grasps:
        assert 0.2 < g.quality <= 1.0
        assert 20 <= g.center_xy[0] < size - 20 and 20 <= g.center_xy[1] < size - 20
        assert -math.pi / 2 <= g.angle_rad < math.pi / 2
        assert g.width_px > 0 and g.length_px == pytest.approx(g.width_px / 2)
    for i, a in enumerate(grasps):
        for b in grasps[i + 1 :]:
            assert (
                max(abs(a.center_xy[0] - b.center_xy[0]), abs(a.center_xy[1] - b.center_xy[1])) > 20
            )


def test_post_process_decodes_angle_and_width() -> None:
    theta, s = 0.3, 64
    ones = torch.ones(1, 1, s, s)
    maps = post_process(
        GraspMaps(ones * 0.5, ones * math.cos(2 * theta), ones * math.sin(2 * theta), ones * 0.4),
        width_scale_px=150.0,
    )
    assert np.allclose(maps.angle, theta, atol=1e-6)
    assert np.allclose(maps.width_px, 60.0, atol=1e-4)
    assert np.allclose(maps.quality, 0.5, atol=1e-6)


def test_find_peaks_like_peak_local_max() -> None:
    yy, xx = np.mgrid[0:100, 0:100]
    img = 0.9 * np.exp(-((xx - 30) ** 2 + (yy - 40) ** 2) / 50.0) + 0.6 * np.exp(
        -((xx - 70) ** 2 + (yy - 60) ** 2) / 50.0
    )
    img[2, 2] = 1.0  # a border peak is ignored
    peaks = find_peaks(img, min_distance=10, threshold=0.2)
    assert peaks.tolist() == [[40, 30], [60, 70]]
    assert find_peaks(img, min_distance=10, threshold=0.7).tolist() == [[40, 30]]
    assert find_peaks(np.ones((50, 50)), min_distance=5).shape == (0, 2)


def test_detect_grasps_respects_mask() -> None:
    yy, xx = np.mgrid[0:100, 0:100]
    q = (0.9 * np.exp(-((xx - 30) ** 2 + (yy - 40) ** 2) / 50.0)).astype(np.float32)
    q += (0.5 * np.exp(-((xx - 70) ** 2 + (yy - 60) ** 2) / 50.0)).astype(np.float32)
    maps = ProcessedMaps(quality=q, angle=np.zeros_like(q), width_px=np.full_like(q, 30.0))
    mask = np.zeros((100, 100), dtype=bool)
    mask[50:70, 60:80] = True
    grasps = detect_grasps(maps, 5, min_distance=10, mask=mask)
    assert [g.center_xy for g in grasps] == [(70.0, 60.0)]


def test_grasps_leave_at_a_fixed_precision_so_last_digit_noise_does_not_reach_them() -> None:
    """The maps' last float digits depend on the CPU's kernels (``postprocess.ANGLE_QUANTUM_RAD``):
    maps that differ by that much must give the same grasp, bit for bit."""
    yy, xx = np.mgrid[0:100, 0:100]
    q = (0.9 * np.exp(-((xx - 30) ** 2 + (yy - 40) ** 2) / 50.0)).astype(np.float32)
    maps = ProcessedMaps(quality=q, angle=np.full_like(q, 0.43721), width_px=np.full_like(q, 31.2468))
    noisy = ProcessedMaps(quality=q, angle=maps.angle + np.float32(4e-6), width_px=maps.width_px - np.float32(8e-5))
    (grasp,), (other,) = detect_grasps(maps, 1, min_distance=10), detect_grasps(noisy, 1, min_distance=10)
    assert grasp == other
    assert grasp.angle_rad == pytest.approx(0.437, abs=1e-12) and grasp.width_px == pytest.approx(31.2, abs=1e-12)
    assert snap(-0.0004, ANGLE_QUANTUM_RAD) == 0.0 and snap(1.23456, WIDTH_QUANTUM_PX) == pytest.approx(1.2)
    # an angle past +pi/2 on the grid still wraps into [-pi/2, pi/2)
    edge = ProcessedMaps(quality=q, angle=np.full_like(q, math.pi / 2 + 3e-4), width_px=maps.width_px)
    assert -math.pi / 2 <= detect_grasps(edge, 1, min_distance=10)[0].angle_rad < math.pi / 2


def test_crop_window_maps_back_to_image() -> None:
    mask = np.zeros((480, 640), dtype=bool)
    mask[300:340, 500:620] = True
    win = choose_crop((480, 640), 224, mask)
    assert win.side == 224 and win.x0 == 640 - 224  # clamped inside the image
    assert win.y0 == 320 - 112
    g = Grasp2D((10.0, 20.0), 0.1, 30.0, 15.0, 0.5)
    assert win.to_image(g).center_xy == (win.x0 + 10.0, win.y0 + 20.0)
    big = CropWindow(x0=100, y0=50, side=448, out_size=224)  # 2 image px per network px
    back = big.to_image(g)
    assert back.center_xy == (100 + 2 * 10 + 0.5, 50 + 2 * 20 + 0.5)
    assert back.width_px == 60.0 and back.angle_rad == 0.1


@pytest.mark.parametrize("name", NETS)
def test_predict_grasps_on_synthetic_bar(name: str) -> None:
    scene = bar_scene(angle_deg=60.0, width_m=0.03, height_m=0.03)
    mask = scene.masks[0]
    depth = scene.depth.copy()
    depth[::37, ::41] = 0.0  # sensor holes must not break pre-processing
    grasps = predict_grasps(name, scene.rgb, depth, mask, max_grasps=3, min_quality=0.05)
    assert 1 <= len(grasps) <= 3
    for g in grasps:
        assert mask[round(g.center_xy[1]), round(g.center_xy[0])]
        assert 0.0 <= g.quality <= 1.0 and g.width_px > 0
    # the bar runs at 60°: the best grasp closes across it (a sign error would give +30°, 60° off)
    assert math.degrees(angle_difference(grasps[0].angle_rad, math.radians(150.0))) < 30.0


def test_predict_grasps_input_errors() -> None:
    scene = bar_scene()
    with pytest.raises(ValueError, match="RGB"):
        predict_grasps("grconvnet", None, scene.depth)
    with pytest.raises(ValueError, match="backend"):
        predict_grasps("graspnet", scene.rgb, scene.depth)
    with pytest.raises(ValueError, match="empty"):
        predict_grasps("ggcnn", None, scene.depth, np.zeros_like(scene.masks[0]))
