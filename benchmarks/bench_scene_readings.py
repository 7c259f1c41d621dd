"""Benchmark: scene-level readings of p(o | r) — does "the regions of one scene are different
objects" name the testbed's objects better? (dev scenes; none is the default)

The grounder reads each region alone: ``p(o | r)`` is a softmax over the vocabulary of the
region's ConSE embedding, with the depth cues and the hubness correction. Two regions of one scene
may then both be "most likely a marker". The readings here share a name's mass out among the
regions of the scene, after the grounder's own ``p(o | r)`` and before the choice:

- **column cap c** (Sinkhorn-style): alternately scale each name's column down to a total of at
  most ``c`` over the scene's regions and renormalise each region's row (20 rounds);
- **explaining away a**: ``p(o | r) · Π_{r' ≠ r} (1 − p(o | r'))^a``, renormalised: a name is less
  likely here the more likely another region is it;
- **per-scene division a**: ``p(o | r) / (Σ_{r'} p(o | r'))^a``, renormalised (the hubness
  correction's idea within one scene).

The vocabulary's plain names cover several assets ("marker", "cup", "clamp"), so two regions of
one scene can rightly share a name; the cap at 2 allows that.

Every episode of ``craft eval sim``'s protocol on the labels (sim-dev by default, 105 per layout
seed) is perceived once as the evaluation does (``perceive``, the defaults). Then, per reading:

- **in-scene top-1 / top-5**: every region whose pixels are mostly one object of the vocabulary
  (the simulator's identity is read here only to score), named by the reading of CRAFT-E's
  ``p(o | r)``;
- **Detect**: CRAFT-E's and direct-LLM's choices (the target's ROI), no pick simulated: the
  lowest total energy with the reading of the method's own ``p(o | r)`` given to
  ``Grounder.energies``.

It also lists each seed's commonest wrong names under the default reading. The first reading
must reproduce ``Grounder.ground``'s choice in every episode (the benchmark
stops otherwise). Run: ``.venv/bin/python benchmarks/bench_scene_readings.py [--labels CSV]
[--seed 0 --seed 1 --seed 2] [--json OUT] [--markdown OUT]`` (~4 min per seed on 2 cores).
Choose on sim-dev only.
"""

from __future__ import annotations

import argparse
import collections
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from dev_scenes import METHODS, Episode, Probs, perceive_seed, publish, rank_of, seed_table

from craft_e.arguments import output_file, positive_int
from craft_e.paths import SIM_DEV_LABELS
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

CAP_ROUNDS = 20
CONFUSIONS = 8  # the commonest wrong names reported per seed


def column_cap(p: Probs, cap: float) -> Probs:
    """Rows stay distributions; each name's total over the scene's regions is brought to ≤ ``cap``."""
    q = p.copy()
    for _ in range(CAP_ROUNDS):
        q = q * np.minimum(1.0, cap / np.maximum(q.sum(axis=0), 1e-12))[None, :]
        q = q / q.sum(axis=1, keepdims=True)
    return q


def explained_away(p: Probs, a: float) -> Probs:
    """Each name down-weighted by the chance that another region of the scene is it."""
    log_not = np.log1p(-np.clip(p, 0.0, 1.0 - 1e-6))
    others = log_not.sum(axis=0)[None, :] - log_not
    q = p * np.exp(a * others)
    out: Probs = q / q.sum(axis=1, keepdims=True)
    return out


def per_scene_division(p: Probs, a: float) -> Probs:
    """Each name divided by its total mass in the scene to the power ``a``."""
    q = p / np.maximum(p.sum(axis=0, keepdims=True), 1e-12) ** a
    out: Probs = q / q.sum(axis=1, keepdims=True)
    return out


READINGS: dict[str, Callable[[Probs], Probs]] = {
    "each region alone (the default)": lambda p: p,
    "column cap 1": lambda p: column_cap(p, 1.0),
    "column cap 2": lambda p: column_cap(p, 2.0),
    "explaining away, a = 0.5": lambda p: explained_away(p, 0.5),
    "explaining away, a = 1": lambda p: explained_away(p, 1.0),
    "per-scene division, a = 0.25": lambda p: per_scene_division(p, 0.25),
    "per-scene division, a = 0.5": lambda p: per_scene_division(p, 0.5),
}


def _usable(roi: ROI) -> bool:
    """The ROIs ``Grounder.ground`` ranks (the others it excludes with a reason)."""
    return roi.image_embedding is not None and len(roi.grasp_scores) > 0 and max(roi.grasp_scores) > 0.0


def score(episodes: list[Episode], read: Callable[[Probs], Probs], grounders: dict[str, Grounder],
          check: bool) -> dict[str, Any]:
    """In-scene top-1 / top-5 and each method's Detect under one reading."""
    vocab = list(grounders[METHODS[0]].vocabulary)
    top1 = top5 = regions = 0
    detect = dict.fromkeys(METHODS, 0)
    confusions: collections.Counter[tuple[str, str]] = collections.Counter()  # (true, named) -> regions
    for ep in episodes:
        seen = [i for i, r in enumerate(ep.rois) if r.image_embedding is not None]
        if not seen:
            continue
        emb = np.stack([np.asarray(ep.rois[i].image_embedding, dtype=np.float32) for i in seen])
        extents = np.array([ep.rois[i].extents_m if ep.rois[i].extents_m is not None else (np.nan,) * 3
                            for i in seen], dtype=np.float64)
        cavities = np.array([np.nan if ep.rois[i].cavity_m is None else ep.rois[i].cavity_m for i in seen])
        # each method's own p(o | r) (its bundle's tables), read at the scene level
        p_of = {m: read(grounders[m].energies(ep.verb, emb, extents=extents, cavities=cavities).p_obj.astype(np.float64))
                for m in METHODS}
        p = p_of[METHODS[0]]
        for k, i in enumerate(seen):
            name = ep.names[i]
            if name is None or name not in vocab:
                continue
            rank = rank_of(p[k], vocab, name)
            if rank:
                confusions[(name, vocab[int(np.argmax(p[k]))])] += 1
            top1 += rank == 0
            top5 += rank < 5
            regions += 1
        ranked = [k for k, i in enumerate(seen) if _usable(ep.rois[i])]
        if not ranked:
            continue
        gmax = np.array([max(ep.rois[seen[k]].grasp_scores) for k in ranked], dtype=np.float32)
        for method in METHODS:
            terms = grounders[method].energies(ep.verb, emb[ranked], gmax, p_obj=p_of[method][ranked].astype(np.float32))
            chosen = seen[ranked[int(np.argsort(terms.total, kind="stable")[0])]]
            if check:
                pipeline = grounders[method].ground(ep.verb, ep.rois).chosen
                if pipeline is None or pipeline.index != chosen:
                    raise SystemExit(f"{method}, {ep.verb}: the default reading chose ROI {chosen}, "
                                     f"Grounder.ground {None if pipeline is None else pipeline.index}")
            detect[method] += chosen == ep.target_roi
    return {"episodes": len(episodes), "regions": regions, "top1": round(100 * top1 / max(regions, 1), 1),
            "top5": round(100 * top5 / max(regions, 1), 1), "detect": detect,
            "confusions": [[true, named, n] for (true, named), n in confusions.most_common(CONFUSIONS)]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--labels", type=Path, default=SIM_DEV_LABELS)
    parser.add_argument("--layouts", type=positive_int, default=3)
    parser.add_argument("--seed", type=int, action="append", default=None, help="layout seeds (repeat; default 0, 1, 2)")
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("--markdown", type=output_file, default=None)
    args = parser.parse_args()
    seeds: list[int] = sorted(set(args.seed or [0, 1, 2]))

    cfg = PipelineConfig()
    reference = default_encoder(cfg.torch_threads)
    runnable, _ = load_methods(select_methods(list(METHODS)), reference.text_encoder_id)
    grounders = build_grounders(runnable, GroundingSettings(), sim_vocabulary())
    perceived = {seed: perceive_seed(args.labels, args.layouts, seed, cfg, reference) for seed in seeds}
    rows = [{"reading": name, "seeds": [{"seed": seed, **score(perceived[seed], read, grounders, check=n == 0)}
                                        for seed in seeds]}
            for n, (name, read) in enumerate(READINGS.items())]
    title = (f"### Scene-level readings of p(o | r): in-scene recognition and the choice on `{args.labels.name}` "
             f"(layout seeds {', '.join(map(str, seeds))}; choice only, no pick simulated)")
    confused = "\n".join(f"- seed {r['seed']}: " + ", ".join(f"{t} → {n} ({c})" for t, n, c in r["confusions"])
                          for r in rows[0]["seeds"])
    table = (seed_table(title, rows, seeds) + "\n"
             f"Commonest wrong names, each region alone (true → named (regions)):\n{confused}\n")
    publish(table, {"benchmark": "scene-level readings of p(o|r) (in-scene recognition, Detect)",
                    "labels": args.labels.name, "layouts": args.layouts, "seeds": seeds, "encoder": reference.id,
                    "cap_rounds": CAP_ROUNDS, "rows": rows}, args.markdown, args.json)

if __name__ == "__main__":
    main()
