"""The shared finger-check work (``fingers.SurfacePoints``) gives the same answers, to the bit.

Why: the robot path's ``finger_checks`` stage ran ``finger_check`` once per refinement candidate
(up to ~20 per network grasp), each gathering the ROI's points relative to the grasp centre again
through a slow two-wide strided array, and then checked every grasp of the expanded list a second
time. Refinement returns the first candidate the fingers fit around, so one flipped borderline
comparison would pick another grasp (or none): the grasps, their order and every ``(ok, why)``
must stay exactly as before. The references below are the replaced implementations, run on seeded
random surfaces (boxes, cups, rings, noise, depth-pixel grids with points exactly on the strip's
edges) and grasps.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator

import numpy as np
import numpy.typing as npt
import pytest

from craft_e.runtime.grasp.geometry import (
    CameraIntrinsics,
    Grasp2D,
    TopDownGrasp,
    pose_to_rect,
    wrap_half_pi,
)
from craft_e.runtime.perception.observation import Observation
from craft_e.runtime.sim.candidates import (
    GraspCandidate,
    fitting_with_refinements,
    tip_height,
    with_refinements,
)
from craft_e.runtime.sim.episode import PickConfig
from craft_e.runtime.sim.fingers import FingerGeometry, SurfacePoints, finger_check
from craft_e.runtime.sim.pipeline import PipelineConfig
from craft_e.runtime.sim.refine import RefineConfig, candidates, refine, turns, wall_runs

FloatArray = npt.NDArray[np.float64]
TipZ = Callable[[TopDownGrasp], float]
PICK = PickConfig()


def _reference_finger_check(
    material: FloatArray, pose: TopDownGrasp, tip_z: float, fingers: FingerGeometry
) -> tuple[bool, str]:
    axis = np.array([np.cos(pose.yaw), np.sin(pose.yaw)])
    normal = np.array([-axis[1], axis[0]])
    rel = material[:, :2] - np.asarray(pose.position[:2], dtype=np.float64)
    squeezed = (np.abs(rel @ normal) <= fingers.pad_half_width) & (
        material[:, 2] > tip_z + fingers.height_tolerance)
    along = np.sort(rel[squeezed] @ axis)
    if along.size < fingers.min_points:
        return False, "no object surface between the fingers at their height"
    breaks = np.nonzero(np.diff(along) > fingers.thickness)[0]
    lows = along[np.concatenate([[0], breaks + 1])]
    highs = along[np.concatenate([breaks, [len(along) - 1]])]
    between = (highs > -fingers.half_opening) & (lows < fingers.half_opening)
    if not np.any(between):
        return False, "no object surface between the fingers at their height"
    span = float(highs[between].max() - lows[between].min())
    if span > fingers.max_span:
        return False, (f"object section {span * 100:.1f} cm does not fit the "
                       f"{fingers.max_span * 100:.1f} cm opening")
    return True, ""


def _reference_wall_runs(
    material: FloatArray, centre_xy: FloatArray, yaw: float, tip_z_of: TipZ, fingers: FingerGeometry,
) -> list[tuple[float, float, float]]:
    axis = np.array([math.cos(yaw), math.sin(yaw)])
    normal = np.array([-axis[1], axis[0]])
    rel = material[:, :2] - centre_xy
    in_strip = np.abs(rel @ normal) <= fingers.pad_half_width
    if np.count_nonzero(in_strip) < fingers.min_points:
        return []
    crest = float(material[in_strip, 2].max())
    tip_z = tip_z_of(TopDownGrasp(position=np.array([centre_xy[0], centre_xy[1], crest]), yaw=yaw, width_m=0.0))
    strip = in_strip & (material[:, 2] > tip_z + fingers.height_tolerance)
    along = rel[strip] @ axis
    if along.size < fingers.min_points:
        return []
    order = np.argsort(along, kind="stable")
    along, heights = along[order], material[strip][order, 2]
    breaks = np.nonzero(np.diff(along) > fingers.thickness)[0]
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks + 1, [along.size]])
    return [(float(along[s]), float(along[e - 1]), float(heights[s:e].max()))
            for s, e in zip(starts, ends, strict=True) if e - s >= fingers.min_points]


def _reference_candidates(
    pose: TopDownGrasp, material: FloatArray, tip_z_of: TipZ, fingers: FingerGeometry, cfg: RefineConfig,
) -> Iterator[TopDownGrasp]:
    centre = np.asarray(pose.position, dtype=np.float64)
    offsets = turns(cfg)
    for delta in offsets[1:]:
        yield TopDownGrasp(position=centre.copy(), yaw=wrap_half_pi(pose.yaw + delta), width_m=pose.width_m)
    for delta in offsets:
        yaw = wrap_half_pi(pose.yaw + delta)
        axis = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        runs = _reference_wall_runs(material, centre[:2], yaw, tip_z_of, fingers)
        for low, high, top in sorted(runs, key=lambda r: abs(r[0] + r[1])):
            mid = (low + high) / 2
            if not 0 < abs(mid) <= cfg.max_shift or high - low > fingers.max_span:
                continue
            moved = centre + mid * axis
            moved[2] = top
            yield TopDownGrasp(position=moved, yaw=yaw, width_m=pose.width_m)


def _reference_refine(
    pose: TopDownGrasp, material: FloatArray, tip_z_of: TipZ, fingers: FingerGeometry, cfg: RefineConfig,
) -> TopDownGrasp | None:
    if not cfg.enabled:
        return None
    for c in _reference_candidates(pose, material, tip_z_of, fingers, cfg):
        if _reference_finger_check(material, c, tip_z_of(c), fingers)[0]:
            return c
    return None


def _reference_with_refinements(candidates: list[GraspCandidate], material: FloatArray, obs: Observation,
                                table_z: float, config: PipelineConfig) -> list[GraspCandidate]:
    if not (config.refine.enabled and config.fit_filter):
        return list(candidates)

    def tip_z_of(pose: TopDownGrasp) -> float:
        return tip_height(pose, config.pick, table_z)

    out: list[GraspCandidate] = []
    for c in candidates:
        out.append(c)
        if c.pose is None or _reference_finger_check(material, c.pose, tip_z_of(c.pose), config.fingers)[0]:
            continue
        better = _reference_refine(c.pose, material, tip_z_of, config.fingers, config.refine)
        if better is None:
            continue
        try:
            rect = pose_to_rect(better, obs.intrinsics, obs.cam_to_world, quality=c.quality,
                                length_px=c.rect.length_px)
        except ValueError:
            continue
        out.append(GraspCandidate(rect, better))
    return out


def _reference_fitting(candidates: list[GraspCandidate], material: FloatArray, obs: Observation,
                       table_z: float, config: PipelineConfig) -> list[GraspCandidate]:
    """The robot path's old list: ``with_refinements``, then every grasp checked again."""
    return [c for c in _reference_with_refinements(candidates, material, obs, table_z, config)
            if c.pose is not None and (not config.fit_filter or _reference_finger_check(
                material, c.pose, tip_height(c.pose, config.pick, table_z), config.fingers)[0])]


def _same_grasp(a: TopDownGrasp | None, b: TopDownGrasp | None) -> bool:
    if a is None or b is None:
        return a is b
    pa, pb = np.asarray(a.position), np.asarray(b.position)
    return (pa.dtype == pb.dtype and pa.tobytes() == pb.tobytes() and a.width_m == b.width_m
            and np.float64(a.yaw).tobytes() == np.float64(b.yaw).tobytes())


# ---------------------------------------------------------------- random surfaces and grasps

def _pixel_grid(rng: np.random.Generator, half: float) -> FloatArray:
    """``[n, 2]`` a depth-pixel-like grid (2 mm, sometimes 1.5 mm): many points lie exactly
    on the pad strip's edge of an axis-aligned grasp, and many share a coordinate."""
    step = float(rng.choice([0.002, 0.0015, 0.001]))
    xs = np.arange(-half, half + 1e-9, step)
    gx, gy = np.meshgrid(xs, xs)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def _box(rng: np.random.Generator) -> FloatArray:
    long_m, short_m = rng.uniform(0.02, 0.16), rng.uniform(0.01, 0.1)
    xy = _pixel_grid(rng, max(long_m, short_m) / 2 + 0.01)
    turn = rng.uniform(-math.pi, math.pi) if rng.random() < 0.5 else 0.0
    c, s = math.cos(turn), math.sin(turn)
    local = xy @ np.array([[c, -s], [s, c]])
    keep = (np.abs(local[:, 0]) <= long_m / 2) & (np.abs(local[:, 1]) <= short_m / 2)
    return np.column_stack([xy[keep], np.full(int(keep.sum()), rng.uniform(0.01, 0.12))])


def _cup(rng: np.random.Generator) -> FloatArray:
    outer = rng.uniform(0.02, 0.07)
    wall = rng.uniform(0.002, 0.012)
    xy = _pixel_grid(rng, outer)
    r = np.hypot(xy[:, 0], xy[:, 1])
    xy, r = xy[r <= outer], r[r <= outer]
    rim, floor = rng.uniform(0.04, 0.14), rng.uniform(0.002, 0.03)
    z = np.where(r >= outer - wall, rim, floor)
    if rng.random() < 0.3:  # a ring: no floor seen at all
        xy, z = xy[r >= outer - wall], z[r >= outer - wall]
    return np.column_stack([xy, z])


def _noise(rng: np.random.Generator) -> FloatArray:
    n = int(rng.integers(0, 40))
    return np.column_stack([rng.uniform(-0.08, 0.08, (n, 2)), rng.uniform(0.0, 0.15, n)])


def _surface(rng: np.random.Generator) -> FloatArray:
    """One ROI's points: one to three shapes, shifted apart, some noisy, plus stray pixels."""
    parts = []
    for _ in range(int(rng.integers(1, 4))):
        shape = _box(rng) if rng.random() < 0.5 else _cup(rng)
        shape[:, :2] += rng.uniform(-0.06, 0.06, 2)
        if rng.random() < 0.5:
            shape = shape + rng.normal(0.0, float(rng.choice([1e-4, 1e-3])), shape.shape)
        parts.append(shape)
    parts.append(_noise(rng))
    material = np.concatenate(parts)
    return material[rng.permutation(len(material))] if rng.random() < 0.5 else material


def _grasp(rng: np.random.Generator, material: FloatArray) -> TopDownGrasp:
    """A grasp on a surface point (as a network's), on an exact grid value, or anywhere near."""
    roll = rng.random()
    if roll < 0.5 and len(material):
        x, y, z = (float(v) for v in material[int(rng.integers(len(material)))])
    elif roll < 0.75:
        x, y = (float(v) for v in rng.choice([0.0, -0.0, 0.01, -0.02, 0.004], 2))
        z = float(rng.uniform(0.0, 0.12))
    else:
        x, y, z = (float(v) for v in rng.uniform([-0.08, -0.08, 0.0], [0.08, 0.08, 0.12]))
    yaw = float(rng.choice([0.0, math.pi / 2, -math.pi / 4])) if rng.random() < 0.3 else float(
        rng.uniform(-math.pi / 2, math.pi / 2))
    return TopDownGrasp(position=np.array([x, y, z]), yaw=yaw, width_m=float(rng.uniform(0.01, 0.08)))


def _fingers(rng: np.random.Generator) -> FingerGeometry:
    """Random hands without the landing rule, which came after the replaced code (its own tests:
    tests/test_finger_landing.py)."""
    if rng.random() < 0.5:
        return FingerGeometry(check_landing=False)
    return FingerGeometry(check_landing=False, half_opening=float(rng.choice([0.03, 0.04, 0.05])),
                          thickness=float(rng.choice([0.004, 0.012, 0.02])),
                          pad_half_width=float(rng.choice([0.01, 0.004, 0.006])),
                          min_points=int(rng.choice([1, 2, 4, 8])))


def _refine_config(rng: np.random.Generator) -> RefineConfig:
    if rng.random() < 0.5:
        return RefineConfig()
    return RefineConfig(yaw_step_deg=float(rng.choice([15.0, 30.0, 45.0])),
                        max_shift=float(rng.choice([0.0, 0.02, 0.05, 0.1])))


def _tip_z_of(rng: np.random.Generator) -> TipZ:
    table_z = float(rng.choice([0.0, 0.0, -0.01, 0.02]))
    pick = dataclasses.replace(PICK, insertion_depth=float(rng.choice([PICK.insertion_depth, 0.0, 0.05])))
    return lambda pose: tip_height(pose, pick, table_z)


CASES = 150


@pytest.mark.parametrize("seed", range(CASES))
def test_refine_and_its_checks_equal_the_replaced_loop(seed: int) -> None:
    rng = np.random.default_rng(seed)
    material = _surface(rng)
    fingers, cfg, tip_z_of = _fingers(rng), _refine_config(rng), _tip_z_of(rng)
    surface = SurfacePoints(material)  # shared by every grasp of this ROI, as the pipeline does
    for _ in range(4):
        pose = _grasp(rng, material)
        tip_z = tip_z_of(pose)
        assert finger_check(surface, pose, tip_z, fingers) == _reference_finger_check(material, pose, tip_z, fingers)
        assert finger_check(material, pose, tip_z, fingers) == _reference_finger_check(material, pose, tip_z, fingers)
        got = list(candidates(pose, surface, tip_z_of, fingers, cfg))
        want = list(_reference_candidates(pose, material, tip_z_of, fingers, cfg))
        assert len(got) == len(want) and all(_same_grasp(g, w) for g, w in zip(got, want, strict=True))
        for c in want:
            assert finger_check(surface, c, tip_z_of(c), fingers) == _reference_finger_check(
                material, c, tip_z_of(c), fingers)
        assert _same_grasp(refine(pose, surface, tip_z_of, fingers, cfg),
                           _reference_refine(pose, material, tip_z_of, fingers, cfg))
        centre = np.asarray(pose.position[:2], dtype=np.float64)
        assert wall_runs(surface, centre, pose.yaw, tip_z_of, fingers) == _reference_wall_runs(
            material, centre, pose.yaw, tip_z_of, fingers)


def test_the_random_cases_reach_every_outcome() -> None:
    """The equivalence above means something only if its cases refine by turns and by walls,
    and fail, both ways a check can fail."""
    turned = walled = failed = 0
    reasons: set[str] = set()
    for seed in range(CASES):
        rng = np.random.default_rng(seed)
        material = _surface(rng)
        fingers, cfg, tip_z_of = _fingers(rng), _refine_config(rng), _tip_z_of(rng)
        for _ in range(4):
            pose = _grasp(rng, material)
            reasons.add(_reference_finger_check(material, pose, tip_z_of(pose), fingers)[1].split(" ")[0])
            better = _reference_refine(pose, material, tip_z_of, fingers, cfg)
            if better is None:
                failed += 1
            elif np.array_equal(better.position, pose.position):
                turned += 1
            else:
                walled += 1
    assert min(turned, walled, failed) >= 20, (turned, walled, failed)
    assert reasons == {"", "no", "object"}


def _observation() -> Observation:
    intr = CameraIntrinsics.realsense_d435()  # a camera 0.7 m straight above; only its model is used
    cam_to_world = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, 0.7], [0, 0, 0, 1.0]])
    return Observation(np.zeros((intr.height, intr.width, 3), np.uint8),
                       np.full((intr.height, intr.width), 0.7, np.float32), intr, cam_to_world)


@pytest.mark.parametrize("settings", [{}, {"fit_filter": False}, {"refine": RefineConfig(enabled=False)}])
def test_the_robots_list_equals_the_old_double_check(settings: dict[str, object]) -> None:
    """``fitting_with_refinements`` checks each grasp once; the old path checked the expanded
    list again. Same grasps (the same objects), same order, under every switch."""
    obs = _observation()
    config = dataclasses.replace(PipelineConfig(fingers=FingerGeometry(check_landing=False)), **settings)
    for seed in range(40):
        rng = np.random.default_rng(1000 + seed)
        material = _surface(rng)
        raw = []
        for q in sorted(rng.uniform(0.1, 1.0, int(rng.integers(1, 6))), reverse=True):
            rect = Grasp2D(center_xy=(320.0, 240.0), angle_rad=0.0, width_px=40.0, length_px=20.0, quality=float(q))
            raw.append(GraspCandidate(rect, None if rng.random() < 0.1 else _grasp(rng, material)))
        _assert_same_list(fitting_with_refinements(raw, material, obs, 0.0, config),
                          _reference_fitting(raw, material, obs, 0.0, config), raw)
        _assert_same_list(with_refinements(raw, material, obs, 0.0, config),
                          _reference_with_refinements(raw, material, obs, 0.0, config), raw)


def _assert_same_list(got: list[GraspCandidate], want: list[GraspCandidate], raw: list[GraspCandidate]) -> None:
    """The network's grasps as the same objects, refinements as new ones with the same pose."""
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        if any(w is c for c in raw):
            assert g is w
        else:
            assert all(g is not c for c in raw) and _same_grasp(g.pose, w.pose) and g.rect == w.rect
