"""Dev study: the weight of E_align (gamma) in the paper's energy, on our development labels only.

The paper fixes alpha = beta = gamma = 1 (Sec. IV). On the ImageNet dev table affordance-only
(gamma = 0) beats CRAFT-E (gamma = 1), so before anyone moves the default this script measures
gamma on *every* dev protocol that has images, per verb, with leave-one-verb-out selection:

* ``imagenet``: ``craft eval imagenet``'s episodes on ``tests/fixtures/imagenet_dev_labels.json``
  (6 verbs, single-affordance top-1, alpha = 0 as that protocol fixes);
* ``static``: ``craft eval static``'s rendered testbed scenes on ``artifacts/labels/sim_dev_labels.csv``
  (12 verbs, 105 scenes), accuracy with GR-ConvNet grasps and predicted ROIs (the full pipeline)
  and with ground-truth grasps and ROIs (knowledge and recognition only).

Leave-one-verb-out: each (protocol, verb) unit in turn is held out, gamma is chosen by the mean
score of the other units (ties go to the paper's 1.0, then to the larger gamma), and the held-out
unit is scored with it. The withheld benchmark labels are never read.

Run: ``.venv/bin/python benchmarks/bench_energy_weights.py [--jobs 2] --json OUT --markdown OUT``
(~6 min on 2 cores; ``--no-static`` runs the ImageNet part alone in ~20 s).
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path
from typing import Any

from craft_e.arguments import number_list, output_file
from craft_e.paths import KB_DIR, SIM_DEV_LABELS
from craft_e.runtime.evaluation.methods import MethodSpec

IMAGENET_DEV = Path("tests/fixtures/imagenet_dev_labels.json")
PAPER_GAMMA = 1.0
STATIC_SETTINGS = {"full": "grconvnet/predicted", "gt": "gt/gt"}  # column -> static setting key


def _row(kb: str, gamma: float) -> str:
    return f"{kb} @ gamma {gamma:g}"


def imagenet_scores(specs: list[MethodSpec], threads: int) -> dict[str, dict[str, float]]:
    """``{method: {verb: top-1}}`` on the ImageNet dev episodes (100 per verb, seed 0)."""
    from craft_e.runtime.evaluation.imagenet import evaluate_imagenet

    report = evaluate_imagenet(IMAGENET_DEV, methods=specs, threads=threads)
    return {r.name: {v: m["top1"] for v, m in r.per_verb.items()} for r in report.results
            if r.name in {s.name for s in specs}}


def static_scores(specs: list[MethodSpec], jobs: int,
                  labels: Path = SIM_DEV_LABELS) -> dict[str, dict[str, dict[str, float]]]:
    """``{column: {method: {verb: accuracy}}}`` on the rendered scenes of ``labels`` (sim-dev)."""
    from craft_e.runtime.evaluation.static_eval import evaluate_static

    report = evaluate_static(labels, backends=("grconvnet",), methods=specs, jobs=jobs).to_dict()
    hits: dict[str, dict[str, dict[str, list[float]]]] = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for ep in report["episodes"]:
        for column, key in STATIC_SETTINGS.items():
            for name, outcome in ep["levels"]["clean"][key]["methods"].items():
                hits[column][name][ep["verb"]].append(float(outcome["success"]))
    return {c: {m: {v: sum(x) / len(x) for v, x in verbs.items()} for m, verbs in by_m.items()}
            for c, by_m in hits.items()}


def leave_one_verb_out(per_gamma: dict[float, dict[str, float]]) -> dict[str, Any]:
    """Choose gamma on all units but one, score the held-out unit; see the module docstring."""
    gammas = sorted(per_gamma)
    units = sorted(per_gamma[gammas[0]])
    chosen: dict[str, float] = {}
    for held in units:
        def train(g: float, held: str = held) -> tuple[float, bool, float]:
            rest = [per_gamma[g][u] for u in units if u != held]
            return sum(rest) / len(rest), g == PAPER_GAMMA, g
        chosen[held] = max(gammas, key=train)
    held_out = sum(per_gamma[chosen[u]][u] for u in units) / len(units)
    # how much one unit decides: the unit whose score moves most with gamma, and the fixed-gamma
    # means without it
    swing = max(units, key=lambda u: max(per_gamma[g][u] for g in gammas) - min(per_gamma[g][u] for g in gammas))
    return {"units": len(units), "chosen": chosen, "held_out_mean": held_out,
            "fixed_mean": {g: sum(per_gamma[g].values()) / len(units) for g in gammas},
            "largest_swing": {"unit": swing, "scores": {g: per_gamma[g][swing] for g in gammas},
                              "fixed_mean_without": {g: sum(per_gamma[g][u] for u in units if u != swing)
                                                     / max(1, len(units) - 1) for g in gammas}}}


def _bundle_name(name: str) -> str:
    """--kb: a bundle folder under artifacts/kb, checked before minutes of ImageNet scoring."""
    if not (KB_DIR / name / "manifest.json").is_file():
        shipped = ", ".join(sorted(p.name for p in KB_DIR.iterdir() if (p / "manifest.json").is_file()))
        raise argparse.ArgumentTypeError(f"no bundle {KB_DIR / name}; shipped: {shipped}")
    return name


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--gammas", type=number_list, default="0,0.1,0.25,0.5,1")
    parser.add_argument("--kb", action="append", type=_bundle_name, default=None,
                        help="bundle names under artifacts/kb "
                        "(default: craft-e-default, direct-llm)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--no-static", action="store_true")
    parser.add_argument("--static-labels", type=Path, default=SIM_DEV_LABELS,
                        help="labels of the rendered scenes (default: sim-dev; artifacts/labels/sim_val_labels.csv "
                        "measures on the verbs no default was chosen on)")
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("--markdown", type=output_file, default=None)
    args = parser.parse_args()
    if not args.no_static and not args.static_labels.is_file():
        parser.error(f"--static-labels {args.static_labels}: no such labels file")
    gammas: list[float] = args.gammas
    kbs = args.kb or ["craft-e-default", "direct-llm"]
    specs = [MethodSpec(_row(kb, g), f"{kb}, beta 1, gamma {g:g}", KB_DIR / kb, beta=1.0, gamma=g)
             for kb in kbs for g in gammas]

    columns: dict[str, dict[str, dict[str, float]]] = {"imagenet": imagenet_scores(specs, args.threads)}
    if not args.no_static:
        columns |= {f"static_{c}": s for c, s in static_scores(specs, args.jobs, args.static_labels).items()}
    lvo = {}
    for kb in kbs:
        # one unit per (protocol, verb): the ImageNet verbs and the static full pipeline's verbs
        units = {g: {f"{col}:{v}": s for col in ("imagenet", "static_full") if col in columns
                     for v, s in columns[col][_row(kb, g)].items()} for g in gammas}
        lvo[kb] = leave_one_verb_out(units)

    lines = ["| KB | gamma | " + " | ".join(columns) + " |", "|---|---:|" + "---:|" * len(columns)]
    for kb in kbs:
        for g in gammas:
            means = [sum(columns[c][_row(kb, g)].values()) / len(columns[c][_row(kb, g)]) for c in columns]
            lines.append(f"| {kb} | {g:g} | " + " | ".join(f"{100 * m:.1f}" for m in means) + " |")
    lines.append("")
    for kb, entry in lvo.items():
        counts = {g: sum(1 for c in entry["chosen"].values() if c == g) for g in gammas}
        lines.append(f"- {kb}: leave-one-verb-out over {entry['units']} units, held-out mean "
                     f"{100 * entry['held_out_mean']:.1f} (gamma fixed at 1: "
                     f"{100 * entry['fixed_mean'][PAPER_GAMMA]:.1f}; at 0: {100 * entry['fixed_mean'].get(0.0, float('nan')):.1f}); "
                     "gamma chosen " + ", ".join(f"{g:g}: {n}x" for g, n in counts.items() if n))
        swing = entry["largest_swing"]
        lines.append(f"  - the unit gamma moves most: {swing['unit']} ("
                     + ", ".join(f"{g:g}: {100 * v:.0f}" for g, v in swing["scores"].items())
                     + "); without it, the mean at each fixed gamma: "
                     + ", ".join(f"{g:g}: {100 * v:.1f}" for g, v in swing["fixed_mean_without"].items()))
    table = "\n".join(lines)
    print(table)
    n_static = len(next(iter(columns["static_full"].values()))) if "static_full" in columns else 0
    if args.markdown is not None:
        args.markdown.write_text(
            "### E_align weight (gamma) on the dev labels (`benchmarks/bench_energy_weights.py`)\n\n"
            "Mean over verbs of: ImageNet dev single-affordance top-1 (6 verbs); rendered scenes' "
            f"accuracy (labels `{args.static_labels.name}`, {n_static} verbs) with GR-ConvNet + predicted "
            "ROIs (`static_full`) and with GT grasps + GT ROIs (`static_gt`). Percent.\n\n"
            + table + "\n", encoding="utf-8")
    if args.json is not None:
        args.json.write_text(json.dumps({"gammas": gammas, "per_verb": columns, "leave_one_verb_out": lvo},
                                        indent=1, sort_keys=True) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
