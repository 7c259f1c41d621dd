"""``craft eval imagenet``: functional grounding on ImageNet (Nguyen et al., RSS 2020 protocol).

Data: ``<shared>/data/imagenet_affordance`` (``objects.tsv``: object, wnid, image — one photo per
class; ``crane`` and ``cardigan`` have two wnids, and both photos belong to the class: an episode
shows one of them, drawn at random). Labels come from a JSON file ``{"verb": ["object", ...]}``
(keys starting with ``_`` are comments); the benchmark's real labels are withheld and are never
reconstructed here.

* **single-affordance**: per verb, ``episodes`` episodes of 1 affording class + 4 distinct
  non-affording classes; top-1 and top-2 accuracy of the lowest-energy image.
* **multi-affordance**: per verb, ``episodes`` episodes of 5 distinct classes of which 2 or 3
  (drawn uniformly) afford the verb; MRR and nDCG. (Drawing 5 classes uniformly among the sets
  with at least one affording class, as before, gave exactly one affording image in ~89 % of
  episodes, so MRR/nDCG sat near chance and were not comparable with the paper.) A verb with a
  single affording class in the pool gets no multi-affordance episodes (listed as skipped).

Every table starts with a **chance** row (the expectation of a random ranking of each episode,
computed exactly) and a **label-oracle** row (the labels as energies: 100 % — the ceiling, and a
check of the harness). There is **one photo per class** (two for ``crane`` and ``cardigan``),
so a method's result on a verb rests on a handful of photos: read differences of a few points
as noise.

``p(o | r)`` uses ``grounding.DEFAULT_TEMPERATURE``, fixed a priori (not calibrated on these
photos, which would fit the benchmark's own images).

Episodes come from a numpy ``Generator`` seeded by ``(seed, crc32(verb), setting)``, so they are
identical for every method and do not change when verbs are added or removed. Whole images are
the ROIs: there is no grasp term (``alpha = 0``). Each image is embedded once per encoder (in
memory and on disk under ``artifacts/cache/encoders``); a method then scores every image for a
verb in one vectorized call, and its episodes index into those energies.
"""

from __future__ import annotations

import csv
import difflib
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ...files import read_json, sha256_file
from ...paths import VOCAB_DIR, shared_dir
from ..grounding.energies import object_hypotheses
from ..grounding.settings import GroundingSettings
from .common import (
    ImageEmbeddingCache,
    MethodResult,
    SkippedMethod,
    markdown_table,
    ndcg,
    read_artifact_names,
    reciprocal_rank,
    topk_accuracy,
    verb_object_lists,
    vocabulary_senses,
)
from .methods import MethodSpec, default_methods, load_methods, method_settings

IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]
FloatArray = npt.NDArray[np.float32]

CANDIDATES = 5
SETTINGS = ("single", "multi")
_SETTING_IDS = {"single": 1, "multi": 2}
#: How many of the 5 candidates afford the verb in a multi-affordance episode (drawn uniformly).
MULTI_AFFORDING = (2, 3)
COLUMNS = (("top1", "Top-1"), ("top2", "Top-2"), ("mrr", "MRR"), ("ndcg", "nDCG"))


class LabelsError(ValueError):
    """The labels file is malformed or names objects outside the benchmark."""


def dataset_dir() -> Path:
    return shared_dir() / "data" / "imagenet_affordance"


def _norm(name: str) -> str:
    from ...schemas.names import normalize_name

    try:
        return normalize_name(name)
    except ValueError:
        return name.strip().lower()


@dataclass(frozen=True)
class ImageNetData:
    """The benchmark's classes and photos: ``class_images[c]`` are indices into ``images``."""

    root: Path
    classes: list[str]
    images: list[Path]
    class_images: list[list[int]]

    @property
    def class_index(self) -> dict[str, int]:
        return {c: i for i, c in enumerate(self.classes)}


def load_dataset(root: Path | None = None) -> ImageNetData:
    """Read ``objects.tsv``; a class listed with several wnids owns all of their images."""
    folder = root or dataset_dir()
    table = folder / "objects.tsv"
    if not table.is_file():
        raise FileNotFoundError(f"{table}: ImageNet affordance data not found; set CRAFT_SHARED to the shared folder")
    classes: list[str] = []
    class_images: list[list[int]] = []
    images: list[Path] = []
    index: dict[str, int] = {}
    with table.open(encoding="utf-8", newline="") as handle:
        for row in csv.DictReader(handle, delimiter="\t"):
            name = _norm(row["object"])
            if name not in index:
                index[name] = len(classes)
                classes.append(name)
                class_images.append([])
            path = folder / "images" / row["image"]
            if not path.is_file():
                raise FileNotFoundError(f"{path}: listed in {table} but missing")
            class_images[index[name]].append(len(images))
            images.append(path)
    return ImageNetData(folder, classes, images, class_images)


def load_labels(path: Path, classes: Sequence[str]) -> dict[str, list[str]]:
    """``{"verb": ["object", ...]}`` with names normalized; unknown objects are an error that
    lists close matches (a typo would silently turn a positive into a negative).

    Also errors, each of which used to run (or print an empty table) as if the file were right:
    a blank verb name; a verb with no objects (no episode can show an affording class); and two
    keys naming one verb (``"carry"`` and ``"CARRY"``, or one key twice), where the second list
    silently replaced the first."""
    raw = read_json(path, "labels file", LabelsError, unique_keys=True)
    known = set(classes)
    labels: dict[str, list[str]] = {}
    for verb, name, objects in verb_object_lists(path, raw, LabelsError, "every episode shows an affording class, "
                                                 "so list the classes that afford it"):
        names = list(dict.fromkeys(_norm(o) for o in objects))
        unknown = [o for o in names if o not in known]
        if unknown:
            close = {o: difflib.get_close_matches(o, list(known), n=3) for o in unknown}
            raise LabelsError(f"{path}: {verb!r} names objects outside the benchmark: "
                              + "; ".join(f"{o!r} (close: {', '.join(c) or 'none'})" for o, c in close.items()))
        labels[name] = names
    if not labels:
        raise LabelsError(f"{path}: no verbs")
    return labels


@dataclass(frozen=True)
class EpisodeSet:
    """``episodes`` x 5 candidate images of one verb and setting, and which ones afford it."""

    verb: str
    setting: str
    images: IntArray  # [E, 5] indices into ImageNetData.images
    relevant: BoolArray  # [E, 5]


@dataclass(frozen=True)
class SkippedVerb:
    verb: str
    setting: str
    reason: str


def _rng(seed: int, verb: str, setting: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(verb.encode()), _SETTING_IDS[setting]]))


def make_episodes(
    labels: dict[str, list[str]], data: ImageNetData, *, episodes: int = 100, seed: int = 0,
    pool: Sequence[str] | None = None,
) -> tuple[list[EpisodeSet], list[SkippedVerb]]:
    """Both settings' episodes for every verb, and the verbs that cannot form episodes (why)."""
    cidx = data.class_index
    pool_ids = np.array(sorted(cidx[c] for c in (pool or data.classes)), dtype=np.intp)
    in_pool = set(pool_ids.tolist())
    sets: list[EpisodeSet] = []
    skipped: list[SkippedVerb] = []
    for verb in labels:
        pos = {cidx[o] for o in labels[verb] if cidx[o] in in_pool}
        neg = np.array([c for c in pool_ids if c not in pos], dtype=np.intp)
        pos_arr = np.array(sorted(pos), dtype=np.intp)
        for setting in SETTINGS:
            if not pos:
                skipped.append(SkippedVerb(verb, setting, "no affording class in the pool"))
                continue
            if setting == "single" and len(neg) < CANDIDATES - 1:
                skipped.append(SkippedVerb(verb, setting, f"only {len(neg)} non-affording classes (need 4)"))
                continue
            if setting == "multi" and len(pos) < MULTI_AFFORDING[0]:
                skipped.append(SkippedVerb(verb, setting, f"only {len(pos)} affording class in the pool "
                                           f"(need {MULTI_AFFORDING[0]})"))
                continue
            if setting == "multi" and len(neg) < CANDIDATES - MULTI_AFFORDING[0]:
                skipped.append(SkippedVerb(verb, setting, f"only {len(neg)} non-affording classes "
                                           f"(need {CANDIDATES - MULTI_AFFORDING[0]})"))
                continue
            rng = _rng(seed, verb, setting)
            classes = np.zeros((episodes, CANDIDATES), dtype=np.intp)
            for e in range(episodes):
                if setting == "single":
                    row = np.concatenate([[rng.choice(pos_arr)], rng.choice(neg, CANDIDATES - 1, replace=False)])
                    classes[e] = row[rng.permutation(CANDIDATES)]
                else:
                    feasible = [k for k in MULTI_AFFORDING
                                if k <= len(pos_arr) and CANDIDATES - k <= len(neg)]
                    k = int(rng.choice(feasible))
                    row = np.concatenate([rng.choice(pos_arr, k, replace=False),
                                          rng.choice(neg, CANDIDATES - k, replace=False)])
                    classes[e] = row[rng.permutation(CANDIDATES)]
            images = np.array([[data.class_images[c][rng.integers(len(data.class_images[c]))] for c in row]
                               for row in classes], dtype=np.intp)  # [E, 5]
            relevant = np.isin(classes, pos_arr)  # [E, 5]
            sets.append(EpisodeSet(verb, setting, images, relevant))
    return sets, skipped


def protocol_episodes(
    labels_path: Path, data: ImageNetData, *, episodes: int, seed: int, pool: Sequence[str] | None,
) -> tuple[dict[str, list[str]], list[str] | None, list[EpisodeSet], list[SkippedVerb]]:
    """The labels read against the benchmark's classes, ``pool`` normalized, and the episodes
    drawn: ``(labels, pool, sets, skipped verbs)``, or ``LabelsError`` naming the labels file when
    the labels are malformed, ``pool`` names an unknown class or no episode can be formed. Done
    before any model loads (``evaluate_robustness`` calls it before its image encoder), so that
    bad labels fail at once, not after the work with an empty table and exit 0."""
    labels = load_labels(labels_path, data.classes)
    if pool is not None:
        pool = [_norm(c) for c in pool]
        bad = [c for c in pool if c not in data.class_index]
        if bad:
            raise LabelsError(f"pool names classes outside the benchmark: {bad}")
    sets, skipped = make_episodes(labels, data, episodes=episodes, seed=seed, pool=pool)
    if not sets:
        raise LabelsError(no_episode_message(labels_path, skipped, pool))
    return labels, pool, sets, skipped


def no_episode_message(labels_path: Path, skipped: Sequence[SkippedVerb], pool: Sequence[str] | None) -> str:
    """Why no verb of ``labels_path`` forms an episode in either setting, verb by verb."""
    where = f"the {len(pool)} --classes" if pool is not None else "the benchmark's classes"
    reasons = "; ".join(f"{s.verb} ({s.setting}): {s.reason}" for s in skipped)
    return (f"{labels_path}: no episode can be formed from {where}: an episode shows {CANDIDATES} distinct "
            f"classes, 1 (single-affordance) or {MULTI_AFFORDING[0]}-{MULTI_AFFORDING[-1]} (multi-affordance) "
            f"of them affording the verb — {reasons}; label more classes or widen --classes")


@dataclass
class ImageNetReport:
    results: list[MethodResult]
    skipped: list[SkippedMethod]
    skipped_verbs: list[SkippedVerb]
    config: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return {
            "benchmark": "imagenet-affordance (Nguyen et al. protocol)",
            "config": self.config,
            "methods": {r.name: {**r.metrics, "description": r.description, "per_verb": r.per_verb,
                                 "notes": r.notes, "settings": r.settings} for r in self.results},
            "skipped_methods": [{"method": s.name, "reason": s.reason} for s in self.skipped],
            "skipped_verbs": [{"verb": s.verb, "setting": s.setting, "reason": s.reason} for s in self.skipped_verbs],
        }

    def to_markdown(self) -> str:
        c = self.config
        head = (f"### ImageNet functional grounding ({c['episodes']} episodes/verb, seed {c['seed']}, "
                f"{c['verbs']} verbs, labels `{Path(c['labels']).name}`)\n\n"
                "Single-affordance: Top-1/Top-2 (1 affording image of 5); multi-affordance: MRR/nDCG "
                "(2-3 affording images of 5), percent. One photo per class (two for crane and "
                f"cardigan); p(o|r) temperature {c['temperature']:g}, fixed a priori.\n\n")
        return head + markdown_table(self.results, self.skipped, COLUMNS)


def _default_encoder(threads: int | None, sense_weight: float, temperature: float) -> Any:
    from ..encoders.conse import ConSEImageEncoder

    return ConSEImageEncoder(threads=threads, sense_weight=sense_weight, temperature=temperature)


def embed_dataset_images(
    data: ImageNetData, indices: Sequence[int], encoder: Any, cache_dir: Path | None, batch_size: int = 16
) -> FloatArray:
    """``[len(indices), d]`` embeddings of whole images, each computed once per encoder."""
    from ..encoders.image import load_image

    cache = ImageEmbeddingCache(encoder.id, cache_dir)
    paths = [data.images[i] for i in indices]
    out: FloatArray = cache.embed_files(
        paths, lambda todo: encoder.embed_images([load_image(str(p)) for p in todo], batch_size)
    )
    return out


def evaluate_imagenet(
    labels_path: Path,
    *,
    methods: Sequence[MethodSpec] | None = None,
    kb: Path | None = None,
    episodes: int = 100,
    seed: int = 0,
    data_root: Path | None = None,
    pool: Sequence[str] | None = None,
    vocabulary: Sequence[str] | None = None,
    encoder: Any | None = None,
    cache_dir: Path | None = None,
    settings: GroundingSettings | None = None,
    threads: int | None = None,
) -> ImageNetReport:
    """Run every method on the same episodes; see the module docstring.

    ``pool`` restricts the classes episodes are drawn from (tests use a few); ``vocabulary`` is
    the object vocabulary of ``p(o | r)`` (default: the 216 ImageNet objects, or ``pool``).
    ``cache_dir`` ``None`` keeps image embeddings in memory only; ``threads`` caps torch threads
    of the default (ConSE) encoder. ``settings`` (temperature, E_aff form and mode) apply to
    every method; the protocol fixes alpha = 0 (photos have no grasps) and the vocabulary.
    """
    from ..grounding.grounder import Grounder

    settings = settings or GroundingSettings()

    data = load_dataset(data_root)
    labels, pool, sets, skipped_verbs = protocol_episodes(labels_path, data, episodes=episodes, seed=seed, pool=pool)
    if vocabulary is None:
        vocabulary = list(pool) if pool is not None else [
            _norm(name) for name in read_artifact_names(VOCAB_DIR / "imagenet_objects.txt", "the ImageNet objects vocabulary")]

    runnable, skipped = load_methods(list(methods) if methods is not None else default_methods(kb))
    # every method reads the names of p(o | r) in the vocabulary's senses (methods.build_grounders)
    senses = vocabulary_senses() if settings.sense_weight > 0 else None

    class_ids = sorted({data.class_index[c] for c in (pool or data.classes)})
    image_ids = sorted(i for c in class_ids for i in data.class_images[c])
    encoder_id = None
    results: list[MethodResult] = []
    if runnable and sets:
        enc = encoder if encoder is not None else _default_encoder(threads, settings.class_senses, settings.conse_temperature)
        encoder_id = enc.id
        emb_rows = embed_dataset_images(data, image_ids, enc, cache_dir)  # [n, d]
        emb = np.zeros((len(data.images), emb_rows.shape[1]), dtype=np.float32)  # [all images, d]
        emb[image_ids] = emb_rows
        for spec, bundle in runnable:
            space = bundle.manifest.text_encoder.id
            if space != enc.text_encoder_id:
                skipped.append(SkippedMethod(spec.name, f"{spec.bundle}/manifest.json: text encoder {space}, "
                                             f"image encoder {enc.id} embeds into {enc.text_encoder_id}"))
                continue
            grounder = Grounder(bundle, method_settings(spec, settings, vocabulary, alpha=0.0), senses=senses)
            results.append(_score_method(spec, grounder, sets, emb, image_ids))
    if sets:
        results = reference_rows(sets) + results
    config = {
        "labels": str(labels_path), "labels_sha256": sha256_file(labels_path), "episodes": episodes,
        "seed": seed, "verbs": len(labels), "candidates": CANDIDATES, "classes": len(class_ids),
        "images": len(image_ids), "vocabulary_size": len(vocabulary), "image_encoder": encoder_id,
        "temperature": settings.temperature, "aff_mode": settings.aff_mode,
        "energy_form": settings.energy_form or "bundle",
        "alpha": 0.0, "data": str(data.root), "multi_affording": list(MULTI_AFFORDING),
        "photos_per_class": "one (two for crane and cardigan)",
        # only when on: results stored before the names were read in their sense read the same
        **({"sense_weight": settings.sense_weight} if senses else {}),
    }
    return ImageNetReport(results, skipped, skipped_verbs, config)


def chance_metrics(relevant: BoolArray) -> dict[str, FloatArray]:
    """``[E]`` expected top-1/top-2/RR/nDCG of a uniformly random ranking of each episode.

    With ``r`` relevant among ``K``: P(top-k hit) = 1 - C(K-r, k)/C(K, k); the first relevant
    is at rank i with probability C(K-i, r-1)/C(K, r); E[DCG] = (r/K) sum_i 1/log2(i+1).
    """
    from math import comb

    k_all = relevant.shape[1]
    discount = 1.0 / np.log2(np.arange(2, k_all + 2))  # [K]
    out: dict[str, list[float]] = {"top1": [], "top2": [], "mrr": [], "ndcg": []}
    for r in relevant.sum(axis=1).tolist():
        total = comb(k_all, r)
        out["top1"].append(1 - comb(k_all - r, 1) / comb(k_all, 1))
        out["top2"].append(1 - comb(k_all - r, 2) / comb(k_all, 2))
        out["mrr"].append(sum(comb(k_all - i, r - 1) / total / i for i in range(1, k_all + 1)))
        out["ndcg"].append(r / k_all * float(discount.sum()) / float(discount[:r].sum()))
    return {k: np.asarray(v, dtype=np.float32) for k, v in out.items()}


def reference_rows(sets: list[EpisodeSet]) -> list[MethodResult]:
    """The chance row (exact expectation) and the label-oracle row (labels as energies)."""
    rows = []
    for name, description in (("chance", "expected value of a random ranking"),
                              ("label oracle", "the labels as energies (the ceiling)")):
        per_verb: dict[str, dict[str, float]] = {}
        sums: dict[str, list[float]] = {k: [] for k, _ in COLUMNS}
        for s in sets:
            keys = ("top1", "top2") if s.setting == "single" else ("mrr", "ndcg")
            if name == "chance":
                values = chance_metrics(s.relevant)
            else:
                e = np.where(s.relevant, -1.0, 0.0)  # [E, 5]
                values = {"top1": topk_accuracy(e, s.relevant, 1), "top2": topk_accuracy(e, s.relevant, 2),
                          "mrr": reciprocal_rank(e, s.relevant), "ndcg": ndcg(e, s.relevant)}
            row = per_verb.setdefault(s.verb, {})
            for key in keys:
                row[key] = float(values[key].mean())
                sums[key].append(row[key])
        rows.append(MethodResult(name=name, description=description,
                                 metrics={k: float(np.mean(v)) for k, v in sums.items() if v},
                                 per_verb=per_verb, settings={"reference": True}))
    return rows


def _score_method(spec: MethodSpec, grounder: Any, sets: list[EpisodeSet], emb: FloatArray,
                  image_ids: list[int]) -> MethodResult:
    """Score every image once per verb, then every episode by indexing (fully vectorized)."""
    energy_by_verb: dict[str, FloatArray] = {}
    open_vocab: list[str] = []
    per_verb: dict[str, dict[str, float]] = {}
    sums: dict[str, list[float]] = {k: [] for k, _ in COLUMNS}
    for s in sets:
        if s.verb not in energy_by_verb:
            if not grounder.knows_verb(s.verb):
                open_vocab.append(s.verb)
            energy = np.full(len(emb), np.inf, dtype=np.float32)  # [all images]
            energy[image_ids] = grounder.energies(s.verb, emb[image_ids]).total
            energy_by_verb[s.verb] = energy
        e = energy_by_verb[s.verb][s.images]  # [E, 5]
        row = per_verb.setdefault(s.verb, {})
        if s.setting == "single":
            row["top1"] = float(topk_accuracy(e, s.relevant, 1).mean())
            row["top2"] = float(topk_accuracy(e, s.relevant, 2).mean())
        else:
            row["mrr"] = float(reciprocal_rank(e, s.relevant).mean())
            row["ndcg"] = float(ndcg(e, s.relevant).mean())
        for key in row:
            if key in (("top1", "top2") if s.setting == "single" else ("mrr", "ndcg")):
                sums[key].append(row[key])
    notes = []
    if open_vocab:
        notes.append(f"{len(open_vocab)} verb(s) not in the KB, scored with the open-vocabulary fallback: "
                     + ", ".join(sorted(open_vocab)))
    if grounder.objects_without_knowledge:
        notes.append(f"{len(grounder.objects_without_knowledge)} vocabulary object(s) not in the KB (E_aff = 0)")
    return MethodResult(
        name=spec.name, description=spec.description,
        metrics={k: float(np.mean(v)) for k, v in sums.items() if v},
        per_verb=per_verb, notes=notes,
        settings={"bundle": str(spec.bundle), "kb": grounder.kb, "beta": spec.beta, "gamma": spec.gamma,
                  "open_vocab_verbs": sorted(open_vocab),
                  "objects_without_knowledge": list(grounder.objects_without_knowledge)},
    )


@dataclass
class Calibration:
    best: float
    nll: dict[float, float] = field(default_factory=dict)
    top1: float = 0.0


def calibrate_temperature(
    image_emb: npt.NDArray[Any], object_emb: npt.NDArray[Any], true_index: Sequence[int],
    grid: Sequence[float] = (0.01, 0.02, 0.03, 0.05, 0.07, 0.1, 0.15, 0.2),
) -> Calibration:
    """Pick T for ``p(o | r)`` by the mean negative log-likelihood of each image's true object.

    Uses only object identities, never affordance labels. Do **not** set the runtime's default
    from the benchmark's own photos (that fits the test images); use other images, e.g. the
    testbed's renders, or keep the a-priori default (``grounding.DEFAULT_TEMPERATURE``).
    """
    img = np.asarray(image_emb, np.float32)
    img = img / np.linalg.norm(img, axis=1, keepdims=True)
    obj = np.asarray(object_emb, np.float32)
    obj = obj / np.linalg.norm(obj, axis=1, keepdims=True)
    cos = img @ obj.T  # [N, O]
    idx = np.asarray(true_index)
    nll = {}
    for t in grid:
        p = object_hypotheses(cos, t)  # [N, O]
        nll[float(t)] = float(-np.log(np.maximum(p[np.arange(len(idx)), idx], 1e-12)).mean())
    best = min(nll, key=lambda t: nll[t])
    return Calibration(best, nll, float((cos.argmax(axis=1) == idx).mean()))
