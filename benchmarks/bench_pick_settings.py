"""Benchmark: one object's episodes of ``craft eval sim``, re-run with other pick settings.

Why: an execution failure that repeats on one object (the wrench's "lost the grip while lifting")
is a question about pick settings, and answering it with the full evaluation costs half an
hour. This re-runs exactly the evaluation's episodes whose target is ``--target`` (the same
scenes, the same perception and grounding, CRAFT-E only, the same single-attempt pick), once per
setting, and prints each episode's outcome side by side. Scenes come from the whole labels file
(a verb's distractors depend on all its affording objects), so episode ids and scenes are those
of ``craft eval sim``.

Run: ``.venv/bin/python benchmarks/bench_pick_settings.py --target adjustable_wrench
--setting 0.004,0 --setting 0.002,-0.002 [--labels FILE ...] [--jobs 2] [--json OUT]``; a setting
is ``PickConfig.table_clearance,ClearanceConfig.margin`` in metres (default: the defaults),
optionally followed by ``,off`` or ``,SCALE``: the antipodal grasp fallback off, or on with its
scores times SCALE (``FallbackConfig.quality_scale``; omitted: the default, on at 1).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from collections import Counter
from functools import partial
from pathlib import Path
from typing import Any

from craft_e.arguments import output_file, positive_int
from craft_e.paths import SIM_DEV_LABELS, SIM_VAL_LABELS
from craft_e.runtime.evaluation.parallel import ordered_map
from craft_e.runtime.evaluation.sim_eval import (
    EpisodeSpec,
    load_sim_labels,
    make_episode_specs,
    run_one_episode,
    select_methods,
    worker_context,
)
from craft_e.runtime.grounding.settings import GroundingSettings
from craft_e.runtime.sim.episode import sim_configs
from craft_e.runtime.sim.fallback import FallbackConfig
from craft_e.runtime.sim.pipeline import PipelineConfig

METHOD = "CRAFT-E"


def target_specs(labels: list[Path], target: str) -> list[EpisodeSpec]:
    """The evaluation's episodes (3 layouts, seed 0) of every pair whose assets include ``target``."""
    specs: list[EpisodeSpec] = []
    for path in labels:
        loaded = load_sim_labels(path)
        pairs = tuple(pair for pair in loaded.pairs if target in pair.assets)
        specs += [s for s in make_episode_specs(dataclasses.replace(loaded, pairs=pairs), layouts=3, seed=0)
                  if s.scene.target == target]
    return specs


def _outcome(record: dict[str, Any]) -> dict[str, Any]:
    """The part of an episode record (``sim_eval.episode_record``) this benchmark reports."""
    method = record["methods"][METHOD]
    return {"id": record["id"], "failure": method["failure"], "chosen_object": method["chosen_object"],
            "detail": method["pick_detail"], "relocation": method.get("relocation", ""),
            "choice_error": method["choice_error"]}


def parse_setting(text: str) -> dict[str, float | None]:
    """``"0.004,0"`` -> ``{"table_clearance": 0.004, "clearance_margin": 0.0, "fallback": 1.0}``;
    a third field ``off`` (``"fallback": None``) or a number sets the grasp fallback."""
    fields = text.split(",")
    try:
        if len(fields) not in (2, 3):
            raise ValueError
        clearance, margin = float(fields[0]), float(fields[1])
        third = fields[2].strip() if len(fields) == 3 else "1"
        fallback = None if third == "off" else float(third)
        if fallback is not None:
            FallbackConfig(quality_scale=fallback)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected TABLE_CLEARANCE,MARGIN[,off|SCALE] (metres; "
                                         "SCALE in (0, 1]), e.g. 0.004,0 or 0.002,-0.002,off") from None
    return {"table_clearance": clearance, "clearance_margin": margin, "fallback": fallback}


def _label(setting: dict[str, Any]) -> str:
    fallback = "fallback off" if setting.get("fallback") is None else f"fallback x{setting['fallback']:g}"
    return (f"{setting['table_clearance'] * 1000:g} mm / {setting['clearance_margin'] * 1000:+g} mm / "
            f"{fallback}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--target", required=True, help="asset id, e.g. adjustable_wrench")
    parser.add_argument("--labels", type=Path, action="append", default=None,
                        help="labels file (repeatable; default: sim-dev and sim-val)")
    parser.add_argument("--setting", type=parse_setting, action="append", default=None,
                        help="TABLE_CLEARANCE,MARGIN in metres (repeatable; default: the defaults)")
    parser.add_argument("--jobs", type=positive_int, default=2)
    parser.add_argument("--json", type=output_file, default=None)
    args = parser.parse_args()

    specs = target_specs(args.labels or [SIM_DEV_LABELS, SIM_VAL_LABELS], args.target)
    if not specs:
        parser.error(f"no episode of the labels has target {args.target!r} (use an asset id)")
    env_config, pick, fingers = sim_configs("panda", wrist_look=True)
    runs: list[dict[str, Any]] = []
    default = {"table_clearance": pick.table_clearance, "clearance_margin": pick.clearance.margin,
               "fallback": FallbackConfig().quality_scale}
    for setting in args.setting or [default]:
        varied = dataclasses.replace(pick, table_clearance=setting["table_clearance"],
                                     clearance=dataclasses.replace(pick.clearance, margin=setting["clearance_margin"]))
        scale = setting["fallback"]
        fallback = FallbackConfig(enabled=False) if scale is None else FallbackConfig(quality_scale=scale)
        config = PipelineConfig(pick=varied, fingers=fingers, fallback=fallback)
        # the evaluation's own worker set-up and episode runner (``craft eval sim``), CRAFT-E only
        records = ordered_map(partial(run_one_episode, config, env_config, None), specs, jobs=args.jobs,
                              build=partial(worker_context, select_methods([METHOD]), 1, GroundingSettings()))
        episodes = [_outcome(r) for r in records]
        counts = Counter(e["failure"] for e in episodes)
        runs.append({"setting": setting, "outcomes": dict(counts), "episodes": episodes})
        print(f"{_label(setting)}: " + ", ".join(f"{k} {v}" for k, v in counts.most_common()))
    print("| episode | " + " | ".join(_label(r["setting"]) for r in runs) + " |")
    print("|---|" + "---|" * len(runs))
    for i, spec in enumerate(specs):
        print(f"| {spec.id} | " + " | ".join(r["episodes"][i]["failure"] for r in runs) + " |")
    if args.json is not None:
        args.json.write_text(json.dumps({"target": args.target, "episodes": len(specs), "method": METHOD,
                                         "runs": runs}, indent=1) + "\n")


if __name__ == "__main__":
    main()
