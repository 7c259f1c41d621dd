"""An analytic antipodal grasp sampler on depth + a region mask — no network, no training data.

Why it exists: the Cornell-trained networks rarely fire on thin objects (knives, screwdrivers,
scissors), which are exactly the tools many verbs ask for. A top-down parallel gripper can hold a
thin object across its narrow axis whenever (1) the object's width along the closing axis fits in
the opening, (2) there is free space on both sides for the fingers to descend, and (3) the contact
normals oppose each other within the friction cone. All three are checkable on one depth image.

Procedure, vectorised over all candidates:

1. Centres: mask pixels drawn with weight ∝ (distance to the mask border)², so they concentrate on
   the medial axis (seeded, deterministic), plus the innermost pixel.
2. Angles: perpendicular to the *local* principal axis of the mask around the centre (PCA in a
   window the size of the gripper), ± 15° and 30°, plus a coarse sweep for round/blobby shapes.
3. For each (centre, angle): march along the closing axis on three parallel lines spanning the
   finger pad, to where the mask ends on each side. The jaws touch the widest line first, so the
   span is the widest; the centre is moved to the span's middle.
4. Keep a candidate if the span (converted to metres through the intrinsics and depth) plus a
   clearance fits in the 85 mm opening; the finger zones beyond the span — off the mask and with
   depth at least ``min_drop_m`` farther than the object's top — are free; and the outward
   normals of the smoothed mask at both contacts lie within the friction cone of the axis.
5. Score in (0, 1]: normal alignment × free fraction × preference for narrow spans × nearness to
   the region's centroid (lifting near the centre of mass); non-maximum suppression by distance.

Without a mask, objects are segmented as pixels above the support plane, fitted in inverse depth
(1/z is linear in (u, v) for a plane seen by a pinhole camera, so a tilted table is fitted exactly).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from .geometry import CameraIntrinsics, DepthImage, Grasp2D, fill_invalid_depth, wrap_half_pi

Float64Array = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class AntipodalConfig:
    """Gripper geometry (defaults: Robotiq 2F-85-like) and sampling settings."""

    max_opening_m: float = 0.085
    min_clearance_m: float = 0.005  # required gap per side between open jaw and object
    preferred_clearance_m: float = 0.015  # opening = span + 2 × this, capped at max_opening_m
    finger_width_m: float = 0.02  # pad extent across the closing axis
    finger_thickness_m: float = 0.01  # pad extent along the closing axis
    min_drop_m: float = 0.002  # finger zone must be this much deeper than the object's top
    min_free_fraction: float = 0.95
    friction_coef: float = 0.5
    n_centres: int = 64
    angle_offsets_deg: tuple[float, ...] = (0.0, -15.0, 15.0, -30.0, 30.0)
    sweep_step_deg: float = 30.0
    min_separation_m: float = 0.015  # non-maximum suppression radius between grasp centres
    step_px: float = 0.5
    plane_min_height_m: float = 0.005  # mask-less segmentation: height above the support plane
    min_region_px: int = 30
    seed: int = 0


def estimate_object_mask(
    depth: DepthImage, min_height_m: float = 0.005, min_region_px: int = 30
) -> BoolArray:
    """Pixels standing ``min_height_m`` above the dominant plane (robust fit of 1/z = a·u+b·v+c)."""
    d, holes = fill_invalid_depth(depth)
    h, w = d.shape
    vv, uu = np.mgrid[0:h, 0:w]
    A = np.stack([uu.ravel(), vv.ravel(), np.ones(h * w)], axis=1).astype(np.float64)  # [HW, 3]
    inv = 1.0 / d.ravel().astype(np.float64)  # [HW]
    use = ~holes.ravel()
    coef = np.zeros(3)
    for _ in range(4):  # refit on points near the plane: objects stop pulling it up
        coef = np.linalg.lstsq(A[use], inv[use], rcond=None)[0]
        height = d.ravel() - 1.0 / (A @ coef)  # < 0 in front of the plane... sign below
        use = (~holes.ravel()) & (np.abs(height) < max(min_height_m, 0.003))
        if use.sum() < 3:
            break
    plane_depth = (1.0 / (A @ coef)).reshape(h, w)
    mask: BoolArray = ((plane_depth - d) > min_height_m) & ~holes
    labels, n = ndimage.label(mask)
    if n:
        sizes = np.bincount(labels.ravel(), minlength=n + 1)
        mask &= sizes[labels] >= min_region_px
    return mask


def _lookup(
    img: npt.NDArray[np.generic], xs: Float64Array, ys: Float64Array, fill: float
) -> Float64Array:
    """Nearest-pixel values at float coordinates; ``fill`` outside the image."""
    h, w = img.shape
    xi = np.rint(xs).astype(np.intp)
    yi = np.rint(ys).astype(np.intp)
    inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    out = np.full(xs.shape, fill, dtype=np.float64)
    out[inside] = img[yi[inside], xi[inside]]
    return out


def _local_axis_angles(mask: BoolArray, centres: npt.NDArray[np.intp], radius: int) -> Float64Array:
    """Angle (module convention) of the mask's principal axis in a window around each centre."""
    h, w = mask.shape
    angles = np.zeros(len(centres))
    for i, (r, c) in enumerate(centres):
        win = mask[max(r - radius, 0) : r + radius + 1, max(c - radius, 0) : c + radius + 1]
        ys, xs = np.nonzero(win)
        if xs.size < 3:
            continue
        cov = np.cov(np.stack([xs, ys]).astype(np.float64))  # [2, 2]
        evals, evecs = np.linalg.eigh(cov)
        ex, ey = evecs[:, int(np.argmax(evals))]
        angles[i] = math.atan2(-ey, ex)
    return angles


def _first_exit(inside: BoolArray) -> npt.NDArray[np.intp]:
    """Index of the first False along the last axis (its length if there is none)."""
    k = inside.shape[-1]
    exits = ~inside
    first = np.argmax(exits, axis=-1)
    return np.where(exits.any(axis=-1), first, k)


def sample_antipodal_grasps(
    depth: DepthImage,
    mask: BoolArray | None,
    intrinsics: CameraIntrinsics,
    max_grasps: int = 5,
    config: AntipodalConfig | None = None,
) -> list[Grasp2D]:
    """Antipodal top-down grasps on ``mask`` (or on everything above the table), best first."""
    cfg = config or AntipodalConfig()
    d, _ = fill_invalid_depth(depth)
    h, w = d.shape
    if (intrinsics.width, intrinsics.height) != (w, h):
        raise ValueError(
            f"intrinsics are for {intrinsics.width}x{intrinsics.height}, depth is {w}x{h}"
        )
    if mask is None:
        region = estimate_object_mask(d, cfg.plane_min_height_m, cfg.min_region_px)
    else:
        region = np.asarray(mask, dtype=bool)
        if region.shape != (h, w):
            raise ValueError(f"mask shape {region.shape} differs from depth shape {(h, w)}")
    if not region.any():
        return []
    rng = np.random.default_rng(cfg.seed)

    # --- 1. candidate centres on the medial axis -------------------------------------------
    dist = ndimage.distance_transform_edt(region)  # [H, W]
    pix = np.argwhere(region)  # [P, 2] (row, col)
    weights = dist[region].astype(np.float64) ** 2
    n = min(cfg.n_centres, len(pix))
    pick = rng.choice(len(pix), size=n, replace=False, p=weights / weights.sum())
    innermost = np.unravel_index(int(np.argmax(dist)), dist.shape)
    centres = np.vstack([np.array(innermost, dtype=np.intp)[None], pix[pick]])  # [Nc, 2]

    z_ref = float(np.median(d[region]))
    px_per_m = 0.5 * (intrinsics.fx + intrinsics.fy) / z_ref
    window = max(int(cfg.max_opening_m / 2 * px_per_m), 3)

    # --- 2. angles ---------------------------------------------------------------------------
    axis = _local_axis_angles(region, centres, window)  # [Nc]
    offsets = np.deg2rad(np.asarray(cfg.angle_offsets_deg))
    sweep = np.deg2rad(np.arange(0.0, 180.0, cfg.sweep_step_deg))
    ang_local = axis[:, None] + math.pi / 2 + offsets[None, :]  # [Nc, A1]
    ang_sweep = np.broadcast_to(sweep[None, :], (len(centres), len(sweep)))  # [Nc, A2]
    angles = np.concatenate([ang_local, ang_sweep], axis=1)  # [Nc, A]
    n_ang = angles.shape[1]
    cx = np.repeat(centres[:, 1].astype(np.float64), n_ang)  # [N]
    cy = np.repeat(centres[:, 0].astype(np.float64), n_ang)  # [N]
    ang = angles.ravel()  # [N]
    ux, uy = np.cos(ang), -np.sin(ang)  # closing axis, image (x, y)
    px_, py_ = -uy, ux  # across the axis (finger pad direction)

    # metres per pixel step along the axis, at the centre's depth
    zc = d[centres[:, 0], centres[:, 1]].astype(np.float64).repeat(n_ang)  # [N]
    mpp = zc * np.hypot(ux / intrinsics.fx, uy / intrinsics.fy)  # [N]
    mpp_across = zc * np.hypot(px_ / intrinsics.fx, py_ / intrinsics.fy)  # [N]

    # --- 3. march along three lines across the pad ------------------------------------------
    k = int(math.ceil(cfg.max_opening_m / float(mpp.min()) / cfg.step_px)) + 1
    t = np.arange(k) * cfg.step_px  # [K] pixels
    pad_half_px = cfg.finger_width_m / 2 / mpp_across  # [N]
    lines = np.array([-1.0, 0.0, 1.0])  # [L] in units of the half pad
    off = lines[None, :] * pad_half_px[:, None]  # [N, L]
    sides = np.array([1.0, -1.0])  # [S]
    # sample positions [N, L, S, K]
    xs = (
        cx[:, None, None, None]
        + off[:, :, None, None] * px_[:, None, None, None]
        + sides[None, None, :, None] * t[None, None, None, :] * ux[:, None, None, None]
    )
    ys = (
        cy[:, None, None, None]
        + off[:, :, None, None] * py_[:, None, None, None]
        + sides[None, None, :, None] * t[None, None, None, :] * uy[:, None, None, None]
    )
    on_obj = _lookup(region, xs, ys, 0.0) > 0.5  # [N, L, S, K]
    # the centre line must start on the object; offset lines may start off it (tapering ends)
    exits = _first_exit(on_obj).astype(np.float64) * cfg.step_px  # [N, L, S] pixels
    edge = exits.max(axis=1)  # [N, S] the widest line touches first
    found = (_first_exit(on_obj) < k).all(axis=(1, 2))  # [N] object ends within reach
    span_px = edge.sum(axis=1)  # [N]
    span_m = span_px * mpp
    fits = found & (span_m <= cfg.max_opening_m - 2 * cfg.min_clearance_m)

    # object top along the centre line
    d_centre = _lookup(d, xs[:, 1], ys[:, 1], np.inf)  # [N, S, K]
    inside_run = t[None, None, :] < exits[:, 1, :, None]  # [N, S, K]
    z_top = np.where(inside_run, d_centre, np.inf).min(axis=(1, 2))  # [N]
    z_top = np.where(np.isfinite(z_top), z_top, zc)

    # recentre on the span
    shift = (edge[:, 0] - edge[:, 1]) / 2.0  # [N] along +axis
    gx, gy = cx + shift * ux, cy + shift * uy  # [N]
    opening_m = np.minimum(cfg.max_opening_m, span_m + 2 * cfg.preferred_clearance_m)  # [N]

    # --- 4a. free space for the fingers -----------------------------------------------------
    m = 8
    frac = np.linspace(0.0, 1.0, m)  # [M]
    start = span_px / 2.0 + 1.0  # [N] just beyond the contact
    stop = opening_m / 2.0 / mpp + cfg.finger_thickness_m / mpp  # [N]
    tz = start[:, None] + frac[None, :] * np.maximum(stop - start, 0.0)[:, None]  # [N, M]
    vz = np.linspace(-1.0, 1.0, 5)[None, :] * pad_half_px[:, None]  # [N, V]
    zx = (
        gx[:, None, None, None]
        + sides[None, :, None, None] * tz[:, None, :, None] * ux[:, None, None, None]
        + vz[:, None, None, :] * px_[:, None, None, None]
    )  # [N, S, M, V]
    zy = (
        gy[:, None, None, None]
        + sides[None, :, None, None] * tz[:, None, :, None] * uy[:, None, None, None]
        + vz[:, None, None, :] * py_[:, None, None, None]
    )
    zone_obj = _lookup(region, zx, zy, 1.0) > 0.5  # outside the image counts as blocked
    zone_depth = _lookup(d, zx, zy, 0.0)
    free = ~zone_obj & (zone_depth >= z_top[:, None, None, None] + cfg.min_drop_m)
    free_frac = free.mean(axis=(2, 3)).min(axis=1)  # [N] worst side
    clear = free_frac >= cfg.min_free_fraction

    # --- 4b. antipodal normals at the centre-line contacts ----------------------------------
    smooth = ndimage.gaussian_filter(region.astype(np.float64), 1.5)
    gy_img, gx_img = np.gradient(smooth)
    cos_sides = []
    for s_idx, sgn in enumerate((1.0, -1.0)):
        ex = cx + sgn * exits[:, 1, s_idx] * ux
        ey = cy + sgn * exits[:, 1, s_idx] * uy
        nx = -_lookup(gx_img, ex, ey, 0.0)
        ny = -_lookup(gy_img, ex, ey, 0.0)
        norm = np.hypot(nx, ny)
        cos_sides.append(
            np.where(norm > 1e-9, (nx * sgn * ux + ny * sgn * uy) / np.maximum(norm, 1e-12), 0.0)
        )
    cos_a = np.minimum(cos_sides[0], cos_sides[1])  # [N]
    cos_cone = math.cos(math.atan(cfg.friction_coef))
    antipodal = cos_a >= cos_cone

    centre_on = _lookup(region, gx, gy, 0.0) > 0.5  # recentring must stay on the region
    ok = fits & clear & antipodal & centre_on
    if not ok.any():
        return []

    # --- 5. score ----------------------------------------------------------------------------
    s_normal = 0.5 + 0.5 * (cos_a - cos_cone) / (1.0 - cos_cone)
    s_span = 1.0 - 0.5 * span_m / (cfg.max_opening_m - 2 * cfg.min_clearance_m)
    ys_r, xs_r = np.nonzero(region)
    cov = np.cov(np.stack([xs_r, ys_r]).astype(np.float64)) if xs_r.size > 2 else np.eye(2)
    sigma = math.sqrt(max(float(np.linalg.eigvalsh(cov).max()), 1.0))
    dc = np.hypot(gx - xs_r.mean(), gy - ys_r.mean())
    s_centre = 0.5 + 0.5 * np.exp(-0.5 * (dc / sigma) ** 2)
    quality = np.clip(s_normal * free_frac * s_span * s_centre, 1e-3, 1.0)

    # --- non-maximum suppression -------------------------------------------------------------
    order = [int(i) for i in np.argsort(-np.where(ok, quality, -1.0), kind="stable") if ok[i]]
    sep_px = cfg.min_separation_m * px_per_m
    grasps: list[Grasp2D] = []
    for i in order:
        if any(math.hypot(gx[i] - g.center_xy[0], gy[i] - g.center_xy[1]) < sep_px for g in grasps):
            continue
        grasps.append(
            Grasp2D(
                center_xy=(float(gx[i]), float(gy[i])),
                angle_rad=wrap_half_pi(float(ang[i])),
                width_px=float(opening_m[i] / mpp[i]),
                length_px=float(2 * pad_half_px[i]),
                quality=float(quality[i]),
            )
        )
        if len(grasps) >= max_grasps:
            break
    return grasps
