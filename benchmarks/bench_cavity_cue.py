"""Benchmark: how the cavity cue moves CRAFT-E's choice, on the rendered dev scenes.

The cavity cue (``runtime/grounding/cavity_cue.py``) weighs ``p(o | r)`` by whether an ROI shows an
open hollow in the overhead depth, against the knowledge base's "is concave" weights. Its detector
rates (``SEEN_IF_CONCAVE`` 0.6, ``SEEN_IF_NOT`` 0.03, a 2 cm threshold) were fixed before any
measurement; this sweep shows what other rates would have done, and what the depth bound (an
object thinner than the threshold cannot show so deep a hollow, ``DEPTH_BOUND``) changes at each. Every episode of ``craft eval
sim``'s protocol on the labels (sim-dev by default: 105 episodes) is perceived once as the
evaluation does (``perceive``, the defaults, cavities measured), then grounded by CRAFT-E without
the cue and with each setting; a choice counts when it is the target's ROI (Detect). No pick is
simulated: the cue changes only the choice, and ``craft eval sim`` measures whole episodes.

Run: ``.venv/bin/python benchmarks/bench_cavity_cue.py [--labels CSV] [--json OUT] [--markdown OUT]``
(~4 min on 2 cores for sim-dev, ~13 for sim-val). Choose settings on sim-dev only.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from craft_e.arguments import output_file, positive_int
from craft_e.paths import SIM_DEV_LABELS
from craft_e.runtime.evaluation.sim_eval import (
    build_grounders,
    default_encoder,
    load_methods,
    load_sim_labels,
    make_episode_specs,
    select_methods,
)
from craft_e.runtime.grounding import cavity_cue
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.perceive import grounding_rois, perceive
from craft_e.runtime.sim.pipeline import PipelineConfig, sim_vocabulary

METHOD = "CRAFT-E"
Setting = tuple[float, float, float, bool]
#: (SEEN_IF_CONCAVE, SEEN_IF_NOT, THRESHOLD_M, DEPTH_BOUND); the first is the shipped one
RATES: tuple[tuple[float, float, float], ...] = (
    (cavity_cue.SEEN_IF_CONCAVE, cavity_cue.SEEN_IF_NOT, cavity_cue.THRESHOLD_M),
    (0.3, 0.03, 0.02),
    (0.8, 0.03, 0.02),
    (0.6, 0.1, 0.02),
    (0.6, 0.03, 0.015),
    (0.6, 0.03, 0.03),
)
SETTINGS: tuple[Setting, ...] = tuple((*r, bound) for bound in (cavity_cue.DEPTH_BOUND, not cavity_cue.DEPTH_BOUND)
                                      for r in RATES)


def _set(setting: Setting) -> None:
    """Set the cue's module constants (the grounder reads them when it is built, the threshold
    again when it grounds)."""
    (cavity_cue.SEEN_IF_CONCAVE, cavity_cue.SEEN_IF_NOT, cavity_cue.THRESHOLD_M,
     cavity_cue.DEPTH_BOUND) = setting


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--labels", type=Path, default=SIM_DEV_LABELS)
    parser.add_argument("--layouts", type=positive_int, default=3)
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("--markdown", type=output_file, default=None)
    args = parser.parse_args()

    cfg = PipelineConfig()
    specs = make_episode_specs(load_sim_labels(args.labels), layouts=args.layouts, seed=0)
    encoder = default_encoder(cfg.torch_threads)
    runnable, _ = load_methods(select_methods([METHOD]), encoder.text_encoder_id)
    plain = build_grounders(runnable, GroundingSettings(cavity_cue=False), sim_vocabulary())[METHOD]
    shipped = SETTINGS[0]
    cued = {}
    try:
        for setting in SETTINGS:
            _set(setting)
            cued[setting] = build_grounders(runnable, GroundingSettings(), sim_vocabulary())[METHOD]
    finally:
        _set(shipped)
    hits: dict[Any, int] = {None: 0, **{s: 0 for s in SETTINGS}}
    moved: dict[Any, list[str]] = {s: [] for s in SETTINGS}
    with SimEnv() as env:
        for n, spec in enumerate(specs):
            env.reset(spec.scene)
            perception = perceive(env, encoder, cfg, cavity=True)
            rois = grounding_rois(perception)
            chosen = plain.ground(spec.verb, rois).chosen
            base = chosen is not None and chosen.index == perception.target_roi
            hits[None] += base
            for setting, grounder in cued.items():
                _set(setting)
                try:
                    chosen = grounder.ground(spec.verb, rois).chosen
                finally:
                    _set(shipped)
                hit = chosen is not None and chosen.index == perception.target_roi
                hits[setting] += hit
                if hit != base:
                    moved[setting].append(("+" if hit else "-") + spec.id)
            print(f"\r{n + 1}/{len(specs)} episodes", end="", flush=True)
    print()
    total = len(specs)
    rows: list[dict[str, Any]] = [{"seen_if_concave": None, "seen_if_not": None, "threshold_cm": None,
                                   "depth_bound": None, "detect": hits[None], "gained": [], "lost": []}]
    rows += [{"seen_if_concave": s[0], "seen_if_not": s[1], "threshold_cm": round(100 * s[2], 1),
              "depth_bound": s[3], "detect": hits[s],
              "gained": [m[1:] for m in moved[s] if m[0] == "+"],
              "lost": [m[1:] for m in moved[s] if m[0] == "-"]} for s in SETTINGS]
    lines = [f"### Cavity cue settings: {METHOD} Detect on {total} episodes of `{args.labels.name}` "
             "(choice only, no pick simulated)\n",
             "| P(hollow seen \\| concave) | P(hollow seen \\| not) | threshold (cm) | depth bound | Detect | "
             "gained | lost |",
             "|---:|---:|---:|---|---:|---:|---:|"]
    for r, setting in zip(rows, (None, *SETTINGS), strict=True):
        mark = " (default)" if setting == shipped else ""
        head = ("no cue", "", "", "") if setting is None else (
            f"{r['seen_if_concave']:g}{mark}", f"{r['seen_if_not']:g}", f"{r['threshold_cm']:g}",
            "yes" if r["depth_bound"] else "no")
        lost = ", ".join(r["lost"])
        lines.append("| " + " | ".join(head) + f" | {r['detect']} ({100 * r['detect'] / total:.1f}) | "
                     f"{len(r['gained'])} | {len(r['lost'])}{f' ({lost})' if lost else ''} |")
    table = "\n".join(lines) + "\n"
    print(table)
    if args.markdown is not None:
        args.markdown.write_text(table, encoding="utf-8")
    if args.json is not None:
        args.json.write_text(json.dumps({"benchmark": "cavity cue settings (Detect, choice only)",
                                         "method": METHOD, "labels": args.labels.name, "episodes": total,
                                         "rows": rows}, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
