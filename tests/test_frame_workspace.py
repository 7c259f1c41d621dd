"""A workspace box or a mask limits a camera's frame to what the robot may pick.

Why: a real camera sees more than the objects (the robot's base and arm, the table's edge, the
floor), and segmentation makes a region of everything standing above the table plane; grounding
then chose the arm as "a pitcher" to pour with (``benchmarks/bench_frame_views.py``).
``perception/workspace.py`` keeps regions to the robot's workspace. Checked on a synthetic frame: a grey table 0.7 m below the camera, one box in the middle and one near the
image's left edge.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from frame_bytes import OVERHEAD_POSE, png_bytes
from typer.testing import CliRunner

from craft_e.paths import KB_DIR, VOCAB_DIR
from craft_e.runtime.cli.main import app
from craft_e.runtime.frame import FrameError, frame_keep, frame_observation
from craft_e.runtime.grasp.geometry import CameraIntrinsics
from craft_e.runtime.perception.segment import segment
from craft_e.runtime.perception.workspace import Workspace, mask_from_image

runner = CliRunner()
W, H = 128, 96
POSE = OVERHEAD_POSE
K = CameraIntrinsics.realsense_d435(W, H)
MIDDLE = (slice(38, 58), slice(54, 74))  # world y about 0
LEFT = (slice(38, 58), slice(4, 20))  # world y about +0.25
NEAR_MIDDLE = Workspace(0.2, 0.55, -0.15, 0.15)


def _frame() -> tuple[np.ndarray, np.ndarray]:
    """The table with a red 5 cm box in the middle and a blue one near the left edge."""
    rgb = np.full((H, W, 3), 130, np.uint8)
    depth = np.full((H, W), 0.7, np.float32)
    for where, colour in ((MIDDLE, (200, 30, 30)), (LEFT, (30, 30, 200))):
        rgb[where] = colour
        depth[where] = 0.65
    return rgb, depth


def _regions(**limits: Any) -> list[tuple[int, int, int, int]]:
    rgb, depth = _frame()
    obs, _, from_table = frame_observation(rgb, depth, K, limits.pop("pose", POSE))
    keep = frame_keep(obs, from_table, **limits)
    return sorted(tuple(int(v) for v in r.box_xywh) for r in segment(obs, keep=keep).rois)  # type: ignore[misc]


def test_a_workspace_reads_as_four_or_five_numbers_and_refuses_the_rest() -> None:
    assert Workspace.parse("0.14, 0.61,-0.30,0.30") == Workspace(0.14, 0.61, -0.30, 0.30)
    assert Workspace.parse("0,1,0,1,0.3").z_max == pytest.approx(0.3)
    assert Workspace.parse("0,1,0,1,0.3").bounds() == [0.0, 1.0, 0.0, 1.0, 0.3]
    for bad, needle in (("1,2,3", "four or five numbers"), ("a,b,c,d", "four or five numbers"),
                        ("1,0,0,1", "each minimum below its maximum"), ("0,1,0,nan", "finite metres"),
                        ("0,1,0,1,2,3", "four or five numbers")):
        with pytest.raises(ValueError, match=needle):
            Workspace.parse(bad)
    points = np.array([[0.3, 0.0, 0.01], [0.3, 0.5, 0.01], [np.nan, 0.0, 0.0], [0.3, 0.0, 0.4]])
    assert NEAR_MIDDLE.contains(points).tolist() == [True, False, False, True]
    assert Workspace(0.2, 0.55, -0.15, 0.15, 0.3).contains(points).tolist() == [True, False, False, False]


def test_a_mask_is_its_non_zero_pixels_in_any_channel() -> None:
    image = np.zeros((2, 3, 3), np.uint8)
    image[0, 1, 2] = 1
    assert mask_from_image(image).tolist() == [[False, True, False], [False, False, False]]
    assert mask_from_image(np.array([[0, 7]], np.uint16)).tolist() == [[False, True]]
    with pytest.raises(ValueError, match="H x W image"):
        mask_from_image(np.zeros((1, 1, 1, 1)))


def test_a_workspace_or_a_mask_leaves_out_what_stands_outside_it() -> None:
    both = _regions()
    assert len(both) == 2
    middle = [b for b in both if b[0] > 40]
    assert _regions(workspace=NEAR_MIDDLE) == middle
    keep = np.ones((H, W), bool)
    keep[:, :30] = False  # the left box's pixels
    assert _regions(mask=keep) == middle
    assert _regions(mask=np.where(keep, 255, 0).astype(np.uint8)) == middle  # an image's 0/255, as numbers
    # a ceiling under the boxes' tops (5 cm above the table) leaves neither; one above them, both
    assert _regions(workspace=Workspace(0.0, 1.0, -1.0, 1.0, 0.03)) == []
    assert _regions(workspace=Workspace(0.0, 1.0, -1.0, 1.0, 0.30)) == both


def test_only_segmentation_reads_the_limits() -> None:
    """The table is fitted to the whole frame, so heights do not change; a box around everything
    keeps every pixel with depth, and no limit is no keep mask."""
    rgb, depth = _frame()
    obs, _, from_table = frame_observation(rgb, depth, K, POSE)
    assert frame_keep(obs, from_table) is None
    everything = frame_keep(obs, from_table, np.ones((H, W), bool), Workspace(-10, 10, -10, 10))
    assert everything is not None and np.array_equal(everything, depth > 0)
    plain, limited = segment(obs), segment(obs, keep=everything)
    assert np.array_equal(plain.plane.normal, limited.plane.normal) and plain.plane.offset == limited.plane.offset
    assert np.array_equal(plain.height, limited.height, equal_nan=True)


@pytest.mark.parametrize(("limits", "part", "needle"), [
    ({"workspace": NEAR_MIDDLE, "pose": None}, "workspace", "give cam_to_world too"),
    ({"workspace": Workspace(5.0, 6.0, 5.0, 6.0)}, "workspace", "no depth reading lies inside the workspace"),
    ({"mask": np.ones((H, W + 1), bool)}, "mask", "give a mask of the frame's size"),
    ({"mask": np.zeros((H, W), bool)}, "mask", "the mask leaves no depth reading"),
])
def test_a_limit_that_does_not_fit_the_frame_is_refused_naming_it(limits: dict[str, Any], part: str,
                                                                   needle: str) -> None:
    with pytest.raises(FrameError, match=needle) as refused:
        _regions(**limits)
    assert refused.value.part == part


@pytest.fixture()
def files(tmp_path: Path) -> dict[str, Path]:
    rgb, depth = _frame()
    paths = {"rgb": tmp_path / "rgb.png", "depth": tmp_path / "depth.npy", "camera": tmp_path / "camera.json"}
    paths["rgb"].write_bytes(png_bytes(rgb))
    np.save(paths["depth"], depth, allow_pickle=False)
    paths["camera"].write_text(json.dumps({"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy, "cam_to_world": POSE}))
    return paths


def _perceive(files: dict[str, Path], *extra: str) -> Any:
    return runner.invoke(app, ["perceive", "--kb", str(KB_DIR / "craft-e-default"), "--verb", "carry",
                               "--rgb", str(files["rgb"]), "--depth", str(files["depth"]),
                               "--vocab", str(VOCAB_DIR / "sim_objects.txt"), *extra], env={"COLUMNS": "300"})


def test_craft_perceive_names_a_bad_workspace_or_mask_before_loading_anything(files: dict[str, Path],
                                                                              tmp_path: Path) -> None:
    camera = ("--camera", str(files["camera"]))
    result = _perceive(files, *camera, "--workspace", "1,2,3")
    assert result.exit_code == 2 and "four or five numbers" in result.output
    result = _perceive(files, "--workspace", "0,1,-1,1")  # no --camera: no pose
    assert result.exit_code == 2 and "give a --camera file with cam_to_world" in result.output
    result = _perceive(files, *camera, "--workspace", "5,6,5,6")
    assert result.exit_code == 2 and "--workspace 5,6,5,6: no depth reading lies inside" in " ".join(result.output.split())
    small = tmp_path / "small_mask.png"
    small.write_bytes(png_bytes(np.full((H, W - 1), 255, np.uint8)))
    result = _perceive(files, *camera, "--mask", str(small))
    assert result.exit_code == 2 and "small_mask.png" in result.output and "give a mask of the frame's size" in result.output
    black = tmp_path / "black.png"
    black.write_bytes(png_bytes(np.zeros((H, W, 3), np.uint8)))
    result = _perceive(files, *camera, "--mask", str(black))
    assert result.exit_code == 2 and "black.png" in result.output and "leaves no depth reading" in result.output
    result = _perceive(files, *camera, "--mask", str(tmp_path))
    assert result.exit_code == 2 and "is a folder" in result.output
    from PIL import Image

    jpeg = tmp_path / "mask.jpg"
    Image.fromarray(np.full((H, W), 255, np.uint8)).save(jpeg, format="JPEG")
    result = _perceive(files, *camera, "--mask", str(jpeg))
    assert result.exit_code == 2 and "mask.jpg: a JPEG mask; save it as PNG" in " ".join(result.output.split())


def test_craft_perceive_within_a_workspace_perceives_only_what_stands_in_it(files: dict[str, Path],
                                                                             tmp_path: Path) -> None:
    out = tmp_path / "choice.json"
    result = _perceive(files, "--camera", str(files["camera"]), "--workspace", "0.2,0.55,-0.15,0.15,0.3",
                       "--json", str(out))
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text(encoding="utf-8"))
    assert data["regions"] == 1 and data["workspace"] == [0.2, 0.55, -0.15, 0.15, 0.3] and data["mask"] is None
    assert "regions only within the workspace" in " ".join(result.output.split())
    # with a mask of the left box instead (an RGBA image: its alpha is not read as "perceive")
    keep = np.zeros((H, W, 4), np.uint8)
    keep[..., 3] = 255
    keep[:, 30:, :3] = 255
    mask = tmp_path / "mask.png"
    mask.write_bytes(png_bytes(keep))
    result = _perceive(files, "--mask", str(mask), "--json", str(out))
    assert result.exit_code == 0, result.output
    assert json.loads(out.read_text(encoding="utf-8"))["regions"] == 1


def test_a_region_whose_points_stand_apart_on_the_table_is_split() -> None:
    """Two objects that overlap in the image (one in front of the other, from an angle) but stand
    5 cm apart on the table are two regions with ``split_on_table``; one object stays one."""
    from craft_e.runtime.perception.plane import Plane
    from craft_e.runtime.perception.segment import SegmentConfig, split_on_table

    plane = Plane(np.array([0.0, 0.0, -1.0]), 0.7)  # the table 0.7 m down the optical axis
    points = np.full((H, W, 3), np.nan)
    mask = np.zeros((H, W), bool)
    mask[30:60, 20:80] = True  # one component in the image
    rows, cols = np.nonzero(mask)
    points[rows, cols] = np.stack([cols * 0.001, rows * 0.001, np.full(len(rows), 0.65)], axis=1)
    points[30:60, 50:80, 0] += 0.05  # the right half stands 5 cm farther along the table
    mask[30:60, 80:86] = True  # flat pixels beside it (what the colour cue adds: a blade lying flat)
    points[30:60, 80:86] = np.stack(np.broadcast_arrays(0.1, 0.04, 0.7), axis=-1)
    height = plane.distance(np.nan_to_num(points, nan=0.0))
    height[~mask] = np.nan
    config = SegmentConfig(split_on_table=True)
    parts = split_on_table(mask, points, height, plane, config)
    # the flat pixels join the part nearest them in the image
    assert sorted(tuple(int(v) for v in p.box_xywh) for p in parts) == [(20, 30, 30, 30), (50, 30, 36, 30)]
    cropped = split_on_table(mask, points, height, plane, config, (slice(25, 70), slice(10, 90)))  # a window holding it
    assert [(p.box_xywh, p.area) for p in cropped] == [(p.box_xywh, p.area) for p in parts]
    assert all(np.array_equal(a.mask, b.mask) for a, b in zip(cropped, parts, strict=True))
    points[30:60, 50:80, 0] -= 0.05  # together again: one object, kept as it was
    assert split_on_table(mask, points, height, plane, config) == []


def test_splitting_leaves_regions_that_stand_apart_in_the_image_alone() -> None:
    from craft_e.runtime.perception.segment import SegmentConfig

    rgb, depth = _frame()
    obs, _, _ = frame_observation(rgb, depth, K, POSE)
    plain = segment(obs)
    split = segment(obs, SegmentConfig(split_on_table=True))
    assert [r.box_xywh for r in split.rois] == [r.box_xywh for r in plain.rois]
    assert all(np.array_equal(a.mask, b.mask) for a, b in zip(split.rois, plain.rois, strict=True))


def test_a_region_inside_another_ones_hole_is_not_split_off_twice() -> None:
    """A ring's region is filled (its hole is part of it) and may hold another region, as a skillet
    lid's knob inside its rim. The split reads each component's own pixels, so the knob, a region
    of its own, is not split off the ring's filled mask as a second copy (sim-dev's write/marker/0
    had the knob twice before)."""
    from craft_e.runtime.perception.segment import SegmentConfig

    rgb = np.full((H, W, 3), 130, np.uint8)
    depth = np.full((H, W), 0.7, np.float32)
    depth[20:76, 30:100] = 0.68  # the ring: 2 cm high, 6 pixels wide
    depth[26:70, 36:94] = 0.7
    depth[41:55, 58:72] = 0.66  # the knob in its middle, on the table
    obs, _, _ = frame_observation(rgb, depth, K, POSE)
    plain = segment(obs)
    assert len(plain.rois) == 2
    assert [r.box_xywh for r in segment(obs, SegmentConfig(split_on_table=True)).rois] == [r.box_xywh for r in plain.rois]
