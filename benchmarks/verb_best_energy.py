"""How far below -1 each testbed verb's best object sits, per bundle: the fact behind ``aff_norm``.

For every verb of the sim-dev and sim-val labels, the most negative E_aff (the bundle's own form,
unscaled) over the 62 sim object names and over all of the bundle's objects, and the means per
labels file. ``docs/energy_weights.md`` quotes it: the normalized product leaves verbs whose
properties are alternatives (*play*, *serve*, *carry*) far from -1, which is why each verb's row
is scaled by its best bundle object by default (``GroundingSettings.aff_norm``). Reads no images
and no withheld labels.

Run: ``.venv/bin/python benchmarks/verb_best_energy.py [--kb NAME ...] [--json OUT]`` (seconds).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from craft_e.arguments import output_file
from craft_e.paths import KB_DIR, SIM_DEV_LABELS, SIM_VAL_LABELS
from craft_e.runtime.evaluation.sim_eval import load_sim_labels
from craft_e.runtime.grounding.grounder import affordance_energy_in_form
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.runtime.sim.pipeline import sim_vocabulary


def verb_bests(kb: str, labels: Path, names: list[str]) -> dict[str, Any]:
    """``{"verbs": {verb: {"sim": (E, object), "kb": (E, object)}}, "mean_sim", "mean_kb"}``."""
    bundle = load_bundle(KB_DIR / kb)
    energy = affordance_energy_in_form(bundle, bundle.manifest.energy.form)  # [V, O_bundle]
    objects = list(bundle.manifest.objects)
    sim_cols = [bundle.object_index[n] for n in names if n in bundle.object_index]
    verbs: dict[str, Any] = {}
    for verb in load_sim_labels(labels).verbs:
        vi = bundle.verb_index.get(verb)
        if vi is None:
            continue  # grounded through the open-vocabulary fallback: no row of its own
        row = energy[vi]
        s = sim_cols[int(np.argmin(row[sim_cols]))]
        k = int(np.argmin(row))
        verbs[verb] = {"sim": [round(float(row[s]), 4), objects[s]], "kb": [round(float(row[k]), 4), objects[k]]}
    return {"verbs": verbs,
            "mean_sim": round(float(np.mean([v["sim"][0] for v in verbs.values()])), 4),
            "mean_kb": round(float(np.mean([v["kb"][0] for v in verbs.values()])), 4)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--kb", action="append", default=None,
                        help="bundle names under artifacts/kb (default: craft-e-default, direct-llm)")
    parser.add_argument("--json", type=output_file, default=None)
    args = parser.parse_args()
    names = list(sim_vocabulary())
    out: dict[str, Any] = {}
    for kb in args.kb or ["craft-e-default", "direct-llm"]:
        if not (KB_DIR / kb / "manifest.json").is_file():
            parser.error(f"--kb {kb}: no bundle {KB_DIR / kb}")
        out[kb] = {}
        for labels in (SIM_DEV_LABELS, SIM_VAL_LABELS):
            found = out[kb][labels.stem] = verb_bests(kb, labels, names)
            print(f"{kb} {labels.stem}: best sim object mean {found['mean_sim']:.2f}, "
                  f"best KB object mean {found['mean_kb']:.2f} ({len(found['verbs'])} verbs)")
            for verb, v in found["verbs"].items():
                print(f"  {verb:10s} sim {v['sim'][0]:6.2f} ({v['sim'][1]})  kb {v['kb'][0]:6.2f} ({v['kb'][1]})")
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
