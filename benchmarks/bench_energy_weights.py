"""Dev study: the weights of E_aff (beta) and E_align (gamma) in the paper's energy, and E_aff's
per-verb scaling, on our development labels only.

The paper fixes alpha = beta = gamma = 1 (Sec. IV) for its sum-tanh E_aff, whose affording objects
sit at -1. Our default E_aff (the normalized product, issue 9) rarely reaches -1, and how far below
it a verb's best object stays depends on the verb, so this script measures the weights on *every*
dev protocol that has images, per verb, with leave-one-verb-out selection, for each bundle both
as is and with ``aff_norm`` "verb-best" (each verb's best bundle object scaled to -1; ``--aff-norm``
picks which):

* ``imagenet``: ``craft eval imagenet``'s episodes on ``tests/fixtures/imagenet_dev_labels.json``
  (6 verbs, single-affordance top-1, alpha = 0 as that protocol fixes);
* ``static_full:<labels>`` / ``static_gt:<labels>``: ``craft eval static``'s rendered testbed
  scenes of each ``--static-labels`` file (default: sim-dev, 12 verbs, 105 scenes, and sim-val,
  23 verbs, 378 scenes), accuracy with GR-ConvNet grasps and predicted ROIs (the full pipeline)
  and with ground-truth grasps and ROIs (knowledge and recognition only).

Leave-one-verb-out: each unit — an ImageNet verb or a full-pipeline verb of one labels file — in
turn is held out, the weights (beta, gamma) are chosen by the mean score of the other units (ties
go to the paper's (1, 1), then to the larger weights), and the held-out unit is scored with them;
each (bundle, scaling) row set has its own, so their held-out means compare the scalings as
procedures. The withheld benchmark labels are never read. The default grid is the one the
shipped default (beta 8, gamma 1, scaled per verb; ``grounding/settings.py``) was chosen from.

Run: ``.venv/bin/python benchmarks/bench_energy_weights.py [--jobs 2] --json OUT --markdown OUT``
(~15 min on 2 cores; ``--no-static`` runs the ImageNet part alone in ~30 s).
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path
from typing import Any

from craft_e.arguments import number_list, output_file
from craft_e.paths import KB_DIR, SIM_DEV_LABELS, SIM_VAL_LABELS
from craft_e.runtime.evaluation.methods import MethodSpec
from craft_e.runtime.grounding.settings import AFF_NORMS, AffNorm

IMAGENET_DEV = Path("tests/fixtures/imagenet_dev_labels.json")
Weights = tuple[float, float]  # (beta, gamma)
PAPER_WEIGHTS: Weights = (1.0, 1.0)
STATIC_SETTINGS = {"full": "grconvnet/predicted", "gt": "gt/gt"}  # column -> static setting key


def _row(kb: str, weights: Weights) -> str:
    return f"{kb} @ beta {weights[0]:g}, gamma {weights[1]:g}"


def _variant(kb: str, norm: AffNorm) -> str:
    """The row-set name of a bundle under an E_aff scaling (the bundle alone when unscaled)."""
    return kb if norm == "none" else f"{kb} + {norm}"


def _norm_of(variant: str) -> AffNorm:
    """The E_aff scaling a row-set name (``_variant``) stands for."""
    _, _, named = variant.partition(" + ")
    return next((n for n in AFF_NORMS if n == named), "none")


def _key(weights: Weights) -> str:
    """JSON key of a weight pair."""
    return f"beta {weights[0]:g}, gamma {weights[1]:g}"


def imagenet_scores(specs: list[MethodSpec], threads: int) -> dict[str, dict[str, float]]:
    """``{method: {verb: top-1}}`` on the ImageNet dev episodes (100 per verb, seed 0)."""
    from craft_e.runtime.evaluation.imagenet import evaluate_imagenet

    report = evaluate_imagenet(IMAGENET_DEV, methods=specs, threads=threads)
    return {r.name: {v: m["top1"] for v, m in r.per_verb.items()} for r in report.results
            if r.name in {s.name for s in specs}}


def static_scores(specs: list[MethodSpec], jobs: int,
                  labels: Path = SIM_DEV_LABELS) -> dict[str, dict[str, dict[str, float]]]:
    """``{column: {method: {verb: accuracy}}}`` on the rendered scenes of ``labels``."""
    from craft_e.runtime.evaluation.static_eval import evaluate_static

    report = evaluate_static(labels, backends=("grconvnet",), methods=specs, jobs=jobs).to_dict()
    hits: dict[str, dict[str, dict[str, list[float]]]] = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for ep in report["episodes"]:
        for column, key in STATIC_SETTINGS.items():
            for name, outcome in ep["levels"]["clean"][key]["methods"].items():
                hits[column][name][ep["verb"]].append(float(outcome["success"]))
    return {c: {m: {v: sum(x) / len(x) for v, x in verbs.items()} for m, verbs in by_m.items()}
            for c, by_m in hits.items()}


def leave_one_verb_out(per_weights: dict[Weights, dict[str, float]]) -> dict[str, Any]:
    """Choose the weights on all units but one, score the held-out unit; see the module docstring."""
    grid = sorted(per_weights)
    units = sorted(per_weights[grid[0]])
    chosen: dict[str, Weights] = {}
    for held in units:
        def train(w: Weights, held: str = held) -> tuple[float, bool, Weights]:
            rest = [per_weights[w][u] for u in units if u != held]
            return sum(rest) / len(rest), w == PAPER_WEIGHTS, w
        chosen[held] = max(grid, key=train)
    held_out = sum(per_weights[chosen[u]][u] for u in units) / len(units)
    # how much one unit decides: the unit whose score moves most with the weights, and the
    # fixed-weight means without it
    swing = max(units, key=lambda u: max(per_weights[w][u] for w in grid) - min(per_weights[w][u] for w in grid))
    return {"units": len(units), "chosen": chosen, "held_out_mean": held_out,
            "fixed_mean": {w: sum(per_weights[w].values()) / len(units) for w in grid},
            "largest_swing": {"unit": swing, "scores": {w: per_weights[w][swing] for w in grid},
                              "fixed_mean_without": {w: sum(per_weights[w][u] for u in units if u != swing)
                                                     / max(1, len(units) - 1) for w in grid}}}


def lvo_as_json(entry: dict[str, Any]) -> dict[str, Any]:
    """``leave_one_verb_out``'s result with its weight pairs written as strings (JSON keys)."""
    swing = entry["largest_swing"]
    return {"units": entry["units"], "held_out_mean": entry["held_out_mean"],
            "chosen": {u: list(w) for u, w in entry["chosen"].items()},
            "fixed_mean": {_key(w): m for w, m in entry["fixed_mean"].items()},
            "largest_swing": {"unit": swing["unit"], "scores": {_key(w): s for w, s in swing["scores"].items()},
                              "fixed_mean_without": {_key(w): m for w, m in swing["fixed_mean_without"].items()}}}


def _bundle_name(name: str) -> str:
    """--kb: a bundle folder under artifacts/kb, checked before minutes of ImageNet scoring."""
    if not (KB_DIR / name / "manifest.json").is_file():
        shipped = ", ".join(sorted(p.name for p in KB_DIR.iterdir() if (p / "manifest.json").is_file()))
        raise argparse.ArgumentTypeError(f"no bundle {KB_DIR / name}; shipped: {shipped}")
    return name


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--betas", type=number_list, default="1,1.5,2,3,4,6,8,12,16")
    parser.add_argument("--gammas", type=number_list, default="0.5,1")
    parser.add_argument("--kb", action="append", type=_bundle_name, default=None,
                        help="bundle names under artifacts/kb "
                        "(default: craft-e-default, direct-llm)")
    parser.add_argument("--aff-norm", action="append", choices=AFF_NORMS, default=None,
                        help="E_aff scaling, repeatable: each is a row set of every --kb with its own "
                        "leave-one-verb-out (default: none and verb-best)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--no-static", action="store_true")
    parser.add_argument("--static-labels", type=Path, action="append", default=None,
                        help="labels of the rendered scenes, repeatable (default: sim-dev and "
                        "artifacts/labels/sim_val_labels.csv)")
    parser.add_argument("--json", type=output_file, default=None)
    parser.add_argument("--markdown", type=output_file, default=None)
    args = parser.parse_args()
    static_labels: list[Path] = [] if args.no_static else (args.static_labels or [SIM_DEV_LABELS, SIM_VAL_LABELS])
    for labels in static_labels:
        if not labels.is_file():
            parser.error(f"--static-labels {labels}: no such labels file")
    grid: list[Weights] = [(b, g) for b in args.betas for g in args.gammas]
    norms: list[AffNorm] = args.aff_norm or list(AFF_NORMS)
    # a row set per KB and E_aff scaling ("craft-e-default", "craft-e-default + verb-best"), each
    # with its own leave-one-verb-out: the held-out means compare the scalings as procedures
    kbs = [_variant(kb, norm) for kb in (args.kb or ["craft-e-default", "direct-llm"]) for norm in norms]
    specs = [MethodSpec(_row(kb, w), f"{kb}, beta {w[0]:g}, gamma {w[1]:g}", KB_DIR / kb.split(" + ")[0],
                        beta=w[0], gamma=w[1], aff_norm=_norm_of(kb))
             for kb in kbs for w in grid]

    columns: dict[str, dict[str, dict[str, float]]] = {"imagenet": imagenet_scores(specs, args.threads)}
    for labels in static_labels:
        columns |= {f"static_{c}:{labels.stem}": s for c, s in static_scores(specs, args.jobs, labels).items()}
    selection_columns = ["imagenet"] + [c for c in columns if c.startswith("static_full:")]
    lvo = {}
    for kb in kbs:
        # one unit per (protocol, verb): the ImageNet verbs and each labels file's full-pipeline verbs
        units = {w: {f"{col}:{v}": s for col in selection_columns
                     for v, s in columns[col][_row(kb, w)].items()} for w in grid}
        lvo[kb] = leave_one_verb_out(units)

    lines = ["| KB | beta | gamma | " + " | ".join(columns) + " |", "|---|---:|---:|" + "---:|" * len(columns)]
    for kb in kbs:
        for w in grid:
            means = [sum(columns[c][_row(kb, w)].values()) / len(columns[c][_row(kb, w)]) for c in columns]
            lines.append(f"| {kb} | {w[0]:g} | {w[1]:g} | " + " | ".join(f"{100 * m:.1f}" for m in means) + " |")
    lines.append("")
    for kb, entry in lvo.items():
        counts = {w: sum(1 for c in entry["chosen"].values() if c == w) for w in grid}
        lines.append(f"- {kb}: leave-one-verb-out over {entry['units']} units, held-out mean "
                     f"{100 * entry['held_out_mean']:.1f} (the paper's weights fixed: "
                     f"{100 * entry['fixed_mean'].get(PAPER_WEIGHTS, float('nan')):.1f}); chosen "
                     + ", ".join(f"({w[0]:g}, {w[1]:g}): {n}x" for w, n in counts.items() if n))
        swing = entry["largest_swing"]
        lines.append(f"  - the unit the weights move most: {swing['unit']} ("
                     + ", ".join(f"({w[0]:g}, {w[1]:g}): {100 * v:.0f}" for w, v in swing["scores"].items())
                     + "); without it, the mean at each fixed (beta, gamma): "
                     + ", ".join(f"({w[0]:g}, {w[1]:g}): {100 * v:.1f}" for w, v in swing["fixed_mean_without"].items()))
    table = "\n".join(lines)
    print(table)
    if args.markdown is not None:
        files = ", ".join(f"`{p.name}`" for p in static_labels) or "none"
        args.markdown.write_text(
            "### Energy weights (beta for E_aff, gamma for E_align) on the dev labels "
            "(`benchmarks/bench_energy_weights.py`)\n\n"
            "Mean over verbs of: ImageNet dev single-affordance top-1 (6 verbs, alpha = 0); each rendered-scene "
            f"labels file's accuracy ({files}) with GR-ConvNet + predicted ROIs (`static_full`) and with GT "
            "grasps + GT ROIs (`static_gt`). Percent. Alpha (E_grasp) is 1 on the rendered scenes.\n\n"
            + table + "\n", encoding="utf-8")
    if args.json is not None:
        args.json.write_text(json.dumps({"weights": [list(w) for w in grid], "per_verb": columns,
                                         "leave_one_verb_out": {kb: lvo_as_json(e) for kb, e in lvo.items()}},
                                        indent=1, sort_keys=True) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
