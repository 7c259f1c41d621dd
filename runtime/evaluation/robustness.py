"""Robustness to perceptual noise: the ImageNet protocol with perturbed photos.

The paper claims CRAFT-E "stays robust under perceptual noise". This harness measures it: the
episodes, methods and scoring of ``craft eval imagenet`` (``evaluation/imagenet.py``, reused
unchanged) are run once per noise kind and level, with every photo perturbed *before* the image
encoder sees it:

* ``gaussian`` — additive pixel noise, sigma in 8-bit intensity units;
* ``blur`` — Gaussian blur, radius in pixels;
* ``crop`` — ROI jitter: a random sub-window keeping ``1 - level`` of the area (level = the
  fraction cut away; the window's IoU with the full frame is exactly ``1 - level``).

Pixel noise and blur are applied at the encoder's input scale (short side 256, bicubic — the
first step of ``resize_center_crop``). Applied at the original resolution, the encoder's own
downsampling would average most of the noise away on a 1600-px photo and almost none on a 100-px
one, so one "sigma" would mean different things per photo. The crop is geometric and is cut at
the original resolution, as a detector's box would be.

Noise is deterministic per (photo content, kind, level, seed): the random generator is seeded
from those, never from call order, so embeddings can be cached per (image, kind, level, seed) —
the perturbed encoder gets its own id and therefore its own on-disk embedding cache file — and a
rerun reproduces every number. Level 0 is the identity for every kind and shares the clean
cache with ``craft eval imagenet``. Episodes do not depend on the noise, so every level scores
the *same* episodes (paired comparison).

Besides the methods' metrics, each level reports how much perception itself degraded: the
fraction of photos whose p(o | r), read as the grounder reads it (``Grounder.image_hypotheses``),
is highest at their own class name among the pool's classes (``recognition``). A method that
holds its accuracy while recognition collapses is robust; one whose accuracy falls with
recognition is not.

``perturb_grasp_scores`` and ``jitter_box`` are exported for the static-scene harness (grasp
score noise and ROI jitter on rendered scenes).
"""

from __future__ import annotations

import hashlib
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from ..grounding.settings import GroundingSettings
from .common import SkippedMethod, vocabulary_senses
from .imagenet import (
    ImageNetReport,
    embed_dataset_images,
    evaluate_imagenet,
    load_dataset,
    protocol_episodes,
)
from .methods import MethodSpec, default_methods, method_settings

UInt8Image = npt.NDArray[np.uint8]
FloatArray = npt.NDArray[np.float32]
NoiseKind = Literal["gaussian", "blur", "crop"]
NOISE_KINDS: tuple[NoiseKind, ...] = ("gaussian", "blur", "crop")
#: Kinds without randomness: one run per level whatever the noise seeds, and no seed in the id.
DETERMINISTIC_KINDS: frozenset[str] = frozenset({"blur"})
#: Default levels per kind; 0 (the identity) first. Gaussian sigma 64 is heavy sensor noise,
#: blur radius 8 px at 256 px leaves only the coarse shape, crop 0.75 keeps a quarter of the frame.
DEFAULT_LEVELS: dict[NoiseKind, tuple[float, ...]] = {
    "gaussian": (0.0, 8.0, 16.0, 32.0, 64.0),
    "blur": (0.0, 1.0, 2.0, 4.0, 8.0),
    "crop": (0.0, 0.25, 0.5, 0.75),
}
#: The encoder's resize target (``resize_center_crop``'s ``resize``): noise is applied at this scale.
ENCODER_SHORT_SIDE = 256
METRICS = ("top1", "top2", "mrr", "ndcg")


def level_label(kind: str, level: float) -> str:
    """Column heading of a level: ``σ=16``, ``r=2px``, ``keep 75%``."""
    if kind == "crop":
        return f"keep {1 - level:.0%}"
    return f"σ={level:g}" if kind == "gaussian" else f"r={level:g}px"


# ---------------------------------------------------------------------------------------------
# noise functions: deterministic for a given generator state; level 0 is the identity


def noise_rng(seed: int, kind: str, level: float, key: bytes = b"") -> np.random.Generator:
    """A generator seeded by (seed, kind, level, key) — never by call order or process."""
    digest = hashlib.sha256(key).digest()
    entropy = [seed, zlib.crc32(kind.encode()), zlib.crc32(repr(float(level)).encode()),
               int.from_bytes(digest[:8], "little")]
    return np.random.default_rng(np.random.SeedSequence(entropy))


def image_key(image: npt.NDArray[Any]) -> bytes:
    """Content key of an image (shape + pixels), for per-image noise seeds and memoization."""
    arr = np.ascontiguousarray(image)
    return hashlib.sha256(repr(arr.shape).encode() + arr.tobytes()).digest()


def add_gaussian_noise(image: UInt8Image, sigma: float, rng: np.random.Generator) -> UInt8Image:
    """``image + N(0, sigma^2)`` per pixel and channel (8-bit units), rounded and clipped."""
    if sigma < 0:
        raise ValueError(f"sigma must be >= 0, got {sigma}")
    if sigma == 0:
        return np.array(image, dtype=np.uint8, copy=True)
    noisy = image.astype(np.float32) + rng.normal(0.0, sigma, size=image.shape).astype(np.float32)
    out: UInt8Image = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    return out


def gaussian_blur(image: UInt8Image, radius: float) -> UInt8Image:
    """PIL's Gaussian blur with ``radius`` pixels (no randomness)."""
    from PIL import Image, ImageFilter

    if radius < 0:
        raise ValueError(f"blur radius must be >= 0, got {radius}")
    if radius == 0:
        return np.array(image, dtype=np.uint8, copy=True)
    blurred = Image.fromarray(np.ascontiguousarray(image)).filter(ImageFilter.GaussianBlur(radius))
    return np.asarray(blurred, dtype=np.uint8)


def jitter_box(
    box: Sequence[float], frac: float, rng: np.random.Generator, image_size: tuple[int, int]
) -> tuple[float, float, float, float]:
    """A random sub-box of ``box`` (x, y, w, h) keeping ``1 - frac`` of its area, same aspect.

    Models a detector's imprecise ROI: the jittered box lies inside the original at a uniformly
    random position, so its IoU with the original is exactly ``1 - frac`` (before clipping to
    ``image_size`` = (width, height)). ``frac`` 0 returns ``box`` unchanged and draws nothing.
    """
    if not 0.0 <= frac < 1.0:
        raise ValueError(f"jitter fraction must be in [0, 1), got {frac}")
    x, y, w, h = (float(v) for v in box)
    if w <= 0 or h <= 0:
        raise ValueError(f"box {tuple(box)} has no area")
    if frac == 0:
        return x, y, w, h
    scale = float(np.sqrt(1.0 - frac))
    nw, nh = w * scale, h * scale
    nx, ny = x + rng.uniform(0.0, w - nw), y + rng.uniform(0.0, h - nh)
    width, height = image_size
    x0, y0 = max(nx, 0.0), max(ny, 0.0)
    x1, y1 = min(nx + nw, float(width)), min(ny + nh, float(height))
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"box {tuple(box)} lies outside the {width}x{height} image")
    return x0, y0, x1 - x0, y1 - y0


def random_crop(image: UInt8Image, frac: float, rng: np.random.Generator) -> UInt8Image:
    """The whole image jittered as an ROI: a random window keeping ``1 - frac`` of the area."""
    h, w = image.shape[:2]
    if frac == 0:
        return np.array(image, dtype=np.uint8, copy=True)
    x, y, bw, bh = jitter_box((0.0, 0.0, float(w), float(h)), frac, rng, (w, h))
    x0, y0 = int(np.floor(x)), int(np.floor(y))
    x1, y1 = max(x0 + 1, int(np.ceil(x + bw))), max(y0 + 1, int(np.ceil(y + bh)))
    return np.array(image[y0:y1, x0:x1], dtype=np.uint8, copy=True)


def perturb_grasp_scores(
    scores: Sequence[float] | npt.NDArray[Any], sigma: float, rng: np.random.Generator
) -> npt.NDArray[np.float64]:
    """Grasp qualities plus ``N(0, sigma^2)`` each, clipped to [0, 1] (what E_grasp accepts).

    ``sigma`` 0 returns the scores unchanged (as floats) and draws nothing, so a sweep's level 0
    equals the clean run exactly.
    """
    if sigma < 0:
        raise ValueError(f"sigma must be >= 0, got {sigma}")
    arr = np.asarray(scores, dtype=np.float64).reshape(-1)  # [G]
    if sigma == 0:
        return arr.copy()
    out: npt.NDArray[np.float64] = np.clip(arr + rng.normal(0.0, sigma, size=arr.shape), 0.0, 1.0)
    return out


def to_encoder_scale(image: UInt8Image, short_side: int = ENCODER_SHORT_SIDE) -> UInt8Image:
    """Resize so the short side is ``short_side`` (bicubic), as the encoder's first step does."""
    from PIL import Image

    h, w = image.shape[:2]
    scale = short_side / min(h, w)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    if size == (w, h):
        return image
    resized = Image.fromarray(np.ascontiguousarray(image)).resize(size, Image.Resampling.BICUBIC)
    return np.asarray(resized, dtype=np.uint8)


def perturb_image(image: UInt8Image, kind: NoiseKind, level: float, rng: np.random.Generator) -> UInt8Image:
    """One perturbed copy of ``image`` (see the module docstring for the scales)."""
    if level == 0:
        return np.array(image, dtype=np.uint8, copy=True)
    if kind == "gaussian":
        return add_gaussian_noise(to_encoder_scale(image), level, rng)
    if kind == "blur":
        return gaussian_blur(to_encoder_scale(image), level)
    if kind == "crop":
        return random_crop(image, level, rng)
    raise ValueError(f"unknown noise kind {kind!r}; choose one of {', '.join(NOISE_KINDS)}")


def check_levels(kind: str, levels: Sequence[float]) -> None:
    """``ValueError`` naming the problem for an unknown kind or an out-of-range level."""
    if kind not in NOISE_KINDS:
        raise ValueError(f"unknown noise kind {kind!r}; choose one of {', '.join(NOISE_KINDS)}")
    for level in levels:
        if not np.isfinite(level) or level < 0 or (kind == "crop" and level >= 1):
            bound = "in [0, 1) (the fraction of the area cut away)" if kind == "crop" else "finite and >= 0"
            raise ValueError(f"{kind} level {level:g}: must be {bound}")


class PerturbedImageEncoder:
    """An image encoder that perturbs each crop before embedding it.

    The id names the perturbation, so the embedding caches of ``evaluate_imagenet`` keep one file
    per (encoder, kind, level, seed); level 0 keeps the base id (identical embeddings, shared
    cache). Results are also memoized in memory by crop content, so asking again is free.
    """

    def __init__(self, base: Any, kind: NoiseKind, level: float, seed: int = 0) -> None:
        check_levels(kind, [level])
        self.base = base
        self.kind: NoiseKind = kind
        self.level = float(level)
        self.seed = seed
        # the noise first: cache file names keep only the id's first 80 characters readable
        tag = f"noise:{kind}={level:g}" + ("" if kind in DETERMINISTIC_KINDS else f"@seed{seed}")
        self.id: str = base.id if level == 0 else f"{tag}+{base.id}"
        self.text_encoder_id: str = base.text_encoder_id
        self.dim: int = base.dim
        self._memo: dict[bytes, FloatArray] = {}

    def embed_images(self, crops: Sequence[UInt8Image], batch_size: int = 16) -> FloatArray:
        """``[N, d]`` embeddings of the perturbed crops (each distinct crop perturbed once)."""
        keys = [image_key(c) for c in crops]
        first: dict[bytes, int] = {}
        for i, k in enumerate(keys):
            first.setdefault(k, i)
        pending = [k for k in first if k not in self._memo]
        if pending:
            noisy = [perturb_image(crops[first[k]], self.kind, self.level,
                                   noise_rng(self.seed, self.kind, self.level, k)) for k in pending]
            vectors = self.base.embed_images(noisy, batch_size)  # [M, d]
            for k, vec in zip(pending, vectors, strict=True):
                self._memo[k] = np.asarray(vec, dtype=np.float32)
        if not keys:
            return np.zeros((0, self.dim), dtype=np.float32)
        return np.stack([self._memo[k] for k in keys]).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# the sweep


def parse_levels(specs: Sequence[str]) -> dict[NoiseKind, tuple[float, ...]]:
    """``["gaussian=0,8,16", "crop=0,0.5"]`` -> levels per kind, sorted, 0 added if missing."""
    out: dict[NoiseKind, tuple[float, ...]] = {}
    for spec in specs:
        name, sep, values = spec.partition("=")
        kind = next((k for k in NOISE_KINDS if k == name.strip()), None)
        if not sep or kind is None:
            raise ValueError(f"--levels {spec!r}: expected KIND=L1,L2,... with KIND one of {', '.join(NOISE_KINDS)}")
        try:
            levels = [float(v) for v in values.split(",") if v.strip()]
        except ValueError:
            raise ValueError(f"--levels {spec!r}: levels must be numbers") from None
        if not levels:
            raise ValueError(f"--levels {spec!r}: no levels")
        check_levels(kind, levels)
        out[kind] = tuple(sorted(set(levels) | {0.0}))
    return out


@dataclass
class RobustnessReport:
    """Metrics per noise kind, method and level (same episodes at every level)."""

    levels: dict[str, list[float]]
    methods: list[str]
    #: kind -> method -> one metrics dict (top1, top2, mrr, ndcg) per level, mean over noise seeds
    metrics: dict[str, dict[str, list[dict[str, float]]]]
    #: the same layout: standard deviation of each metric across noise seeds (0 with one seed)
    spread: dict[str, dict[str, list[dict[str, float]]]]
    #: kind -> fraction of photos whose p(o | r) is highest at their own class name, per level
    #: (None: unavailable)
    recognition: dict[str, list[float | None]]
    skipped: list[SkippedMethod]
    config: dict[str, Any]
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "benchmark": "imagenet-affordance under perceptual noise",
            "config": self.config, "levels": self.levels, "methods": self.methods,
            "metrics": self.metrics, "spread_across_noise_seeds": self.spread,
            "recognition": self.recognition,
            "skipped_methods": [{"method": s.name, "reason": s.reason} for s in self.skipped],
            "notes": self.notes,
        }

    def to_markdown(self) -> str:
        c = self.config
        out = [f"### Robustness to perceptual noise (ImageNet protocol, {c['episodes']} episodes/verb, "
               f"seed {c['seed']}, noise seeds {c['noise_seeds']}, T={c['temperature']:g}, {c['verbs']} verbs, labels "
               f"`{Path(c['labels']).name}`)\n",
               "Cells: single-affordance Top-1 / multi-affordance MRR, percent. The same episodes at "
               "every level. *Recognition*: photos whose p(o|r), read as the grounder reads it (names in their "
               "sense, the hubness correction), is highest at their own class name among the pool's classes.\n"]
        for kind, levels in self.levels.items():
            heads = [level_label(kind, v) for v in levels]
            out.append(f"\n#### {kind}\n")
            out.append("| Method | " + " | ".join(heads) + " | Δ Top-1 (max level) |")
            out.append("|---|" + "---:|" * (len(levels) + 1))
            several = len(self.config.get("noise_seeds", [])) > 1 and kind not in DETERMINISTIC_KINDS
            for method in self.methods:
                rows, spread = self.metrics[kind][method], self.spread[kind][method]
                cells = [_cell(r, d, several and v > 0) for r, d, v in zip(rows, spread, levels, strict=True)]
                top1 = [r.get("top1") for r in rows]
                delta = "–" if top1[0] is None or top1[-1] is None else f"{100 * (top1[-1] - top1[0]):+.1f}"
                out.append(f"| {method} | " + " | ".join(cells) + f" | {delta} |")
            rec = self.recognition.get(kind, [])
            if rec and all(r is not None for r in rec):
                cells = [f"{100 * float(r or 0):.1f}" for r in rec]
                change = 100 * (float(rec[-1] or 0) - float(rec[0] or 0))
                out.append("| *Recognition* | " + " | ".join(cells) + f" | {change:+.1f} |")
        for s in self.skipped:
            out.append(f"\n- **{s.name}** skipped: {s.reason}")
        if self.notes:
            out.append("")
            out += [f"- {n}" for n in self.notes]
        return "\n".join(out) + "\n"

    def plot(self, path: Path) -> Path:
        """Top-1 and MRR against the noise level, one column per kind (matplotlib, Agg)."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        kinds = list(self.levels)
        fig, axes = plt.subplots(2, len(kinds), figsize=(4.2 * len(kinds), 6.4), squeeze=False)
        for col, kind in enumerate(kinds):
            xs = self.levels[kind]
            for row, (metric, label) in enumerate((("top1", "Top-1"), ("mrr", "MRR"))):
                ax = axes[row][col]
                for method in self.methods:
                    ys = [100 * r.get(metric, float("nan")) for r in self.metrics[kind][method]]
                    errs = [100 * d.get(metric, 0.0) for d in self.spread[kind][method]]
                    ax.errorbar(xs, ys, yerr=errs if any(errs) else None, marker="o", capsize=3, label=method)
                rec = self.recognition.get(kind, [])
                if row == 0 and rec and all(r is not None for r in rec):
                    ax.plot(xs, [100 * float(r or 0) for r in rec], "k--", marker="x", label="recognition")
                ax.set_ylim(0, 100)
                ax.grid(alpha=0.3)
                ax.set_ylabel(f"{label} (%)")
                ax.set_xlabel({"gaussian": "noise σ (8-bit units, at 256 px)", "blur": "blur radius (px at 256 px)",
                               "crop": "area cut away (fraction)"}[kind])
                if row == 0:
                    ax.set_title(kind)
        handles, labels = axes[0][0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 6), fontsize=8, frameon=False)
        fig.suptitle(f"ImageNet protocol under perceptual noise ({self.config['episodes']} episodes/verb, "
                     f"{self.config['verbs']} verbs)")
        fig.tight_layout(rect=(0.0, 0.05, 1.0, 1.0))
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
        plt.close(fig)
        return path


def _cell(row: Mapping[str, float], spread: Mapping[str, float], show_spread: bool) -> str:
    """``Top-1 / MRR`` in percent, ``±`` the Top-1 spread across noise seeds where there is one."""
    top1 = f"{100 * row['top1']:.1f}" if "top1" in row else "–"
    if show_spread and "top1" in spread:
        top1 += f" ±{100 * spread['top1']:.1f}"
    mrr = f"{100 * row['mrr']:.1f}" if "mrr" in row else "–"
    return f"{top1} / {mrr}"


@dataclass(frozen=True)
class _Recogniser:
    """The photos of the pool's classes that the first method's bundle knows, their true classes,
    and that bundle's grounder over those names: built once per sweep, since none depends on the
    noise."""

    images: list[int]
    truth: npt.NDArray[np.intp]
    grounder: Any


def _recogniser(data: Any, class_ids: list[int], spec: MethodSpec, settings: GroundingSettings,
                text_encoder_id: str) -> _Recogniser | None:
    """p(o | r) read as ``spec``'s grounder reads it (``Grounder.image_hypotheses``: names in their
    sense, the hubness correction), so that the row measures the perception the methods act on.
    (Until 2026-12-07 it ranked the bundle's bare name embeddings, which the grounder stopped
    reading when the senses and the hubness correction became defaults.) None: no such bundle, a
    bundle in another text space than the image encoder's (``text_encoder_id``), or fewer than
    two known classes."""
    from ..grounding.grounder import Grounder
    from ..kb.bundle import BundleError, load_bundle

    try:
        bundle = load_bundle(spec.bundle, check_encoder=False)
    except BundleError:
        return None
    known = [c for c in class_ids if data.classes[c] in bundle.object_index]
    if len(known) < 2 or bundle.manifest.text_encoder.id != text_encoder_id:
        return None
    names = [data.classes[c] for c in known]
    senses = vocabulary_senses() if settings.sense_weight > 0 else None
    grounder = Grounder(bundle, method_settings(spec, settings, names, alpha=0.0), senses=senses)
    return _Recogniser([i for c in known for i in data.class_images[c]],
                       np.array([k for k, c in enumerate(known) for _ in data.class_images[c]]),
                       grounder)


def _recognition(data: Any, recogniser: _Recogniser | None, encoder: Any, cache_dir: Path | None) -> float | None:
    """Fraction of the recogniser's photos whose p(o | r) is highest at their own class name."""
    if recogniser is None:
        return None
    emb = embed_dataset_images(data, recogniser.images, encoder, cache_dir)  # [n, d]
    p = recogniser.grounder.image_hypotheses(emb)  # [n, C]
    return float((p.argmax(axis=1) == recogniser.truth).mean())


def evaluate_robustness(
    labels_path: Path,
    *,
    levels: Mapping[NoiseKind, Sequence[float]] | None = None,
    methods: Sequence[MethodSpec] | None = None,
    kb: Path | None = None,
    episodes: int = 100,
    seed: int = 0,
    noise_seeds: Sequence[int] = (0,),
    data_root: Path | None = None,
    pool: Sequence[str] | None = None,
    vocabulary: Sequence[str] | None = None,
    encoder: Any | None = None,
    cache_dir: Path | None = None,
    settings: GroundingSettings | None = None,
    threads: int | None = None,
) -> RobustnessReport:
    """Run ``evaluate_imagenet`` once per (kind, level, noise seed) with a ``PerturbedImageEncoder``.

    Arguments as for ``evaluate_imagenet``; ``levels`` maps kinds to levels (default
    ``DEFAULT_LEVELS``; 0 is added where missing). Each noisy level is run once per seed in
    ``noise_seeds`` (independent of the episode ``seed``) and its metrics are averaged, with the
    standard deviation across seeds in ``spread``: with few positive photos per verb, one noise
    draw on one photo can flip a verb's episodes, and several draws show how much. The clean level
    and blur (no randomness) do not depend on the noise seed and are evaluated once.
    """
    chosen = {k: tuple(sorted(set(map(float, v)) | {0.0})) for k, v in (levels or DEFAULT_LEVELS).items()}
    if not chosen:
        raise ValueError("no noise kinds to evaluate")
    for kind, values in chosen.items():
        check_levels(kind, values)
    seeds = list(dict.fromkeys(int(x) for x in noise_seeds))
    if not seeds:
        raise ValueError("need at least one noise seed")
    data = load_dataset(data_root)
    # the labels and the pool before the encoder loads (it loaded first, then bad labels failed)
    _, checked_pool, _, _ = protocol_episodes(labels_path, data, episodes=episodes, seed=seed, pool=pool)
    specs = list(methods) if methods is not None else default_methods(kb)
    if encoder is None:
        from ..encoders.conse import ConSEImageEncoder

        encoder = ConSEImageEncoder(threads=threads)
    class_ids = sorted(data.class_index[c] for c in (checked_pool if checked_pool is not None else data.classes))

    recogniser = (_recogniser(data, class_ids, specs[0], settings or GroundingSettings(), encoder.text_encoder_id)
                  if specs else None)

    def run(kind: NoiseKind, level: float, noise_seed: int) -> tuple[dict[str, dict[str, float]], float | None,
                                                                    ImageNetReport]:
        wrapped = PerturbedImageEncoder(encoder, kind, level, noise_seed)
        report = evaluate_imagenet(labels_path, methods=specs, episodes=episodes, seed=seed, data_root=data_root,
                                   pool=pool, vocabulary=vocabulary, encoder=wrapped, cache_dir=cache_dir,
                                   settings=settings)
        rec = _recognition(data, recogniser, wrapped, cache_dir)
        return {r.name: r.metrics for r in report.results}, rec, report

    clean_metrics, clean_rec, clean = run(NOISE_KINDS[0], 0.0, seeds[0])
    # the chance and label-oracle rows do not depend on perception: not plotted against noise
    names = [r.name for r in clean.results if not r.settings.get("reference")]
    metrics: dict[str, dict[str, list[dict[str, float]]]] = {}
    spread: dict[str, dict[str, list[dict[str, float]]]] = {}
    recognition: dict[str, list[float | None]] = {}
    for kind, values in chosen.items():
        metrics[kind] = {n: [] for n in names}
        spread[kind] = {n: [] for n in names}
        recognition[kind] = []
        for level in values:
            draws = seeds[:1] if kind in DETERMINISTIC_KINDS else seeds
            runs = [(clean_metrics, clean_rec)] if level == 0 else [run(kind, level, s)[:2] for s in draws]
            for n in names:
                mean: dict[str, float] = {}
                std: dict[str, float] = {}
                for m in METRICS:
                    vals = [r[n][m] for r, _ in runs if m in r.get(n, {})]
                    if vals:
                        mean[m], std[m] = float(np.mean(vals)), float(np.std(vals))
                metrics[kind][n].append(mean)
                spread[kind][n].append(std)
            recs = [r for _, r in runs if r is not None]
            recognition[kind].append(float(np.mean(recs)) if len(recs) == len(runs) else None)
    n_eval = episodes * int(clean.config["verbs"])
    notes = [f"sampling error: one Top-1 cell averages {n_eval} episodes (standard error ≤ "
             f"{100 * 0.5 / np.sqrt(max(n_eval, 1)):.1f} points over episodes); levels share their episodes, "
             "so differences between levels of one method are paired.",
             f"noisy levels average {len(seeds)} noise seed(s) {seeds}; ± is the standard deviation of Top-1 "
             "across them (how much one noise draw moves the result)." if len(seeds) > 1 else
             "one noise draw per photo and level (noise seed "
             f"{seeds[0]}); with few positive photos per verb, one photo's draw can move a verb's score a lot: "
             "use several noise seeds to average it out.",
             "noise is applied to whole photos before the image encoder (ConSE); the knowledge and "
             "text embeddings are untouched."]
    notes += [f"{s.verb} ({s.setting}) skipped: {s.reason}" for s in clean.skipped_verbs]
    config = {**clean.config, "noise_seeds": seeds, "levels": {k: list(v) for k, v in chosen.items()},
              "recognition_vocabulary": "pool classes known to the first method's bundle",
              "recognition_reads": "Grounder.image_hypotheses (names in their sense, the hubness correction)",
              "image_encoder": getattr(encoder, "id", None)}
    return RobustnessReport({k: list(v) for k, v in chosen.items()}, names, metrics, spread, recognition,
                            list(clean.skipped), config, notes)
