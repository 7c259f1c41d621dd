"""Dev study: does the look-alike cue (``grounding/lookalike_cue.py``, ``--lookalikes``) help the
testbed's choices, on our development labels only?

Each rendered scene of ``craft eval static`` (sim-dev, 105 scenes, and sim-val, 378 scenes: 1
target + 4 distractors, seed 0, 3 layouts per pair) is rendered once and scored by CRAFT-E and
direct-LLM at the default settings, each with and without the cue, in the static protocol's
three settings (ground-truth grasps and ROIs; ground-truth grasps on predicted ROIs; GR-ConvNet
on predicted ROIs, the full pipeline). Scores are the static protocol's: the chosen ROI is the
target (IoU >= 0.5) and, for accuracy, its grasp is correct. Pairing the variants on the same
renders shows the cue's own effect; ``craft eval static --lookalikes`` gives the same numbers one
variant at a time. Recognition of isolated assets is ``craft eval recognition``.

Run: ``.venv/bin/python benchmarks/bench_lookalike_cue.py [--jobs 2] --json OUT --markdown OUT``
(~19 min on 2 cores).
"""

from __future__ import annotations

import argparse
import json
from functools import partial
from pathlib import Path
from typing import Any

from craft_e.arguments import output_file, positive_int
from craft_e.paths import SIM_DEV_LABELS, SIM_VAL_LABELS
from craft_e.runtime.evaluation.methods import build_grounders, load_methods, select_methods
from craft_e.runtime.evaluation.parallel import ordered_map
from craft_e.runtime.evaluation.sim_eval import default_encoder, load_sim_labels, make_episode_specs
from craft_e.runtime.evaluation.static_eval import NoiseLevel, _static_record, setting_ids
from craft_e.runtime.grounding.grounder import Grounder
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.sim.env import EnvConfig
from craft_e.runtime.sim.pipeline import sim_vocabulary

METHODS = ("CRAFT-E", "direct-LLM")
CUE = "+look-alike cue"
SETTINGS = setting_ids(["grconvnet"])
SETTING_NAMES = {"gt/gt": "GT grasp & ROI", "gt/predicted": "GT grasp", "grconvnet/predicted": "full pipeline"}


def paired_context() -> tuple[dict[str, Grounder], Any]:
    """Every method twice, without and with the cue (a ``--jobs`` worker builds this once)."""
    encoder = default_encoder(1)
    runnable, _ = load_methods(select_methods(list(METHODS)), encoder.text_encoder_id)
    grounders: dict[str, Grounder] = {}
    for cue in (False, True):
        built = build_grounders(runnable, GroundingSettings(lookalikes=cue or None), sim_vocabulary())
        grounders.update({name + (CUE if cue else ""): g for name, g in built.items()})
    return grounders, encoder


def score(labels: Path, jobs: int) -> dict[str, Any]:
    """Accuracy and Detect (percent) per setting and variant on the scenes of ``labels``."""
    env = EnvConfig()
    specs = make_episode_specs(load_sim_labels(labels), layouts=3, seed=0, env_config=env)
    run = partial(_static_record, ["grconvnet"], env, None, 1, [NoiseLevel()], SETTINGS, 0)
    records = list(ordered_map(run, specs, jobs=jobs, build=paired_context, context=paired_context()))
    variants = [m + c for m in METHODS for c in ("", CUE)]
    table: dict[str, dict[str, dict[str, float]]] = {}
    for setting in SETTINGS:
        table[setting] = {}
        for variant in variants:
            cells = [r["levels"]["clean"][setting]["methods"][variant] for r in records]
            table[setting][variant] = {
                "accuracy": round(100 * sum(c["success"] for c in cells) / len(cells), 2),
                "detect": round(100 * sum(c["detect"] for c in cells) / len(cells), 2)}
    changed = {v: [r["id"] for r in records
                   if r["levels"]["clean"]["grconvnet/predicted"]["methods"][v]["detect"]
                   != r["levels"]["clean"]["grconvnet/predicted"]["methods"][v.removesuffix(CUE)]["detect"]]
               for v in variants if v.endswith(CUE)}
    return {"labels": str(labels), "scenes": len(records), "table": table, "full_pipeline_detect_changed": changed}


def markdown(results: list[dict[str, Any]]) -> str:
    lines = ["### The look-alike cue on the rendered testbed scenes (static protocol, paired renders)", "",
             "Accuracy / Detect, percent. Each scene rendered once, every variant scored on it.", "",
             "| labels | setting | " + " | ".join(f"{m} | {m} {CUE}" for m in METHODS) + " |",
             "|---|---|" + "---:|" * (2 * len(METHODS))]
    for res in results:
        for setting in SETTINGS:
            row = res["table"][setting]
            cells = " | ".join(f"{row[m + c]['accuracy']:.1f} / {row[m + c]['detect']:.1f}"
                               for m in METHODS for c in ("", CUE))
            lines.append(f"| `{Path(res['labels']).name}` ({res['scenes']}) | {SETTING_NAMES[setting]} | {cells} |")
    lines.append("")
    for res in results:
        for variant, ids in res["full_pipeline_detect_changed"].items():
            lines.append(f"- `{Path(res['labels']).name}`, {variant}: full-pipeline Detect changed in "
                         f"{len(ids)} scenes.")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--jobs", type=positive_int, default=2)
    parser.add_argument("--labels", type=Path, action="append",
                        help="sim labels file (repeatable; default: sim-dev and sim-val)")
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("--markdown", type=output_file, default=None)
    args = parser.parse_args()
    results = [score(path, args.jobs) for path in (args.labels or [SIM_DEV_LABELS, SIM_VAL_LABELS])]
    text = markdown(results)
    print(text)
    if args.markdown:
        args.markdown.write_text(text, encoding="utf-8")
    if args.json:
        args.json.write_text(json.dumps({"results": results}, indent=1, sort_keys=True) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
