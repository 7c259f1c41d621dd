"""``craft eval static``: the paper's static table on rendered testbed scenes (no execution).

Scenes are the ones ``craft eval sim`` builds (same labels, pairs, layouts and seeds), rendered
once and never executed. Three settings, as in the paper's static table:

* ``gt/gt`` — *Perfect Grasp & Detect*: ground-truth ROIs (the simulator's masks) with
  ground-truth grasps;
* ``gt/predicted`` — *Perfect Grasp*: predicted ROIs (RGB-D segmentation), each with the
  ground-truth grasps of the object it covers most whose centre lies on the ROI;
* ``<backend>/predicted`` — *Full Pipeline*: predicted ROIs with a grasp backend's predictions
  (one row per ``--grasp``).

Success = the chosen ROI's box has IoU >= 0.5 with the target's ground-truth box AND the chosen
grasp is within 30° and Jaccard > 0.25 of a ground-truth rectangle of the target (the Cornell
criterion, ``grasp.metrics.grasp_success``).

Ground-truth grasp rectangles (``gt_grasp_rects``) play the role of Cornell's annotations: the
oracle's rule (a finger-pad-wide section of the object's top surface across the closing axis that
fits the opening and has parallel sides) applied at every 1 cm along the long axis, across the
narrow axis; for round footprints (narrow extent >= 75% of the long one) at every 15° of closing
direction. Each is projected into the image with ``pose_to_rect``; its opening is the section plus
1 cm of finger clearance per side (capped at the gripper's opening), its jaw size half of that, as
the networks' rectangles have. Only if no parallel-sided section exists are the first fitting
sections used (the oracle's fallback), and if even those are too wide (a bowl, a plate), the radial
grasps across its rim (``sim.oracle.rim_grasps``), as a person would take it.

Noise (``--noise grasp=0.1,box=0.2``): per level, grasp scores get ``perturb_grasp_scores`` and
ROI boxes ``jitter_box`` from ``evaluation/robustness.py`` (the box the grounder crops and the
detection check scores; masks and grasps are those of the clean ROI). Each level is seeded by
(seed, level, episode, setting), so every method sees the same perturbation.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from ...files import sha256_file
from ..grasp.geometry import Grasp2D, TopDownGrasp, pose_to_rect
from ..grounding.settings import GroundingSettings
from ..perception.roi import ROI
from ..sim.env import EnvConfig
from ..sim.oracle import OracleConfig, rim_grasps, top_surface_points
from ..sim.scene import Scene
from .common import MethodResult, SkippedMethod
from .methods import MethodSpec, build_grounders, load_methods, select_methods
from .sim_eval import (
    EpisodeSpec,
    default_encoder,
    load_sim_labels,
    make_episode_specs,
    text_space,
)

if TYPE_CHECKING:
    from ..encoders.image import ImageEncoder
    from ..grounding.grounder import Grounder, Grounding
    from ..perception.observation import Observation

BoolMask = npt.NDArray[np.bool_]
Embedding = npt.NDArray[np.float32]
RGBImage = npt.NDArray[np.uint8]

DETECT_IOU = 0.5
GRASP_BACKENDS = ("grconvnet", "ggcnn", "ggcnn2", "antipodal")
COLUMNS = (("accuracy", "Accuracy"), ("detect", "Detect"), ("grasp", "Grasp"))  # grasp: target_grasp_ok
_PAPER_NAMES = {"gt/gt": "Perfect Grasp & Detect", "gt/predicted": "Perfect Grasp"}


# ---------------------------------------------------------------------------------------------
# ground-truth grasp rectangles


@dataclass(frozen=True)
class GTGraspConfig:
    """How ground-truth rectangles are generated (see the module docstring)."""

    oracle: OracleConfig = field(default_factory=OracleConfig)
    round_ratio: float = 0.75  # narrow / long extent above which every direction is tried
    yaw_step_deg: float = 15.0
    finger_clearance: float = 0.01  # m per side added to the section in the rectangle


def gt_grasp_poses(scene: Scene, body: int, config: GTGraspConfig | None = None) -> list[TopDownGrasp]:
    """Every top-down grasp of ``body`` the oracle's section rule accepts (see module docstring).

    ``width_m`` is the object's section, not the opening.
    """
    from ..sim.oracle import grasp_at  # the oracle's own rule, shared on purpose

    cfg = config or GTGraspConfig()
    o = cfg.oracle
    points = top_surface_points(scene, body, o.ray_spacing)
    if len(points) < 3:
        return []
    xy = points[:, :2]
    centroid = xy.mean(axis=0)
    _, _, vt = np.linalg.svd(xy - centroid, full_matrices=False)
    long_extent = float(np.ptp((xy - centroid) @ vt[0]))
    narrow_extent = float(np.ptp((xy - centroid) @ vt[1]))
    base = math.atan2(float(vt[1][1]), float(vt[1][0]))
    if narrow_extent >= cfg.round_ratio * long_extent:
        steps = round(180.0 / cfg.yaw_step_deg)
        yaws = [base + math.radians(k * cfg.yaw_step_deg) for k in range(steps)]
    else:
        yaws = [base]
    for parallel in (True, False):
        poses: list[TopDownGrasp] = []
        for yaw in yaws:
            closing = np.array([math.cos(yaw), math.sin(yaw)])
            along_axis = np.array([-closing[1], closing[0]])
            along = (xy - centroid) @ along_axis
            offsets = np.arange(0.0, float(np.abs(along).max()), o.slide_step)
            for offset in sorted(np.concatenate([offsets, -offsets[1:]]).tolist(), key=abs):
                grasp = grasp_at(points, centroid, along_axis, closing, yaw, float(offset), o, parallel)
                if grasp is not None:
                    poses.append(grasp)
        if poses:
            return poses
    return rim_grasps(points, o, scene.layout.table_z)  # too wide everywhere: by the rim, if any


def gt_grasp_rects(
    scene: Scene, obs: Observation, body: int, config: GTGraspConfig | None = None
) -> list[Grasp2D]:
    """``gt_grasp_poses`` as image rectangles (quality 1), opening = section + finger clearance."""
    cfg = config or GTGraspConfig()
    rects: list[Grasp2D] = []
    for pose in gt_grasp_poses(scene, body, cfg):
        opening = min(pose.width_m + 2 * cfg.finger_clearance, cfg.oracle.max_width)
        rects.append(pose_to_rect(TopDownGrasp(pose.position, pose.yaw, opening),
                                  obs.intrinsics, obs.cam_to_world, quality=1.0))
    return rects


def rect_centre_on(rect: Grasp2D, mask: BoolMask) -> bool:
    """Whether the rectangle's centre pixel lies on ``mask``."""
    h, w = mask.shape
    col = min(max(round(rect.center_xy[0]), 0), w - 1)
    row = min(max(round(rect.center_xy[1]), 0), h - 1)
    return bool(mask[row, col])


# ---------------------------------------------------------------------------------------------
# noise


@dataclass(frozen=True)
class NoiseLevel:
    """Grasp-score noise (sigma, score units) and ROI box jitter (fraction of area cut)."""

    grasp_sigma: float = 0.0
    box_frac: float = 0.0

    @property
    def clean(self) -> bool:
        return self.grasp_sigma == 0.0 and self.box_frac == 0.0

    @property
    def label(self) -> str:
        if self.clean:
            return "clean"
        parts = ([f"grasp={self.grasp_sigma:g}"] if self.grasp_sigma else []) + (
            [f"box={self.box_frac:g}"] if self.box_frac else [])
        return ",".join(parts)


def parse_noise(spec: str) -> NoiseLevel:
    """``"grasp=0.1"``, ``"box=0.2"`` or ``"grasp=0.1,box=0.2"`` → a level; errors say why."""
    values = {"grasp": 0.0, "box": 0.0}
    for part in spec.split(","):
        key, sep, raw = part.strip().partition("=")
        if not sep or key not in values:
            raise ValueError(f"--noise {spec!r}: expected grasp=SIGMA and/or box=FRACTION, comma-separated")
        try:
            values[key] = float(raw)
        except ValueError:
            raise ValueError(f"--noise {spec!r}: {raw!r} is not a number") from None
    if not 0 <= values["grasp"] < float("inf") or not 0 <= values["box"] < 1:  # NaN fails both
        raise ValueError(f"--noise {spec!r}: grasp sigma must be finite and >= 0, box fraction in [0, 1)")
    return NoiseLevel(values["grasp"], values["box"])


def _robustness() -> Any:
    """``evaluation.robustness`` (grasp-score noise, box jitter), imported only when noise is asked."""
    try:
        from . import robustness
    except ImportError as exc:  # pragma: no cover - depends on the tree
        raise RuntimeError("--noise needs craft_e.runtime.evaluation.robustness "
                           f"(perturb_grasp_scores, jitter_box), which is not available: {exc}") from exc
    missing = [n for n in ("perturb_grasp_scores", "jitter_box", "noise_rng") if not hasattr(robustness, n)]
    if missing:
        raise RuntimeError(f"--noise: evaluation/robustness.py lacks {', '.join(missing)}")
    return robustness


# ---------------------------------------------------------------------------------------------
# one rendered scene


@dataclass(frozen=True)
class StaticROI:
    """An ROI as the static benchmark sees it: box, grasp rectangles, embedding."""

    box: tuple[float, float, float, float]
    mask: BoolMask
    grasps: tuple[Grasp2D, ...]
    embedding: Embedding
    extents_m: tuple[float, float, float] | None = None  # from depth, for the size cue
    colours: tuple[float, ...] | None = None  # colour shares of its raised pixels, for the colour cue
    classes: tuple[tuple[int, float], ...] | None = None  # top ImageNet classes, for the look-alike cue
    cavity_m: float | None = None  # how far its inside lies below its rim, for the cavity cue


@dataclass(frozen=True)
class StaticScene:
    """One rendered scene: every setting's ROIs, the target's box and its GT rectangles."""

    spec: EpisodeSpec
    rgb: RGBImage
    target_box: tuple[int, int, int, int] | None
    target_rects: tuple[Grasp2D, ...]
    settings: dict[str, list[StaticROI]]


def setting_ids(backends: Sequence[str]) -> list[str]:
    return ["gt/gt", "gt/predicted", *(f"{b}/predicted" for b in backends)]


def render_scene(
    spec: EpisodeSpec, backends: Sequence[str], encoder: ImageEncoder, env_config: EnvConfig,
    gt_config: GTGraspConfig | None = None, torch_threads_n: int = 1, rgb_scale: int = 2,
) -> StaticScene:
    """Build and render ``spec`` (no execution) and prepare the ROIs of every setting."""
    from ..encoders.conse import encode_with_classes
    from ..encoders.image import crop_box
    from ..grasp.predict import predict_grasps_rois
    from ..perception.cavity import measure_cavity
    from ..perception.colours import measure_colours
    from ..perception.extents import measure_extents
    from ..perception.segment import segment
    from ..sim.env import SimEnv
    from ..sim.fingers import FingerGeometry
    from ..sim.oracle import gt_rois
    from ..sim.perceive import majority_body, raised_mask, raster_order, torch_threads

    with SimEnv(env_config) as env:
        scene = env.reset(spec.scene)
        obs = env.capture()
        sharp = env.capture_rgb(rgb_scale)  # crops for the encoder, as in sim.perceive
        truth = raster_order(gt_rois(obs, scene))
        bodies = [o.body_id for o in scene.objects]
        rects = {b: gt_grasp_rects(scene, obs, b, gt_config) for b in {r.label for r in truth}
                 if b is not None}
    target_body = scene.target.body_id
    target = next((r for r in truth if r.label == target_body), None)
    predicted = segment(obs).rois
    owners = [majority_body(obs, r.mask, bodies) for r in predicted]
    with torch_threads(torch_threads_n):
        boxes = [r.box_xywh for r in truth] + [r.box_xywh for r in predicted]
        emb, cls = encode_with_classes(encoder, [crop_box(sharp, tuple(v * rgb_scale for v in b))
                                                 for b in boxes])  # [N, d], N top-class lists
        # one network pass per scene, as the robot's pipeline (sim.candidates.raw_candidates)
        net = {b: [tuple(g) for g in predict_grasps_rois(b, obs.rgb, obs.depth, [r.mask for r in predicted],
                                                        intrinsics=obs.intrinsics)] for b in backends}
    gt_emb, pred_emb = emb[: len(truth)], emb[len(truth):]
    gt_cls, pred_cls = cls[: len(truth)], cls[len(truth):]
    world = obs.points_world()  # [H, W, 3]
    table_z = scene.layout.table_z
    raised = raised_mask(world, table_z, FingerGeometry().height_tolerance)
    gt_ext = [measure_extents(world[r.mask & raised], table_z) for r in truth]
    pred_ext = [measure_extents(world[r.mask & raised], table_z) for r in predicted]
    gt_col = [measure_colours(obs.rgb[r.mask & raised]) for r in truth]
    pred_col = [measure_colours(obs.rgb[r.mask & raised]) for r in predicted]
    height = world[..., 2] - table_z
    gt_cav = [measure_cavity(height, r.mask & raised) for r in truth]
    pred_cav = [measure_cavity(height, r.mask & raised) for r in predicted]

    def fbox(box: tuple[int, int, int, int]) -> tuple[float, float, float, float]:
        return (float(box[0]), float(box[1]), float(box[2]), float(box[3]))

    settings: dict[str, list[StaticROI]] = {
        "gt/gt": [StaticROI(fbox(r.box_xywh), r.mask, tuple(rects.get(r.label, [])) if r.label is not None
                            else (), gt_emb[i], gt_ext[i], gt_col[i], gt_cls[i], gt_cav[i])
                   for i, r in enumerate(truth)],
        "gt/predicted": [StaticROI(fbox(r.box_xywh), r.mask,
                                   tuple(g for g in rects.get(owner, []) if rect_centre_on(g, r.mask))
                                   if owner is not None else (), pred_emb[i], pred_ext[i], pred_col[i],
                                   pred_cls[i], pred_cav[i])
                         for i, (r, owner) in enumerate(zip(predicted, owners, strict=True))],
    }
    for b in backends:
        settings[f"{b}/predicted"] = [StaticROI(fbox(r.box_xywh), r.mask, net[b][i], pred_emb[i], pred_ext[i],
                                                pred_col[i], pred_cls[i], pred_cav[i])
                                      for i, r in enumerate(predicted)]
    return StaticScene(spec, obs.rgb, target.box_xywh if target is not None else None,
                       tuple(rects.get(target_body, [])), settings)


def _perturbed(
    rois: list[StaticROI], level: NoiseLevel, rng: np.random.Generator, rgb: RGBImage,
    encoder: ImageEncoder,
) -> list[StaticROI]:
    """The ROIs under a noise level (scores first, then boxes, in ROI order: reproducible)."""
    if level.clean:
        return rois
    from ..encoders.conse import encode_with_classes
    from ..encoders.image import crop_box

    rb = _robustness()
    h, w = rgb.shape[:2]
    out: list[StaticROI] = []
    for r in rois:
        scores = rb.perturb_grasp_scores([g.quality for g in r.grasps], level.grasp_sigma, rng)
        grasps = tuple(Grasp2D(g.center_xy, g.angle_rad, g.width_px, g.length_px, float(s))
                       for g, s in zip(r.grasps, scores, strict=True))
        box = r.box if level.box_frac == 0 else tuple(float(v) for v in rb.jitter_box(r.box, level.box_frac, rng, (w, h)))
        out.append(StaticROI(box, r.mask, grasps, r.embedding, r.extents_m, r.colours,  # type: ignore[arg-type]
                             r.classes, r.cavity_m))
    if level.box_frac:
        crops = [crop_box(rgb, r.box) for r in out]
        emb, cls = encode_with_classes(encoder, crops)
        out = [StaticROI(r.box, r.mask, r.grasps, emb[i], r.extents_m, r.colours, cls[i], r.cavity_m)
               for i, r in enumerate(out)]
    return out


def _box_iou(a: Sequence[float], b: Sequence[float]) -> float:
    """IoU of two (x, y, w, h) boxes with float coordinates (jittered boxes are not integers)."""
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = a[2] * a[3] + b[2] * b[3] - inter
    return inter / union if union > 0 else 0.0


def score_choice(scene: StaticScene, rois: list[StaticROI], grounding: Grounding) -> dict[str, Any]:
    """Detection and overall success of one grounding (see the module docstring)."""
    from ..grasp.metrics import grasp_success

    chosen = grounding.chosen
    if chosen is None or scene.target_box is None:
        return {"chosen_roi": None if chosen is None else chosen.index, "iou": 0.0, "detect": False,
                "success": False}
    iou = _box_iou(rois[chosen.index].box, scene.target_box)
    rect = chosen.grasp
    grasp_ok = bool(isinstance(rect, Grasp2D) and scene.target_rects
                    and grasp_success(rect, scene.target_rects))
    detect = iou >= DETECT_IOU
    return {"chosen_roi": chosen.index, "iou": round(iou, 6), "detect": detect,
            "success": detect and grasp_ok}


def target_grasp_ok(scene: StaticScene, rois: list[StaticROI]) -> bool:
    """Grounding aside: is the best-scoring grasp of the target's ROI (best IoU >= 0.5) correct?

    The grasp module's share of the static score, the same for every method.
    """
    from ..grasp.metrics import grasp_success

    if scene.target_box is None or not rois or not scene.target_rects:
        return False
    ious = [_box_iou(r.box, scene.target_box) for r in rois]
    best = max(range(len(rois)), key=lambda i: (ious[i], -i))
    grasps = rois[best].grasps
    if ious[best] < DETECT_IOU or not grasps:
        return False
    top = max(range(len(grasps)), key=lambda i: grasps[i].quality)  # the grounder's choice rule
    return grasp_success(grasps[top], scene.target_rects)


# ---------------------------------------------------------------------------------------------
# report


@dataclass
class StaticReport:
    """Per noise level and setting, one row per method; plus every episode's choices."""

    levels: dict[str, dict[str, list[MethodResult]]]  # level -> setting -> rows
    skipped: list[SkippedMethod]
    episodes: list[dict[str, Any]]
    config: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        def row(r: MethodResult) -> dict[str, Any]:
            return {**{k: round(v, 6) for k, v in r.metrics.items()}, "description": r.description,
                    "settings": r.settings}

        return {
            "benchmark": "static (rendered CR3 testbed scenes; the paper's static protocol)",
            "config": self.config,
            "levels": {lvl: {s: {"grasp": s.split("/")[0], "rois": s.split("/")[1],
                                 "methods": {r.name: row(r) for r in rows}}
                             for s, rows in settings.items()}
                       for lvl, settings in self.levels.items()},
            "skipped_methods": [{"method": s.name, "reason": s.reason} for s in self.skipped],
            "episodes": self.episodes,
        }

    def to_markdown(self) -> str:
        c = self.config
        out = [f"### Static evaluation on rendered testbed scenes — {c['episodes']} scenes "
               f"({c['pairs']} verb–target pairs × {c['layouts']} layouts, seed {c['seed']}, labels "
               f"`{Path(c['labels']).name}`)\n",
               "Accuracy: chosen ROI IoU ≥ 0.5 with the target AND chosen grasp within 30° / Jaccard > 0.25 "
               "of a ground-truth rectangle. Detect: the first condition alone. Grasp: the best-scoring "
               "grasp of the target's ROI is correct (the grasp module's share; the same for every "
               "method). Percent.\n"]
        for level, settings in self.levels.items():
            if len(self.levels) > 1:
                out.append(f"#### noise: {level}\n")
            out.append("| Setting | Grasp | ROI | Method | Accuracy | Detect | Grasp |")
            out.append("|---|---|---|---|---:|---:|---:|")
            for setting, rows in settings.items():
                grasp, rois = setting.split("/")
                name = _PAPER_NAMES.get(setting, "Full Pipeline")
                for r in rows:
                    cells = " | ".join(f"{100 * r.metrics[k]:.2f}" for k, _ in COLUMNS)
                    out.append(f"| {name} | {'GT' if grasp == 'gt' else grasp} | "
                               f"{'GT' if rois == 'gt' else 'predicted'} | {r.name} | {cells} |")
            for s in self.skipped:
                out.append(f"| – | – | – | {s.name} | skipped | skipped | skipped |")
            out.append("")
        if self.skipped:
            out += [f"- **{s.name}** skipped: {s.reason}" for s in self.skipped] + [""]
        return "\n".join(out) + "\n"


ProgressFn = Callable[[int, int, dict[str, Any]], None]


def evaluate_static(
    labels_path: Path,
    *,
    backends: Sequence[str] = ("grconvnet",),
    layouts: int = 3,
    seed: int = 0,
    methods: Sequence[MethodSpec] | None = None,
    max_pairs: int | None = None,
    noise: Sequence[NoiseLevel] = (),
    encoder: ImageEncoder | None = None,
    env_config: EnvConfig | None = None,
    gt_config: GTGraspConfig | None = None,
    threads: int = 1,
    settings: GroundingSettings | None = None,
    progress: ProgressFn | None = None,
    jobs: int = 1,
    classifier: str | None = None,
) -> StaticReport:
    """Render every scene once, then score every method in every setting and noise level.

    ``jobs`` > 1 renders and scores scenes in that many worker processes, with a report
    byte-identical to ``jobs=1`` (``evaluation.parallel``); ``encoder`` must then be None.
    ``classifier`` chooses the default encoder's ImageNet classifier (``sim_eval.default_encoder``)."""
    from functools import partial

    from .parallel import ordered_map
    from .sim_eval import worker_context

    bad = [b for b in backends if b not in GRASP_BACKENDS]
    if bad:
        raise ValueError(f"unknown grasp backend(s) {', '.join(bad)}; choose from {', '.join(GRASP_BACKENDS)}")
    levels = [NoiseLevel(), *(n for n in noise if not n.clean)]
    if len(levels) > 1:
        _robustness()  # fail before rendering anything
    env_cfg = env_config or EnvConfig()
    labels = load_sim_labels(labels_path)
    specs = make_episode_specs(labels, layouts=layouts, seed=seed, max_pairs=max_pairs,
                               env_config=env_cfg)
    settings = settings or GroundingSettings()
    runnable, skipped = load_methods(list(methods) if methods is not None else select_methods(),
                                     text_space(encoder))
    enc = encoder if encoder is not None else default_encoder(threads, classifier, settings.class_senses,
                                                              settings.conse_temperature)
    from ..sim.pipeline import sim_vocabulary

    grounders = build_grounders(runnable, settings, sim_vocabulary())
    setting_names = setting_ids(backends)
    episodes: list[dict[str, Any]] = []
    if jobs > 1 and encoder is not None:
        raise ValueError("jobs > 1 builds the default image encoder in every worker; pass encoder=None")
    run = partial(_static_record, backends, env_cfg, gt_config, threads, levels, setting_names, seed)
    build = partial(worker_context, [m for m, _ in runnable], threads, settings, classifier)
    for record in ordered_map(run, specs if grounders else [], jobs=jobs, build=build, context=(grounders, enc)):
        episodes.append(record)
        if progress is not None:
            progress(len(episodes), len(specs), record)
    rows: dict[str, dict[str, list[MethodResult]]] = {}
    for level in levels:
        rows[level.label] = {}
        for setting in setting_names:
            rows[level.label][setting] = []
            for spec_m, _ in runnable:
                cells = [e["levels"][level.label][setting] for e in episodes]
                outcomes = [c["methods"][spec_m.name] for c in cells]
                n = max(len(outcomes), 1)
                rows[level.label][setting].append(MethodResult(
                    name=spec_m.name, description=spec_m.description,
                    metrics={"accuracy": sum(o["success"] for o in outcomes) / n,
                             "detect": sum(o["detect"] for o in outcomes) / n,
                             "grasp": sum(c["target_grasp"] for c in cells) / n},
                    settings={"bundle": str(spec_m.bundle), "beta": spec_m.beta, "gamma": spec_m.gamma,
                              "size_cue": grounders[spec_m.name].size_cue_active,
                              **({"colour_cue": True} if grounders[spec_m.name].colour_cue_active else {}),
                              **({"cavity_cue": True} if grounders[spec_m.name].cavity_cue_active else {}),
                              **({"hubness": True} if grounders[spec_m.name].hubness_active else {}),
                              **({"sense_weight": grounders[spec_m.name].settings.sense_weight}
                                 if grounders[spec_m.name].senses_active else {})}))
    config = {"labels": str(labels_path), "labels_sha256": sha256_file(labels_path), "seed": seed,
              "layouts": layouts, "max_pairs": max_pairs, "episodes": len(episodes),
              "pairs": len({(s.verb, s.object) for s in specs}), "backends": list(backends),
              "noise": [lvl.label for lvl in levels], "image_encoder": enc.id, "detect_iou": DETECT_IOU,
              "energy_form": settings.energy_form or "bundle", "aff_mode": settings.aff_mode,
              "gt_grasps": "oracle section rule, 1 cm along the long axis; every 15° for round footprints",
              # runs from before the check read the same
              **({} if env_cfg.layout.placement.whole_in_view else {"whole_in_view": False})}
    return StaticReport(rows, skipped, episodes, config)


def _static_record(
    backends: Sequence[str], env_cfg: EnvConfig, gt_config: GTGraspConfig | None, threads: int,
    levels: Sequence[NoiseLevel], settings: Sequence[str], seed: int,
    ctx: tuple[dict[str, Grounder], ImageEncoder], spec: EpisodeSpec,
) -> dict[str, Any]:
    """Render one scene and score every method in every setting and noise level."""
    grounders, enc = ctx
    rb = _robustness() if len(levels) > 1 else None
    scene = render_scene(spec, backends, enc, env_cfg, gt_config, threads)
    record: dict[str, Any] = {"id": spec.id, "verb": spec.verb, "object": spec.object,
                              "layout": spec.layout, "target": spec.scene.target,
                              "distractors": list(spec.scene.distractors), "scene_seed": spec.scene.seed,
                              "target_box": list(scene.target_box) if scene.target_box else None,
                              "target_gt_grasps": len(scene.target_rects), "levels": {}}
    for li, level in enumerate(levels):
        per_setting: dict[str, Any] = {}
        for setting in settings:
            rng = (rb.noise_rng(seed, "static", float(li), f"{spec.id}|{setting}|{level.label}".encode())
                   if rb is not None and not level.clean else np.random.default_rng(0))
            rois = _perturbed(scene.settings[setting], level, rng, scene.rgb, enc)
            g_rois = _grounding_rois(rois)
            per_setting[setting] = {
                "target_grasp": target_grasp_ok(scene, rois),
                "methods": {name: score_choice(scene, rois, grounder.ground(spec.verb, g_rois))
                            for name, grounder in grounders.items()},
            }
        record["levels"][level.label] = per_setting
    return record


def _grounding_rois(rois: list[StaticROI]) -> list[ROI]:
    return [ROI(box_xywh=r.box, grasp_scores=[g.quality for g in r.grasps], grasps=list(r.grasps),
                image_embedding=r.embedding, mask=r.mask, label=f"roi{i}", extents_m=r.extents_m,
                colours=r.colours, classes=r.classes, cavity_m=r.cavity_m)
            for i, r in enumerate(rois)]
