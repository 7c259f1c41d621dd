"""Benchmark: how the active look's settings move the choice, on the rendered dev scenes.

The active look (``runtime/sim/active_look.py``, opt-in ``--active-look``) looks again at the
``top_k`` lowest-energy ROIs from a camera 0.35 m away at 45° and grounds with the mixed
embedding (``weight`` on the look's, its colour image ``scale`` times the scene camera's). This
sweep chose its defaults: every episode of ``craft eval sim``'s protocol on the labels (sim-dev by
default: 105 episodes) is perceived once as the evaluation does (``perceive``, the defaults), then
grounded by CRAFT-E and direct-LLM without the look and with each setting; a choice counts when
it is the target's ROI (Detect). No pick is simulated: the look changes only the choice, and
``craft eval sim --active-look`` measures the whole episode at the chosen setting.

Run: ``.venv/bin/python benchmarks/bench_active_look.py [--labels CSV] [--json OUT] [--markdown OUT]``
(~6 min on 2 cores for sim-dev). Choose settings on sim-dev only.
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

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
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.sim.active_look import ActiveLookConfig
from craft_e.runtime.sim.env import SimEnv
from craft_e.runtime.sim.perceive import frame_look, grounding_rois, perceive
from craft_e.runtime.sim.pipeline import PipelineConfig, sim_vocabulary

METHODS = ("CRAFT-E", "direct-LLM")
TOP_K = (2, 3, 5)  # 5: every ROI of a scene (1 target + 4 distractors, as segmented)
SCALES = (1, 2)
WEIGHTS = (0.5, 1.0)


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
    runnable, _ = load_methods(select_methods(list(METHODS)), encoder.text_encoder_id)
    grounders = build_grounders(runnable, GroundingSettings(), sim_vocabulary())
    settings = list(itertools.product(TOP_K, SCALES, WEIGHTS))
    hits: dict[tuple[str, Any], int] = {(m, s): 0 for m in METHODS for s in [None, *settings]}
    cavity = any(g.cavity_cue_active for g in grounders.values())  # measured as ``craft eval sim`` does
    with SimEnv() as env:
        for n, spec in enumerate(specs):
            env.reset(spec.scene)
            perception = perceive(env, encoder, cfg, cavity=cavity)
            rois = grounding_rois(perception)
            seen: dict[int, dict[int, npt.NDArray[np.float32] | None]] = {s: {} for s in SCALES}
            for method in METHODS:
                grounder = grounders[method]
                chosen = grounder.ground(spec.verb, rois).chosen
                hits[method, None] += int(chosen is not None and chosen.index == perception.target_roi)
                for k, scale, weight in settings:
                    look = frame_look(env, perception, encoder,
                                      ActiveLookConfig(enabled=True, top_k=k, scale=scale, weight=weight))
                    look.seen = seen[scale]  # one render and encoding per ROI and scale, shared
                    chosen = look.ground(grounder, spec.verb, rois)[0].chosen
                    hits[method, (k, scale, weight)] += int(chosen is not None and chosen.index == perception.target_roi)
            print(f"\r{n + 1}/{len(specs)} episodes", end="", flush=True)
    print()
    total = len(specs)
    rows: list[dict[str, Any]] = [{"top_k": None, "scale": None, "weight": None, **{m: hits[m, None] for m in METHODS}}]
    rows += [{"top_k": k, "scale": s, "weight": w, **{m: hits[m, (k, s, w)] for m in METHODS}}
             for k, s, w in settings]
    default = ActiveLookConfig()
    lines = [f"### Active look settings: Detect on {total} episodes of `{args.labels.name}` "
             "(choice only, no pick simulated)\n",
             "| top_k | scale | weight | " + " | ".join(METHODS) + " |",
             "|---:|---:|---:|" + "---:|" * len(METHODS)]
    for r in rows:
        mark = " (default)" if (r["top_k"], r["scale"], r["weight"]) == (default.top_k, default.scale,
                                                                         default.weight) else ""
        setting = ("no look", "", "") if r["top_k"] is None else (f"{r['top_k']}{mark}", str(r["scale"]),
                                                                 str(r["weight"]))
        lines.append("| " + " | ".join(setting) + " | "
                     + " | ".join(f"{r[m]} ({100 * r[m] / total:.1f})" for m in METHODS) + " |")
    table = "\n".join(lines) + "\n"
    print(table)
    if args.markdown is not None:
        args.markdown.write_text(table, encoding="utf-8")
    if args.json is not None:
        args.json.write_text(json.dumps({"benchmark": "active look settings (Detect, choice only)",
                                         "labels": args.labels.name, "episodes": total, "rows": rows},
                                        indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
