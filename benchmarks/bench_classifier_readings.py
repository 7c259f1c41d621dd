"""Benchmark: other readings of the ImageNet classifier on the crops the robot sees (dev scenes).

ConSE (``runtime/encoders/conse.py``) turns one classifier's probabilities (EfficientNet-Lite1, its
softmax at temperature 2 over the top-10 classes) into a point among the class names. This asks
whether more of the classifier's own evidence names the testbed's objects better: its mirror
image averaged in (test-time augmentation), the second classifier that installs offline
(EfficientNet-Lite0) averaged in (an ensemble, arithmetic or geometric), and the scenes' own
class prior divided out (label-shift correction: ``p(c | x) / prior(c) ** 0.5``, the prior the
mean of the classifier's probabilities over the *other* seeds' crops, no label read). Every
reading goes through the same ConSE step and the grounder's defaults (hubness, senses, size and
cavity cues).

Every episode of ``craft eval sim``'s protocol on the labels (sim-dev by default: 105 per layout
seed) is perceived once as the evaluation does (``perceive``, the defaults); each crop the
encoder sees is classified once more by each extra classifier. Then, per reading:

- **in-scene top-1 / top-5**: every region whose pixels are mostly one object of the vocabulary
  (the simulator's identity is read here only to score), named by ``p(o | r)``;
- **Detect**: CRAFT-E's and direct-LLM's choices (the target's ROI), no pick simulated.

The first row must reproduce the pipeline's own embeddings (checked to 1e-5: the benchmark stops
otherwise). Run: ``.venv/bin/python benchmarks/bench_classifier_readings.py [--labels CSV]
[--seed 0 --seed 1 --seed 2] [--json OUT] [--markdown OUT]`` (~28 min on 2 busy cores for three
seeds of sim-dev). Choose on sim-dev only.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from dev_scenes import METHODS, Episode, Probs, perceive_seed, publish, rank_of, seed_table

from craft_e.arguments import output_file, positive_int
from craft_e.paths import SIM_DEV_LABELS
from craft_e.runtime.encoders.conse import ConSEImageEncoder, conse_embed
from craft_e.runtime.evaluation.sim_eval import (
    build_grounders,
    default_encoder,
    load_methods,
    select_methods,
)
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.perception.roi import ROI
from craft_e.runtime.sim.pipeline import PipelineConfig, sim_vocabulary

#: the extra classifications of each crop: name -> (classifier, mirror TTA)
EXTRA = {"lite1_mirror": ("efficientnet-lite1", 2), "lite0": ("efficientnet-lite0", 1),
         "lite0_mirror": ("efficientnet-lite0", 2)}
PRIOR_EXPONENT = 0.5


class RecordingEncoder:
    """The pipeline's encoder, unchanged, that also keeps the class probabilities it computes
    (``encode_with_classes`` embeds exactly these)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.crops: list[Any] = []
        self.probs: Probs | None = None

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def class_probabilities(self, crops: Sequence[Any], batch_size: int = 16) -> Any:
        probs = self.inner.class_probabilities(crops, batch_size)
        self.crops, self.probs = list(crops), np.asarray(probs, dtype=np.float64)
        return probs


def classified(recorder: RecordingEncoder, extra: dict[str, ConSEImageEncoder]) -> Callable[[list[ROI]], dict[str, Probs]]:
    """``perceive_seed``'s ``extra``: the probabilities the pipeline's classifier just gave each
    crop, and each extra classifier's of the same crops."""
    def record(rois: list[ROI]) -> dict[str, Probs]:
        assert recorder.probs is not None and len(recorder.probs) == len(rois)
        probs = {"lite1": recorder.probs}
        for key, encoder in extra.items():
            probs[key] = np.asarray(encoder.class_probabilities(recorder.crops), dtype=np.float64)
        recorder.probs = None  # the next episode's perception sets it again
        return probs

    return record


def _normalized(p: Probs) -> Probs:
    out: Probs = p / p.sum(axis=1, keepdims=True)
    return out


def readings(priors: dict[int, Probs]) -> dict[str, Callable[[dict[str, Probs], int], Probs]]:
    """Reading name -> f(an episode's classifications, its seed) -> ``[N, 1000]`` probabilities."""
    def geometric(p: dict[str, Probs], _: int) -> Probs:
        log = (np.log(np.maximum(p["lite1"], 1e-12)) + np.log(np.maximum(p["lite0"], 1e-12))) / 2
        return _normalized(np.exp(log - log.max(axis=1, keepdims=True)))

    return {
        "Lite1 (the default)": lambda p, _: p["lite1"],
        "Lite1 + mirror image": lambda p, _: p["lite1_mirror"],
        "Lite0": lambda p, _: p["lite0"],
        "Lite1 + Lite0, mean": lambda p, _: (p["lite1"] + p["lite0"]) / 2,
        "Lite1 + Lite0, each + mirror, mean": lambda p, _: (p["lite1_mirror"] + p["lite0_mirror"]) / 2,
        "Lite1 + Lite0, geometric mean": geometric,
        f"Lite1, the other seeds' class prior divided out (^{PRIOR_EXPONENT:g})":
            lambda p, seed: _normalized(p["lite1"] / priors[seed][None, :] ** PRIOR_EXPONENT),
    }


def score(episodes: list[Episode], read: Callable[[dict[str, Probs], int], Probs], seed: int,
          encoder: ConSEImageEncoder, grounders: dict[str, Grounder], check: bool) -> dict[str, Any]:
    """In-scene top-1 / top-5 and each method's Detect under one reading, on one seed."""
    vocab = list(grounders[METHODS[0]].vocabulary)
    top1 = top5 = regions = 0
    detect = dict.fromkeys(METHODS, 0)
    for ep in episodes:
        if not ep.rois:
            continue
        emb = conse_embed(read(ep.probs, seed), encoder.class_embeddings, encoder.top_k, encoder.temperature)
        if check:
            worst = max(float(np.abs(emb[i] - np.asarray(r.image_embedding)).max()) for i, r in enumerate(ep.rois))
            if worst > 1e-5:
                raise SystemExit(f"the default reading differs from the pipeline's embeddings by {worst:.2e}")
        rois = [dataclasses.replace(r, image_embedding=emb[i].astype(np.float32)) for i, r in enumerate(ep.rois)]
        extents = np.array([r.extents_m if r.extents_m is not None else (np.nan,) * 3 for r in rois])
        cavities = np.array([np.nan if r.cavity_m is None else r.cavity_m for r in rois])
        p = grounders[METHODS[0]].energies(ep.verb, np.stack([np.asarray(r.image_embedding) for r in rois]),
                                           extents=extents, cavities=cavities).p_obj
        for i, name in enumerate(ep.names):
            if name is None or name not in vocab:
                continue
            rank = rank_of(p[i], vocab, name)
            top1 += rank == 0
            top5 += rank < 5
            regions += 1
        for method in METHODS:
            chosen = grounders[method].ground(ep.verb, rois).chosen
            detect[method] += chosen is not None and chosen.index == ep.target_roi
    return {"seed": seed, "episodes": len(episodes), "regions": regions,
            "top1": round(100 * top1 / max(regions, 1), 1), "top5": round(100 * top5 / max(regions, 1), 1),
            "detect": detect}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--labels", type=Path, default=SIM_DEV_LABELS)
    parser.add_argument("--layouts", type=positive_int, default=3)
    parser.add_argument("--seed", type=int, action="append", default=None,
                        help="layout seeds (repeat; default 0, 1 and 2; the prior row needs two or more)")
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("--markdown", type=output_file, default=None)
    args = parser.parse_args()
    seeds: list[int] = sorted(set(args.seed or [0, 1, 2]))
    if len(seeds) < 2:
        parser.error("give two or more --seed values: each seed's class prior comes from the others")

    cfg = PipelineConfig()
    extra = {key: ConSEImageEncoder(threads=cfg.torch_threads, preprocess="fit", classifier=clf, tta=tta)
             for key, (clf, tta) in EXTRA.items()}
    reference = default_encoder(cfg.torch_threads)
    assert isinstance(reference, ConSEImageEncoder)
    runnable, _ = load_methods(select_methods(list(METHODS)), reference.text_encoder_id)
    grounders = build_grounders(runnable, GroundingSettings(), sim_vocabulary())
    recorder = RecordingEncoder(default_encoder(cfg.torch_threads))
    perceived = {seed: perceive_seed(args.labels, args.layouts, seed, cfg, recorder, classified(recorder, extra))
                 for seed in seeds}
    crops_probs = {seed: np.concatenate([ep.probs["lite1"] for ep in eps if ep.probs]) for seed, eps in perceived.items()}
    priors = {seed: np.concatenate([crops_probs[s] for s in seeds if s != seed]).mean(axis=0) + 1e-6
              for seed in seeds}

    rows: list[dict[str, Any]] = []
    for n, (name, read) in enumerate(readings(priors).items()):
        per_seed = [score(perceived[seed], read, seed, reference, grounders, check=n == 0) for seed in seeds]
        rows.append({"reading": name, "seeds": per_seed})
    title = (f"### Readings of the classifier: in-scene recognition and the choice on `{args.labels.name}` "
             f"(layout seeds {', '.join(map(str, seeds))}; choice only, no pick simulated)")
    table = seed_table(title, rows, seeds)
    publish(table, {"benchmark": "readings of the classifier (in-scene recognition, Detect)",
                    "labels": args.labels.name, "layouts": args.layouts, "seeds": seeds, "encoder": reference.id,
                    "prior_exponent": PRIOR_EXPONENT, "rows": rows}, args.markdown, args.json)

if __name__ == "__main__":
    main()
