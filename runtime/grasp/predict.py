"""One entry point for every grasp backend: full-resolution RGB-D in, grasp rectangles out.

Pre-processing follows the original repositories so the Cornell-trained weights see what they
were trained on: a square crop at the native pixel scale (GR-ConvNet's ``CameraData`` crops the
centre 224×224 of a 640×480 frame; GG-CNN crops 300×300), invalid depth filled in (the originals
in-paint with OpenCV; here nearest valid value), depth in metres minus its mean and clipped to
±1, RGB scaled to [0, 1] minus its mean, GR-ConvNet channels ordered (depth, r, g, b). With a
mask the crop is centred on the region, and grown (then resized) only if the region does not fit.

Several regions of one frame (``predict_grasps_rois``): one network pass over the window that holds
them all, at the image's own scale (the networks are fully convolutional), then per-region peak
picking on the shared maps, each region's quality zeroed outside its mask (``detect_grasps``). The
regions' grasps differ from separate passes only through context (input normalisation over the
larger window) and, for regions too large for one 224 px crop, scale; peaks stay
``PEAK_SPACING_PX`` image pixels apart.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Literal, get_args

import numpy as np
import numpy.typing as npt
import torch
import torch.nn.functional as F

from .antipodal import AntipodalConfig, sample_antipodal_grasps
from .base import GraspNet
from .geometry import CameraIntrinsics, Grasp2D, fill_invalid_depth
from .postprocess import ProcessedMaps, detect_grasps, post_process
from .registry import GraspModelSpec, get_spec, load

Backend = Literal["grconvnet", "ggcnn", "ggcnn2", "antipodal"]
BACKENDS: tuple[str, ...] = get_args(Backend)

RGBImage = npt.NDArray[np.uint8]
DepthImage = npt.NDArray[np.float32] | npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
Float32Array = npt.NDArray[np.float32]

MASK_MARGIN = 1.25  # crop side ≥ 1.25 × the mask's bounding box, so the fingers' free space shows
PEAK_SPACING_PX = 20  # peaks at least this many image pixels apart (the originals: 20 network px at 1:1)


@dataclass(frozen=True)
class CropWindow:
    """A square image window ``[y0:y0+side, x0:x0+side]`` resized to ``out_size``²."""

    x0: int
    y0: int
    side: int
    out_size: int

    @property
    def scale(self) -> float:
        """Image pixels per network pixel."""
        return self.side / self.out_size

    @property
    def out_hw(self) -> tuple[int, int]:
        return self.out_size, self.out_size

    def to_image(self, grasp: Grasp2D) -> Grasp2D:
        """Network-pixel grasp → full-image grasp (pixel centres map as in bilinear resizing)."""
        s = self.scale
        return grasp.scaled(s, (self.x0 + 0.5 * s - 0.5, self.y0 + 0.5 * s - 0.5))

    @property
    def slices(self) -> tuple[slice, slice]:
        """Row and column slices of the window in the full image."""
        return slice(self.y0, self.y0 + self.side), slice(self.x0, self.x0 + self.side)

    def resample_mask(self, crop_mask: BoolArray) -> BoolArray:
        """A ``[side, side]`` crop mask at the network pixels' centres (nearest), ``[S, S]``."""
        idx = np.floor((np.arange(self.out_size) + 0.5) * self.scale).astype(np.intp)
        idx = np.minimum(idx, self.side - 1)
        out: BoolArray = crop_mask[np.ix_(idx, idx)]
        return out


def choose_crop(
    image_hw: tuple[int, int],
    out_size: int,
    mask: BoolArray | None = None,
    crop_size: int | None = None,
) -> CropWindow:
    """Square crop at native scale (``crop_size`` defaults to the network size), centred on the
    mask's bounding box if given, else on the image; clamped inside the image."""
    h, w = image_hw
    side = min(crop_size or out_size, h, w)
    cx, cy = w / 2.0, h / 2.0
    if mask is not None:
        if mask.shape != (h, w):
            raise ValueError(f"mask shape {mask.shape} differs from image shape {(h, w)}")
        rows, cols = np.nonzero(mask)
        if rows.size == 0:
            raise ValueError("mask is empty: no region to grasp")
        y_lo, y_hi, x_lo, x_hi = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
        cx, cy = (x_lo + x_hi) / 2.0, (y_lo + y_hi) / 2.0
        side = min(max(side, int(np.ceil(MASK_MARGIN * max(x_hi - x_lo, y_hi - y_lo)))), h, w)
    x0 = int(np.clip(round(cx - side / 2.0), 0, w - side))
    y0 = int(np.clip(round(cy - side / 2.0), 0, h - side))
    return CropWindow(x0, y0, side, out_size)


def _resize(img: Float32Array, out_hw: tuple[int, int]) -> torch.Tensor:
    """``[C, H, W]`` → ``[1, C, h, w]`` bilinear (antialiased when shrinking, like skimage)."""
    t = torch.from_numpy(np.ascontiguousarray(img)).unsqueeze(0)  # [1, C, H, W]
    if (t.shape[-2], t.shape[-1]) == out_hw:
        return t
    shrink = t.shape[-1] > out_hw[1]
    return F.interpolate(t, size=out_hw, mode="bilinear", align_corners=False, antialias=shrink)


@dataclass(frozen=True)
class FrameWindow:
    """A rectangular image window ``[y0:y0+height, x0:x0+width]`` fed at native scale (one
    network pixel per image pixel): the frame pass that keeps the per-ROI crops' scale."""

    x0: int
    y0: int
    width: int
    height: int

    scale = 1.0  # image pixels per network pixel

    @property
    def out_hw(self) -> tuple[int, int]:
        return self.height, self.width

    @property
    def slices(self) -> tuple[slice, slice]:
        return slice(self.y0, self.y0 + self.height), slice(self.x0, self.x0 + self.width)

    def to_image(self, grasp: Grasp2D) -> Grasp2D:
        return grasp.scaled(1.0, (float(self.x0), float(self.y0)))

    def resample_mask(self, crop_mask: BoolArray) -> BoolArray:
        return crop_mask


FRAME_MARGIN_PX = 40  # context around the ROIs' union: the open fingers' half-span at 0.7 m
FRAME_MULTIPLE = 12  # window sides the networks map back to the same size (GG-CNN: 12, GR-ConvNet: 4)


def frame_window(image_hw: tuple[int, int], mask: BoolArray, min_side: int = 224) -> FrameWindow:
    """The native-scale window holding ``mask`` with ``FRAME_MARGIN_PX`` around it, each side at
    least ``min_side`` and a multiple of ``FRAME_MULTIPLE`` (capped by the image), inside it."""
    h, w = image_hw
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        raise ValueError("mask is empty: no region to grasp")

    def span(lo: int, hi: int, size: int) -> tuple[int, int]:
        want = max(hi - lo + 2 * FRAME_MARGIN_PX, min_side)
        want = min(-(-want // FRAME_MULTIPLE) * FRAME_MULTIPLE, size - size % FRAME_MULTIPLE)
        start = int(np.clip(round((lo + hi) / 2 - want / 2), 0, size - want))
        return start, want

    x0, width = span(int(cols.min()), int(cols.max()) + 1, w)
    y0, height = span(int(rows.min()), int(rows.max()) + 1, h)
    return FrameWindow(x0, y0, width, height)


def prepare_input(
    spec: GraspModelSpec, rgb: RGBImage | None, depth: DepthImage, window: CropWindow | FrameWindow
) -> tuple[torch.Tensor, BoolArray]:
    """Full image → network tensor ``[1, C, S, S]`` and the resized hole mask ``[S, S]``."""
    sl = window.slices
    d, holes = fill_invalid_depth(np.asarray(depth, dtype=np.float32)[sl])
    d_t = _resize(d[None], window.out_hw)  # [1, 1, S, S]
    d_t = torch.clamp(d_t - d_t.mean(), -1.0, 1.0)
    hole_mask = window.resample_mask(holes)
    if spec.net_class.modality == "depth":
        return d_t, hole_mask
    if rgb is None:
        raise ValueError(f"backend {spec.name!r} needs an RGB image")
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[:2] != np.asarray(depth).shape:
        raise ValueError(f"rgb must be HxWx3 matching the depth image, got {rgb.shape}")
    c = rgb[sl].astype(np.float32).transpose(2, 0, 1) / 255.0  # [3, side, side]
    c_t = _resize(c, window.out_hw)  # [1, 3, S, S]
    c_t = c_t - c_t.mean()
    return torch.cat([d_t, c_t], dim=1), hole_mask  # [1, 4, S, S]: depth, r, g, b


@cache
def _cached_model(name: str, device: str, fuse: bool = False) -> GraspNet:
    """The loaded network, or its inference rewrite (``grasp.fused``) with ``fuse``."""
    if fuse:
        from .fused import fused

        return fused(_cached_model(name, device)).to(device)
    return load(name, device=device)


def predict_maps(
    name: str,
    rgb: RGBImage | None,
    depth: DepthImage,
    mask: BoolArray | None = None,
    crop_size: int | None = None,
    device: str = "cpu",
) -> tuple[ProcessedMaps, CropWindow, BoolArray]:
    """Run a network on the crop; return its smoothed maps, the crop, and the region mask in
    network pixels (the mask without depth holes, or just the valid-depth pixels)."""
    spec = get_spec(name)
    d = np.asarray(depth, dtype=np.float32)
    if d.ndim != 2:
        raise ValueError(f"depth must be HxW, got shape {d.shape}")
    window = choose_crop((d.shape[0], d.shape[1]), spec.input_size, mask, crop_size)
    frame = _run(spec, rgb, d, window, device)
    region = frame.valid if mask is None else window.resample_mask(mask[window.slices]) & frame.valid
    return frame.maps, window, region


@dataclass(frozen=True)
class FrameMaps:
    """One network pass over a crop of a frame: smoothed maps, the crop, valid-depth pixels."""

    maps: ProcessedMaps
    window: CropWindow | FrameWindow
    valid: BoolArray  # [S, S] network pixels with depth (not filled-in holes)

    @property
    def min_distance(self) -> int:
        """Peak spacing in network pixels: ``PEAK_SPACING_PX`` image pixels at the crop's scale
        (20 at 1:1, as in the originals)."""
        return max(1, round(PEAK_SPACING_PX / self.window.scale))

    def grasps_in(self, mask: BoolArray, max_grasps: int = 5, min_quality: float = 0.2) -> list[Grasp2D]:
        """The best grasps whose centre lies on ``mask`` (full image ``[H, W]``), best first, in
        full-image pixels: peaks of the shared quality map zeroed outside the region."""
        region = self.window.resample_mask(mask[self.window.slices]) & self.valid  # [S, S]
        if not region.any():
            return []
        # ask for spare peaks: resampling can move a centre off a thin mask by a pixel
        found = detect_grasps(self.maps, 2 * max_grasps, self.min_distance, min_quality, mask=region)
        grasps = [g for g in (self.window.to_image(g) for g in found) if _centre_in_mask(g, mask)]
        return grasps[:max_grasps]


def _run(spec: GraspModelSpec, rgb: RGBImage | None, depth: Float32Array,
         window: CropWindow | FrameWindow, device: str, fuse: bool = False) -> FrameMaps:
    """The network on one crop window: smoothed maps and valid-depth network pixels."""
    x, holes = prepare_input(spec, rgb, depth, window)
    model = _cached_model(spec.name, str(device), fuse)
    with torch.inference_mode():
        out = model(x.to(device))
    return FrameMaps(post_process(out, spec.width_scale_px), window, ~holes)


def predict_frame(
    name: str,
    rgb: RGBImage | None,
    depth: DepthImage,
    masks: Sequence[BoolArray],
    crop_size: int | None = None,
    device: str = "cpu",
    *,
    native: bool = True,
    fused: bool = False,
) -> FrameMaps:
    """One pass of network ``name`` over the window holding every mask.

    ``native`` (default): the union's box plus a margin at the image's own scale
    (``frame_window``), the scale the per-ROI crops had for all but the largest objects.
    Otherwise the square crop ``choose_crop`` frames the union with, resized to the network's
    input size (one pass at the cost of one ROI's, but objects shrink ~2x in a full scene:
    measured worse on the static protocol, BENCHMARKS.md). With no non-empty mask, the centre
    crop. ``fused``: run the network's inference rewrite (``grasp.fused``; same maps to float
    rounding, faster on CPU) instead of the checkpoint's layer layout."""
    d = np.asarray(depth, dtype=np.float32)
    if d.ndim != 2:
        raise ValueError(f"depth must be HxW, got shape {d.shape}")
    union: BoolArray | None = None
    for m in masks:
        union = np.asarray(m, dtype=bool) if union is None else union | np.asarray(m, dtype=bool)
    spec = get_spec(name)
    hw = (d.shape[0], d.shape[1])
    has_union = union is not None and bool(union.any())
    window: CropWindow | FrameWindow
    if native and has_union and union is not None:
        window = frame_window(hw, union, spec.input_size)
    else:
        window = choose_crop(hw, spec.input_size, union if has_union else None, crop_size)
    return _run(spec, rgb, d, window, device, fused)


def predict_grasps_rois(
    backend: str,
    rgb: RGBImage | None,
    depth: DepthImage,
    masks: Sequence[BoolArray],
    max_grasps: int = 5,
    *,
    intrinsics: CameraIntrinsics | None = None,
    min_quality: float = 0.2,
    crop_size: int | None = None,
    device: str = "cpu",
    antipodal_config: AntipodalConfig | None = None,
    native: bool = True,
    fused: bool = False,
) -> list[list[Grasp2D]]:
    """``predict_grasps`` for several regions of one frame with one network pass for all of them
    (see the module docstring): one list per mask, best first, every centre on its mask.

    ``native``, ``crop_size`` and ``fused``: see ``predict_frame``; the antipodal sampler runs
    per region.
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown grasp backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    d = np.asarray(depth, dtype=np.float32)
    bool_masks = [np.asarray(m, dtype=bool) for m in masks]
    if backend == "antipodal":
        intr = intrinsics or CameraIntrinsics.realsense_d435(d.shape[1], d.shape[0])
        return [sample_antipodal_grasps(d, m, intr, max_grasps, antipodal_config) for m in bool_masks]
    present = [m for m in bool_masks if m.any()]
    if not present:
        return [[] for _ in bool_masks]
    frame = predict_frame(backend, rgb, d, present, crop_size, device, native=native, fused=fused)
    return [frame.grasps_in(m, max_grasps, min_quality) if m.any() else [] for m in bool_masks]


def predict_grasps(
    backend: str,
    rgb: RGBImage | None,
    depth: DepthImage,
    mask: BoolArray | None = None,
    max_grasps: int = 5,
    *,
    intrinsics: CameraIntrinsics | None = None,
    min_quality: float = 0.2,
    crop_size: int | None = None,
    device: str = "cpu",
    antipodal_config: AntipodalConfig | None = None,
) -> list[Grasp2D]:
    """Grasp rectangles in full-image pixels, best first, quality in [0, 1].

    ``depth`` is metric (metres). With ``mask`` every returned grasp has its centre on the mask.
    ``intrinsics`` only matter to the antipodal sampler (millimetres ↔ pixels); the default is
    RealSense-like for the image size. ``min_quality`` is the networks' peak threshold (0.2 in
    the originals); an empty list means no grasp above it.
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown grasp backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    d = np.asarray(depth, dtype=np.float32)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
    if backend == "antipodal":
        intr = intrinsics or CameraIntrinsics.realsense_d435(d.shape[1], d.shape[0])
        return sample_antipodal_grasps(d, mask, intr, max_grasps, antipodal_config)
    maps, window, region = predict_maps(backend, rgb, d, mask, crop_size, device)
    # with a mask, ask for spare peaks: resampling can move a centre off a thin mask by a pixel
    n_peaks = max_grasps if mask is None else 2 * max_grasps
    found = detect_grasps(maps, n_peaks, min_quality=min_quality, mask=region)
    grasps = [window.to_image(g) for g in found]
    if mask is not None:
        grasps = [g for g in grasps if _centre_in_mask(g, mask)]
    return grasps[:max_grasps]


def _centre_in_mask(grasp: Grasp2D, mask: BoolArray) -> bool:
    h, w = mask.shape
    col = min(max(round(grasp.center_xy[0]), 0), w - 1)
    row = min(max(round(grasp.center_xy[1]), 0), h - 1)
    return bool(mask[row, col])
