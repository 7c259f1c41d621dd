"""``craft eval sim``: the paper's real-world table — 3D, Detect, Grasp Rate — on the CR3 testbed.

Labels are a CSV of affording pairs ``verb,object`` (``#`` comments, optional ``verb,object``
header). ``object`` is a sim asset id (``mug``, ``black_marker``) or a plain name (``marker``,
``cup``): an asset id is one target; a plain name is one target pair whose asset is drawn per
layout among the assets with that name. Every asset a verb's rows name — and every asset sharing
a plain name with one of them — affords the verb and is never its distractor.

Scenes follow the paper's protocol: per verb–target pair, ``layouts`` layouts (3), each with the
target and 4 distractors drawn from the assets that do not afford the verb (distinct plain names,
so no scene holds two "cup"s), at random non-overlapping poses. Everything is drawn from a numpy
generator seeded by ``(seed, crc32(verb), crc32(object), layout)``, so an episode does not change
when pairs are added, removed or capped with ``--max-pairs``. A draw is redrawn from the same
generator when its footprints cannot be placed on the table (checked before any scene is built)
or when, once the scene has settled, two objects lie closer than 1 cm (a tall bottle that
toppled onto a neighbour): the protocol's objects do not overlap.

Each episode is perceived once (``sim.perceive``) and every method grounds the same ROIs; see
``runtime/sim/pipeline.py`` for the metrics and the failure classes. The JSON holds no wall-clock
value, so two runs give identical files.
"""

from __future__ import annotations

import csv
import dataclasses
import difflib
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from ...files import sha256_file
from ...paths import artifacts_hint
from ..grounding.grounder import normalize_verb_name
from ..grounding.settings import GroundingSettings
from ..sim.assets import object_asset, object_catalog
from ..sim.env import EnvConfig
from ..sim.placement import Footprint, PlacementConfig, PlacementError, sample_layout
from ..sim.scene import SceneSpec
from .common import (
    MethodResult,
    SkippedMethod,
    markdown_table,
)
from .imagenet import LabelsError
from .methods import MethodSpec, build_grounders, load_methods, select_methods

if TYPE_CHECKING:
    from ..encoders.image import ImageEncoder
    from ..grounding.grounder import Grounder
    from ..sim.pipeline import EpisodeResult, PipelineConfig
    from ..sim.retry import RetryConfig

DISTRACTORS = 4
#: Distractor sets tried per episode before giving up (loudly). A draw that succeeds is the same
#: whatever this is (later draws continue the same generator), so raising it moves no episode
#: that was placed before. The chain spreads as it settles: hang/chain layout 1 needs 104 draws
#: (sim-val labels), every sim-dev episode fewer than 50.
MAX_DRAWS = 200
#: Restarts of the placement check before a distractor set is redrawn. ``make_scene`` later runs
#: the same sampler from the same seed with all its restarts, so it finds the same layout; fewer
#: here only makes a crowded set cost 0.3 s instead of 1.5 s before it is redrawn.
CHECK_RESTARTS = 10
MIN_GAP = 0.01  # m between any two settled objects (segmentation needs a visible gap)
COLUMNS = (("three_d", "3D"), ("detect", "Detect"), ("grasp_rate", "Grasp Rate"))

__all__ = [
    "COLUMNS",
    "EpisodeSpec",
    "LabelPair",
    "LabelsError",
    "SimLabels",
    "SimReport",
    "evaluate_sim",
    "load_sim_labels",
    "make_episode_specs",
]


# ---------------------------------------------------------------------------------------------
# labels


@dataclass(frozen=True)
class LabelPair:
    """One ``verb,object`` row: the object as written and the assets it can stand for."""

    verb: str
    object: str
    assets: tuple[str, ...]


@dataclass(frozen=True)
class SimLabels:
    """Affording pairs, and per verb the assets that must never be its distractors."""

    path: Path
    pairs: tuple[LabelPair, ...]
    affording: dict[str, frozenset[str]]  # verb -> asset ids

    @property
    def verbs(self) -> list[str]:
        return list(dict.fromkeys(p.verb for p in self.pairs))


def plain_name(name: str) -> str:
    """A plain object name as the catalogue writes it: lower case, single spaces."""
    return " ".join(name.strip().lower().split())


def load_sim_labels(path: Path) -> SimLabels:
    """Read and validate a labels CSV (see the module docstring); errors name file and line."""
    catalog = object_catalog()
    by_name: dict[str, list[str]] = {}
    for asset in sorted(catalog.values(), key=lambda a: a.asset_id):
        by_name.setdefault(asset.name, []).append(asset.asset_id)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise LabelsError(f"{path}: labels file not found{artifacts_hint(path)}") from None
    except UnicodeDecodeError as exc:
        raise LabelsError(f"{path}: not UTF-8 text (byte {exc.start}); save the labels as a UTF-8 "
                          "CSV of 'verb,object' rows") from None
    except OSError as exc:
        raise LabelsError(f"{path}: cannot read the labels file ({exc.strerror or exc})") from None
    pairs: dict[tuple[str, str], LabelPair] = {}
    for lineno, row in enumerate(csv.reader(lines), start=1):
        cells = [c.strip() for c in row]
        if not cells or not any(cells) or cells[0].startswith("#"):
            continue
        if [c.lower() for c in cells] == ["verb", "object"]:
            continue
        if len(cells) != 2 or not all(cells):
            quoted = any("," in c for c in cells)  # only a quoted field holds a comma: csv read a '"' as opening one
            raise LabelsError(f"{path}:{lineno}: expected 'verb,object', got {','.join(row)!r}"
                              + ("; a double quote there opens one quoted field: remove it or close it"
                                 if quoted else ""))
        verb, raw = normalize_verb_name(cells[0]), cells[1]
        if raw in catalog:
            assets: tuple[str, ...] = (raw,)
        elif plain_name(raw) in by_name:
            raw = plain_name(raw)
            assets = tuple(by_name[raw])
        else:
            known = list(catalog) + list(by_name)
            close = difflib.get_close_matches(plain_name(raw), known, n=3)
            raise LabelsError(f"{path}:{lineno}: {raw!r} is neither a sim asset id nor a plain name "
                              f"(close: {', '.join(close) or 'none'}; see runtime/sim/objects.json)")
        pairs.setdefault((verb, raw), LabelPair(verb, raw, assets))
    if not pairs:
        raise LabelsError(f"{path}: no verb,object pairs")
    affording: dict[str, set[str]] = {}
    for pair in pairs.values():
        names = {catalog[a].name for a in pair.assets}
        affording.setdefault(pair.verb, set()).update(
            a for n in names for a in by_name[n]
        )
    return SimLabels(path, tuple(pairs.values()), {v: frozenset(a) for v, a in affording.items()})


# ---------------------------------------------------------------------------------------------
# scenes


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode: which pair and layout it is, and the scene to build."""

    verb: str
    object: str  # as written in the labels
    layout: int
    scene: SceneSpec
    draws: int  # distractor sets drawn until one could be placed (1 = the first)

    @property
    def id(self) -> str:
        return f"{self.verb}/{self.object}/{self.layout}"


@cache
def asset_footprint(asset_id: str, fine_collision: bool = True) -> Footprint:
    """An asset's object-frame x-y footprint, measured exactly as ``make_scene`` measures it
    (loaded unrotated at the origin, base AABB), in a private pybullet client."""
    import pybullet as p

    from ..sim.collision_meshes import sim_urdf

    asset = object_asset(asset_id)
    client = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(str(sim_urdf(asset, fine_collision)), basePosition=[0.0, 0.0, 0.0],
                          globalScaling=asset.scale, physicsClientId=client)
        lo, hi = p.getAABB(body, -1, physicsClientId=client)
    finally:
        p.disconnect(physicsClientId=client)
    return Footprint(center=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2),
                     half_size=((hi[0] - lo[0]) / 2, (hi[1] - lo[1]) / 2))


def placeable(assets: Sequence[str], scene_seed: int, placement: PlacementConfig,
              fine_collision: bool = True) -> bool:
    """Whether ``make_scene`` will find a layout for these assets with this seed (within
    ``CHECK_RESTARTS`` restarts)."""
    quick = dataclasses.replace(placement, restarts=min(placement.restarts, CHECK_RESTARTS))
    try:
        sample_layout([asset_footprint(a, fine_collision) for a in assets], np.random.default_rng(scene_seed),
                      quick)
    except PlacementError:
        return False
    return True


def settled_apart(spec: SceneSpec, env_config: EnvConfig, min_gap: float | None,
                  whole_in_view: bool = False) -> bool:
    """Build the scene and check that, once settled, no two objects are closer than ``min_gap``
    (None: not checked) and, with ``whole_in_view``, that the overhead camera sees every object
    whole (``objects_cut_by_view`` finds none).

    Placement keeps upright footprints apart, but a tall bottle may topple onto its neighbour
    while settling; the protocol asks for non-overlapping objects, so such a layout is redrawn.
    """
    import pybullet as p

    from ..sim.env import SimEnv

    with SimEnv(env_config) as env:
        scene = env.reset(spec)
        bodies = [o.body_id for o in scene.objects]
        if min_gap is not None:
            for i, a in enumerate(bodies):
                for b in bodies[i + 1:]:
                    if p.getClosestPoints(a, b, distance=min_gap, physicsClientId=env.client):
                        return False
        if whole_in_view and objects_cut_by_view(env.capture().seg, bodies):
            return False
    return True


def objects_cut_by_view(seg: npt.NDArray[np.integer[Any]] | None, bodies: Sequence[int]) -> list[int]:
    """The ``bodies`` whose pixels in the segmentation ``seg`` touch the image's edge: the camera
    sees them only in part (and their grasp, a handle or a cap, may be the part it misses)."""
    if seg is None:
        raise ValueError("the view check needs the segmentation buffer of a rendered frame")
    edge = np.concatenate([seg[0], seg[-1], seg[:, 0], seg[:, -1]])
    seen = set(np.unique(edge).tolist())
    return [b for b in bodies if b in seen]


def episode_rng(seed: int, verb: str, obj: str, layout: int) -> np.random.Generator:
    """The draws of one episode, from (seed, verb, object, layout) alone: a pair's scenes do not
    change when other pairs are added or removed."""
    entropy = [seed, zlib.crc32(verb.encode()), zlib.crc32(obj.encode()), layout]
    return np.random.default_rng(np.random.SeedSequence(entropy))


def make_episode_specs(
    labels: SimLabels,
    *,
    layouts: int = 3,
    seed: int = 0,
    max_pairs: int | None = None,
    env_config: EnvConfig | None = None,
    min_gap: float | None = MIN_GAP,
    only_layout: int | None = None,
) -> list[EpisodeSpec]:
    """``layouts`` scenes per pair (the first ``max_pairs`` pairs), in label-file order.

    ``only_layout``: just that layout of each pair (``layouts`` is then ignored). Each layout is
    drawn from (seed, verb, object, layout) alone, so it is the same scene the full run builds,
    at the cost of one build however large its index (``craft sim demo --episode v/o/N``).

    A draw is kept if its footprints can be placed and, unless ``min_gap`` is None, the settled
    scene keeps every two objects ``min_gap`` apart, and (``PlacementConfig.whole_in_view``) the
    overhead camera sees every settled object whole (this builds the scene once, ~0.5 s).
    """
    catalog = object_catalog()
    env_cfg = env_config or EnvConfig()
    place = env_cfg.layout.placement
    pairs = labels.pairs[:max_pairs] if max_pairs is not None else labels.pairs
    specs: list[EpisodeSpec] = []
    for pair in pairs:
        excluded = labels.affording[pair.verb]
        for layout in range(layouts) if only_layout is None else (only_layout,):
            rng = episode_rng(seed, pair.verb, pair.object, layout)
            target = pair.assets[int(rng.integers(len(pair.assets)))]
            target_name = catalog[target].name
            pool = sorted(a for a in catalog if a not in excluded and catalog[a].name != target_name)
            draws = 0
            while draws < MAX_DRAWS:
                draws += 1
                distractors: list[str] = []
                names = {target_name}
                for index in rng.permutation(len(pool)).tolist():
                    asset = pool[index]
                    if catalog[asset].name not in names:
                        distractors.append(asset)
                        names.add(catalog[asset].name)
                    if len(distractors) == DISTRACTORS:
                        break
                if len(distractors) < DISTRACTORS:
                    raise LabelsError(f"{labels.path}: verb {pair.verb!r} leaves only {len(distractors)} "
                                      "distinct non-affording objects for distractors (need 4)")
                scene_seed = int(rng.integers(2**31 - 1))
                scene = SceneSpec(pair.verb, target, tuple(distractors), scene_seed)
                if placeable(scene.assets, scene_seed, place, env_cfg.physics.fine_collision) and (
                    (min_gap is None and not place.whole_in_view)
                    or settled_apart(scene, env_cfg, min_gap, place.whole_in_view)
                ):
                    break
            else:
                raise PlacementError(f"{pair.verb}/{pair.object} layout {layout}: no placeable "
                                     f"distractor set in {MAX_DRAWS} draws")
            specs.append(EpisodeSpec(pair.verb, pair.object, layout, scene, draws))
    return specs


# ---------------------------------------------------------------------------------------------
# encoder


def default_encoder(threads: int = 1, classifier: str | None = None,
                    sense_weight: float | None = None, temperature: float | None = None) -> ImageEncoder:
    """The ConSE image encoder with a fixed torch thread count, on whole square ROI crops
    (``conse.ROBOT_PREPROCESS``, "fit"; chosen on ``craft eval recognition``, docs/recognition.md).
    ``classifier``: its ImageNet classifier (None: the default, EfficientNet-Lite1;
    ``efficientnet-lite0`` reproduces runs from before 2026-12-04). ``sense_weight``: how its
    class names are read (``GroundingSettings.class_senses``, so that the grounders' hubness
    reference is the same; None: the default). ``temperature``: the classifier's softmax
    temperature for ConSE's weights (``GroundingSettings.conse_temperature``; None: the default)."""
    from ..encoders.conse import ROBOT_PREPROCESS, ConSEImageEncoder

    return ConSEImageEncoder(threads=threads, preprocess=ROBOT_PREPROCESS, classifier=classifier,
                             sense_weight=sense_weight, temperature=temperature)


def text_space(encoder: ImageEncoder | None) -> str:
    """The text space ``encoder`` embeds into, or the default encoder's (:func:`default_encoder`)
    without building it: the methods' bundles are checked against it first, so a run that
    cannot ground fails before it loads weights or writes the encoder's cache."""
    from ..encoders.conse import ConSEImageEncoder

    return encoder.text_encoder_id if encoder is not None else ConSEImageEncoder.text_encoder_id


# ---------------------------------------------------------------------------------------------
# records and report


def _r(x: float) -> float:
    """Rounded for the JSON (6 decimals: stable, readable, well below any effect size)."""
    return round(float(x), 6)


def episode_record(spec: EpisodeSpec, result: EpisodeResult, detect_iou: float = 0.5) -> dict[str, Any]:
    """JSON-ready summary of one ``EpisodeResult``."""
    catalog = object_catalog()
    per = result.perception
    assets = result.body_assets

    def asset_of(body: int | None) -> str | None:
        return None if body is None else assets.get(body)

    methods: dict[str, Any] = {}
    for name, o in result.outcomes.items():
        chosen = o.grounding.chosen
        methods[name] = {
            "chosen_roi": o.chosen_roi,
            "chosen_object": asset_of(o.chosen_body),
            "chosen_iou": _r(o.chosen_iou),
            "detect": o.detect,
            "success": o.success,
            "failure": o.failure.value,
            "true_class_roi": o.true_class_roi,
            "true_class_detect": (o.true_class_roi is not None and per.target_box is not None
                                  and per.rois[o.true_class_roi].target_iou >= detect_iou),
            "choice_error": o.choice_error.value if o.choice_error is not None else None,
            "pick_outcome": o.pick.outcome.value if o.pick is not None else None,
            "pick_detail": o.pick.detail if o.pick is not None else "",
            "pick_steps": o.pick.steps if o.pick is not None else 0,
            "pick_wrist_shift_mm": _r(1000 * o.pick.wrist_shift) if o.pick is not None else None,
            "grasp_quality": _r(o.grasp.quality) if o.grasp is not None else None,
            "hypothesis": ({"object": chosen.hypotheses[0].name, "p": _r(chosen.hypotheses[0].probability)}
                           if chosen is not None and chosen.hypotheses else None),
            "energies": ({"total": _r(chosen.total), "e_grasp": _r(chosen.e_grasp),
                          "e_aff": _r(chosen.e_aff), "e_align": _r(chosen.e_align)}
                         if chosen is not None else None),
        }
        if o.relocation is not None:  # the relocation policy ran: key only then (headline JSON unchanged)
            methods[name]["relocation"] = o.relocation
        if o.looked is not None:  # the active look ran: key only then (headline JSON unchanged)
            methods[name]["looked_rois"] = list(o.looked)
        if o.retries is not None:  # a retry policy ran: keys only then (the headline JSON is unchanged)
            from ..sim.retry import succeeded

            methods[name]["retries"] = [a.to_dict() for a in o.retries]
            methods[name]["success_with_retries"] = succeeded(o.success, o.retries)
    return {
        "id": spec.id,
        "verb": spec.verb,
        "object": spec.object,
        "layout": spec.layout,
        "target": spec.scene.target,
        "target_name": catalog[spec.scene.target].name,
        "distractors": list(spec.scene.distractors),
        "scene_seed": spec.scene.seed,
        "distractor_draws": spec.draws,
        "three_d": per.three_d,
        "three_d_detail": per.three_d_detail,
        "target_roi": per.target_roi,
        "target_box": list(per.target_box) if per.target_box is not None else None,
        "rois": [{"box": list(r.roi.box_xywh), "object": asset_of(r.body), "target_iou": _r(r.target_iou),
                  "grasps": len(r.candidates),
                  "usable_quality": _r(r.usable[0].quality) if r.usable else None}
                 for r in per.rois],
        "methods": methods,
    }


def summarize(name: str, description: str, records: Sequence[dict[str, Any]],
              settings: dict[str, Any]) -> MethodResult:
    """A method's row: 3D, Detect, Grasp Rate, the failure breakdown and per-verb rates."""
    from ..sim.choice_errors import ChoiceError
    from ..sim.pipeline import Failure

    mine = [(r, r["methods"][name]) for r in records]
    n = max(len(mine), 1)
    metrics = {
        "three_d": sum(r["three_d"] for r, _ in mine) / n,
        "detect": sum(m["detect"] for _, m in mine) / n,
        "grasp_rate": sum(m["success"] for _, m in mine) / n,
    }
    per_verb: dict[str, dict[str, float]] = {}
    for verb in dict.fromkeys(r["verb"] for r, _ in mine):
        rows = [(r, m) for r, m in mine if r["verb"] == verb]
        k = len(rows)
        per_verb[verb] = {"episodes": float(k), "three_d": sum(r["three_d"] for r, _ in rows) / k,
                          "detect": sum(m["detect"] for _, m in rows) / k,
                          "grasp_rate": sum(m["success"] for _, m in rows) / k}
    metrics["detect_true_class"] = sum(bool(m.get("true_class_detect")) for _, m in mine) / n
    if any("success_with_retries" in m for _, m in mine):
        metrics["grasp_rate_retries"] = sum(bool(m.get("success_with_retries")) for _, m in mine) / n
    failures = {f.value: 0 for f in Failure}
    for _, m in mine:
        failures[m["failure"]] += 1
    errors = {e.value: sum(m.get("choice_error") == e.value for _, m in mine) for e in ChoiceError}
    return MethodResult(name=name, description=description, metrics=metrics, per_verb=per_verb,
                        settings={**settings, "failures": failures, "choice_errors": errors})


@dataclass
class SimReport:
    """Results of ``evaluate_sim``: one row per method, plus every episode's record."""

    results: list[MethodResult]
    skipped: list[SkippedMethod]
    episodes: list[dict[str, Any]]
    config: dict[str, Any]
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        methods: dict[str, Any] = {}
        for r in self.results:
            settings = {k: v for k, v in r.settings.items() if k not in ("failures", "choice_errors")}
            methods[r.name] = {
                **{k: _r(v) for k, v in r.metrics.items()},
                "description": r.description,
                "failures": r.settings["failures"],
                "choice_errors": r.settings["choice_errors"],
                "per_verb": {v: {k: _r(x) for k, x in d.items()} for v, d in r.per_verb.items()},
                "settings": settings,
                "notes": r.notes,
                "episodes": [{"id": e["id"], **e["methods"][r.name]} for e in self.episodes],
            }
        return {
            "benchmark": "sim (CR3 testbed; the paper's real-world protocol)",
            "config": self.config,
            "methods": methods,
            "skipped_methods": [{"method": s.name, "reason": s.reason} for s in self.skipped],
            "episodes": self.episodes,
            "notes": self.notes,
        }

    def to_markdown(self) -> str:
        c = self.config
        head = (f"### CR3 testbed: grasp `{c['pipeline']['grasp']}`, ROIs `{c['pipeline']['rois']}` — "
                f"{c['pairs']} verb–target pairs × {c['layouts']} layouts = {c['episodes']} episodes "
                f"(seed {c['seed']}, labels `{Path(c['labels']).name}`)\n\n"
                "3D: the grasp module returned a viable grasp on the target; Detect: the chosen ROI is "
                "the target (IoU ≥ 0.5); Grasp Rate: end-to-end success in physics (percent).\n\n")
        retries = int(c.get("retries", 0))
        columns = COLUMNS + ((("grasp_rate_retries", f"Grasp Rate, ≤ {retries} retries"),) if retries else ())
        if retries:
            head += (f"Grasp Rate, ≤ {retries} retries: success within the first pick and up to {retries} more "
                     "after a pick whose hand ended empty, each on a fresh frame (`sim/retry.py`); "
                     "the headline Grasp Rate is single-attempt.\n\n")
        table = markdown_table(self.results, self.skipped, columns)
        return head + table + "\n" + self.failure_table()

    def failure_table(self) -> str:
        """Episodes per outcome class and method (the paper's failure analysis)."""
        from ..sim.choice_errors import ChoiceError
        from ..sim.pipeline import Failure

        kinds = [f.value for f in Failure]
        used = [k for k in kinds if any(r.settings["failures"][k] for r in self.results)]
        if not used:
            return ""
        split = [e.value for e in ChoiceError]
        rows = ["| Method | " + " | ".join(used) + " | " + " | ".join(f"wrong: {e}" for e in split)
                + " | Detect, true class |",
                "|---|" + "---:|" * (len(used) + len(split) + 1)]
        for r in self.results:
            errors = r.settings["choice_errors"]
            rows.append(f"| {r.name} | " + " | ".join(str(r.settings["failures"][k]) for k in used)
                        + " | " + " | ".join(str(errors.get(e, 0)) for e in split) + " | "
                        + f"{100 * r.metrics['detect_true_class']:.1f} |")
        return ("Outcomes (episodes). A `wrong_object` episode is a *perception* error when re-grounding "
                "it with p(o|r) set to every ROI's true class picks the target; otherwise a *knowledge* "
                "error when, so named, the KB's E_aff ranks another ROI strictly ahead of the target (or finds "
                "nothing affordant), and an "
                "*energies* error when the KB ranks the target first but E_grasp and E_align move another "
                "ROI ahead. *Detect, true class* is Detect (percent) under that re-grounding.\n\n"
                + "\n".join(rows) + "\n")


ProgressFn = Callable[[int, int, dict[str, Any]], None]


def worker_context(
    runnable_specs: Sequence[MethodSpec], threads: int, settings: GroundingSettings,
    classifier: str | None = None,
) -> tuple[dict[str, Grounder], ImageEncoder]:
    """What a ``--jobs`` worker builds once: the grounders and the default image encoder."""
    from ..sim.pipeline import sim_vocabulary

    enc = default_encoder(threads, classifier, settings.class_senses, settings.conse_temperature)
    runnable, _ = load_methods(runnable_specs, enc.text_encoder_id)
    return build_grounders(runnable, settings, sim_vocabulary()), enc


def run_one_episode(
    cfg: PipelineConfig, env_cfg: EnvConfig, retry: RetryConfig | None,
    ctx: tuple[dict[str, Grounder], ImageEncoder], spec: EpisodeSpec,
) -> dict[str, Any]:
    """One episode in a fresh pybullet client (nothing carries over), as its JSON record."""
    from ..sim.env import SimEnv
    from ..sim.pipeline import run_episode

    grounders, enc = ctx
    with SimEnv(env_cfg) as env:
        result = run_episode(env, spec.scene, grounders, enc, cfg, retry=retry)
    return episode_record(spec, result, cfg.detect_iou)


def evaluate_sim(
    labels_path: Path,
    *,
    config: PipelineConfig | None = None,
    layouts: int = 3,
    seed: int = 0,
    methods: Sequence[MethodSpec] | None = None,
    max_pairs: int | None = None,
    encoder: ImageEncoder | None = None,
    env_config: EnvConfig | None = None,
    settings: GroundingSettings | None = None,
    progress: ProgressFn | None = None,
    jobs: int = 1,
    retry: RetryConfig | None = None,
    classifier: str | None = None,
) -> SimReport:
    """Run every episode once and every method on it; see the module docstring.

    ``config`` is a ``sim.pipeline.PipelineConfig`` (default: GR-ConvNet on predicted ROIs);
    ``progress(done, total, record)`` is called after each episode. ``jobs`` > 1 runs episodes
    in that many worker processes (``evaluation.parallel``): the report is byte-identical to
    ``jobs=1``. Workers build the default image encoder, so ``encoder`` must then be None.
    ``classifier`` chooses that encoder's ImageNet classifier (``default_encoder``).
    ``retry`` (``sim.retry.RetryConfig``) adds a retry policy's column beside the single-attempt
    metrics; without it (or with 0 retries) the report is what it was.
    """
    from functools import partial

    from ..sim.pipeline import PipelineConfig, sim_vocabulary
    from .parallel import ordered_map

    if layouts < 1:
        raise ValueError(f"layouts must be >= 1, got {layouts}")
    if jobs > 1 and encoder is not None:
        raise ValueError("jobs > 1 builds the default image encoder in every worker; pass encoder=None")
    cfg = config or PipelineConfig()
    env_cfg = env_config or EnvConfig()
    labels = load_sim_labels(labels_path)
    specs = make_episode_specs(labels, layouts=layouts, seed=seed, max_pairs=max_pairs,
                               env_config=env_cfg)
    settings = settings or GroundingSettings()
    method_specs = list(methods) if methods is not None else select_methods()
    runnable, skipped = load_methods(method_specs, text_space(encoder))
    enc = encoder if encoder is not None else default_encoder(cfg.torch_threads, classifier, settings.class_senses,
                                                                 settings.conse_temperature)
    grounders = build_grounders(runnable, settings, sim_vocabulary())
    records: list[dict[str, Any]] = []
    if grounders:
        build = partial(worker_context, [m for m, _ in runnable], cfg.torch_threads, settings, classifier)
        for record in ordered_map(partial(run_one_episode, cfg, env_cfg, retry), specs, jobs=jobs, build=build,
                                  context=(grounders, enc)):
            records.append(record)
            if progress is not None:
                progress(len(records), len(specs), record)
    results: list[MethodResult] = []
    for spec_m, _ in runnable:
        grounder = grounders[spec_m.name]
        row = summarize(spec_m.name, spec_m.description, records,
                        {"bundle": str(spec_m.bundle), "kb": grounder.kb, "beta": spec_m.beta,
                         "gamma": spec_m.gamma, "alpha": grounder.alpha, "energy_form": grounder.energy_form,
                         "aff_mode": grounder.aff_mode, "size_cue": grounder.size_cue_active,
                         # only when on: results stored before the cue existed read the same
                         **({"colour_cue": True} if grounder.colour_cue_active else {}),
                         **({"cavity_cue": True} if grounder.cavity_cue_active else {}),
                         **({"hubness": True} if grounder.hubness_active else {}),
                         **({"sense_weight": grounder.settings.sense_weight} if grounder.senses_active else {})})
        open_vocab = sorted(v for v in labels.verbs if not grounder.knows_verb(v))
        if open_vocab:
            row.notes.append("verbs not in the KB, grounded with the open-vocabulary fallback: "
                             + ", ".join(open_vocab))
        results.append(row)
    config_out = {
        "labels": str(labels_path), "labels_sha256": sha256_file(labels_path), "seed": seed,
        "layouts": layouts, "max_pairs": max_pairs, "pairs": len({(s.verb, s.object) for s in specs}),
        "episodes": len(specs), "verbs": len({s.verb for s in specs}), "distractors": DISTRACTORS,
        "pipeline": cfg.to_dict(), "gripper": env_cfg.gripper.hand, "fine_collision": env_cfg.physics.fine_collision, "wrist_look": cfg.pick.wrist.enabled,
        "image_encoder": enc.id, "vocabulary_size": len(sim_vocabulary()),
        "energy_form": settings.energy_form or "bundle", "aff_mode": settings.aff_mode,
    }
    if not env_cfg.layout.placement.whole_in_view:  # runs from before the check read the same
        config_out["whole_in_view"] = False
    if retry is not None and retry.retries > 0:
        config_out["retries"] = retry.retries
    if cfg.pick.clearance.prefer:
        config_out["prefer_clear"] = True
    config_out["relocate"] = cfg.pick.clearance.relocate
    # the pick settings results have turned on (finger tips 4 -> 2 mm above the table), so a
    # results file says which it was measured at
    config_out["table_clearance_m"] = cfg.pick.table_clearance
    config_out["clearance_margin_m"] = cfg.pick.clearance.margin
    # the gentle grip's size limit (None: the full force for every object, as before session 41)
    config_out["gentle_below_m"] = cfg.pick.gentle_below
    # the carry's check against the arm (None: off, every carry at yaw 0, as before session 44)
    config_out["carry_margin_m"] = cfg.pick.carry_margin if cfg.pick.carry_check else None
    return SimReport(results, skipped, records, config_out)
