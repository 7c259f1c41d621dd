"""From the four network maps to ranked grasp rectangles, as the original repositories do it.

Steps (GG-CNN ``post_process_output`` + ``detect_grasps``; GR-ConvNet copies them):
angle = ½·atan2(sin, cos); width in pixels = width map × the training normalisation; Gaussian
smoothing of quality (σ=2), angle (σ=2) and width (σ=1), edge mode "nearest", truncate 4 (scikit-image
``gaussian`` defaults, reproduced with scipy so scikit-image is not needed); then local maxima of
quality at least ``min_distance`` apart and above 0.2, strongest first. The opening is the width
map at the peak, the jaw size half of it; angle and opening leave at a fixed precision (``snap``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import torch
from scipy import ndimage

from .base import GraspMaps
from .geometry import Grasp2D, wrap_half_pi

Float32Array = npt.NDArray[np.float32]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.intp]

#: The precision at which a grasp's angle and opening leave the network (``snap``). The maps'
#: last float digits depend on the CPU's kernels: on the development host, limiting oneDNN to AVX
#: or running on one thread instead of two moved the angle map by up to 4.5e-6 rad and the width
#: map by up to 8e-5 px (ad hoc, 3 sim-dev frames), and a grasp yaw that differs in the sixth
#: digit was enough to change 2 of 222 pickability outcomes (the physics amplifies it). On grids
#: ~200 and ~1000 times coarser than those differences, every host gets the same grasp except
#: where a value lies within that difference of a grid line (about 1 grasp in 100). Both grids
#: are far below what the networks resolve (their angle bins are degrees wide, 1e-3 rad is
#: 0.06 degrees) and below what the simulated fingers feel (0.1 px is ~0.1 mm at the table).
ANGLE_QUANTUM_RAD = 1e-3
WIDTH_QUANTUM_PX = 0.1


def snap(value: float, quantum: float) -> float:
    """``value`` to the nearest multiple of ``quantum`` (a pure function of its inputs' bits)."""
    return round(value / quantum) * quantum


@dataclass(frozen=True)
class ProcessedMaps:
    """Smoothed per-pixel grasp maps of one image, each ``[S, S]`` (network input pixels)."""

    quality: Float32Array
    angle: Float32Array
    width_px: Float32Array


def post_process(maps: GraspMaps, width_scale_px: float, index: int = 0) -> ProcessedMaps:
    """Raw network maps (batch element ``index``) → smoothed quality, angle and width maps."""
    with torch.no_grad():
        q = maps.pos[index, 0].detach().cpu().numpy().astype(np.float64)  # [S, S]
        ang = (torch.atan2(maps.sin[index, 0], maps.cos[index, 0]) / 2.0).cpu().numpy()  # [S, S]
        width = maps.width[index, 0].detach().cpu().numpy().astype(np.float64) * width_scale_px
    q = ndimage.gaussian_filter(q, 2.0, mode="nearest", truncate=4.0)
    ang = ndimage.gaussian_filter(ang.astype(np.float64), 2.0, mode="nearest", truncate=4.0)
    width = ndimage.gaussian_filter(width, 1.0, mode="nearest", truncate=4.0)
    return ProcessedMaps(q.astype(np.float32), ang.astype(np.float32), width.astype(np.float32))


def find_peaks(
    image: npt.NDArray[np.floating[npt.NBitBase]] | Float32Array,
    min_distance: int = 20,
    threshold: float = 0.2,
    num_peaks: int | None = None,
    exclude_border: bool = True,
) -> IntArray:
    """Local maxima ``[N, 2]`` as (row, col), strongest first — ``skimage.peak_local_max``.

    A pixel is a peak if it equals the maximum of its ``(2·min_distance+1)²`` window and exceeds
    ``threshold``; peaks closer than ``min_distance`` to the border are dropped (as the original,
    since the maps are unreliable there); equal-valued neighbours within ``min_distance``
    (Chebyshev) are thinned greedily.
    """
    img = np.asarray(image, dtype=np.float64)
    return _peaks_of(img, img.shape, (0, 0), min_distance, threshold, num_peaks, exclude_border)


def find_peaks_in_mask(
    image: npt.NDArray[np.floating[npt.NBitBase]] | Float32Array,
    mask: BoolArray,
    min_distance: int = 20,
    threshold: float = 0.2,
    num_peaks: int | None = None,
    exclude_border: bool = True,
) -> IntArray:
    """``find_peaks`` of ``image`` zeroed outside ``mask``, computed on the mask's bounding box
    plus ``min_distance`` only.

    Exactly the same peaks (``tests/test_grasp_frame.py``): every pixel of the box sees its whole
    maximum window inside the crop, or the image border the full computation sees too; pixels
    of the margin are zero and never above the threshold; row-major order and the border rule
    are kept in full-image coordinates. The robot's one grasp-network pass covers every ROI, so
    this saves a full-window maximum filter per ROI.
    """
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return np.zeros((0, 2), dtype=np.intp)
    height, width = mask.shape
    r0, r1 = max(int(rows[0]) - min_distance, 0), min(int(rows[-1]) + min_distance + 1, height)
    c0, c1 = max(int(cols[0]) - min_distance, 0), min(int(cols[-1]) + min_distance + 1, width)
    crop = np.where(mask[r0:r1, c0:c1], np.asarray(image[r0:r1, c0:c1], dtype=np.float64), 0.0)
    return _peaks_of(crop, (height, width), (r0, c0), min_distance, threshold, num_peaks, exclude_border)


def _peaks_of(
    img: npt.NDArray[np.float64], full_shape: tuple[int, ...], origin: tuple[int, int], min_distance: int,
    threshold: float, num_peaks: int | None, exclude_border: bool,
) -> IntArray:
    """``find_peaks`` on ``img``, a crop at ``origin`` of an image of ``full_shape``; peaks in
    full-image coordinates."""
    size = 2 * min_distance + 1
    local_max = ndimage.maximum_filter(img, size=size, mode="nearest")
    peaks = img == local_max
    if peaks.all():  # a constant image has no peaks
        return np.zeros((0, 2), dtype=np.intp)
    peaks &= img > threshold
    if exclude_border and min_distance > 0:
        b, (r0, c0) = min_distance, origin
        peaks[: max(b - r0, 0)] = False
        peaks[max(full_shape[0] - b - r0, 0):] = False
        peaks[:, : max(b - c0, 0)] = False
        peaks[:, max(full_shape[1] - b - c0, 0):] = False
    coords = np.argwhere(peaks) + np.array(origin, dtype=np.intp)  # [N, 2] row-major order
    order = np.argsort(img[peaks], kind="stable")[::-1]
    chosen: list[npt.NDArray[np.intp]] = []
    for rc in coords[order]:
        if all(np.abs(rc - other).max() > min_distance for other in chosen):
            chosen.append(rc)
            if num_peaks is not None and len(chosen) >= num_peaks:
                break
    return np.array(chosen, dtype=np.intp).reshape(-1, 2)


def detect_grasps(
    maps: ProcessedMaps,
    max_grasps: int = 5,
    min_distance: int = 20,
    min_quality: float = 0.2,
    mask: BoolArray | None = None,
) -> list[Grasp2D]:
    """Grasps at the quality peaks, in network-input pixel coordinates.

    With a ``mask`` the quality outside it is zeroed *before* peak finding, so the grasps returned
    are the best ones whose centre lies on the region (filtering afterwards could leave none when
    a neighbouring object holds the strongest peaks).
    """
    q = maps.quality
    if mask is not None:
        if mask.shape != q.shape:
            raise ValueError(f"mask shape {mask.shape} differs from map shape {q.shape}")
        peaks = find_peaks_in_mask(q, mask, min_distance, min_quality, num_peaks=max_grasps)
    else:
        peaks = find_peaks(q, min_distance, min_quality, num_peaks=max_grasps)
    grasps: list[Grasp2D] = []
    for row, col in peaks:
        width = max(snap(float(maps.width_px[row, col]), WIDTH_QUANTUM_PX), 0.0)
        grasps.append(
            Grasp2D(
                center_xy=(float(col), float(row)),
                angle_rad=wrap_half_pi(snap(float(maps.angle[row, col]), ANGLE_QUANTUM_RAD)),
                width_px=width,
                length_px=width / 2.0,
                quality=float(np.clip(q[row, col], 0.0, 1.0)),
            )
        )
    return grasps
