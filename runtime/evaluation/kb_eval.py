"""``craft eval kb``: the knowledge alone — E_aff with perfect recognition, on any dev labels.

The image benchmarks mix perception with knowledge. Here every candidate's object is known (its
true class is the hypothesis, ``p(o | r) = 1``), so a bundle's ``E_aff`` table is scored
directly against labels ``verb -> affording objects`` over a fixed candidate set of objects:

* **AP** — ranking all candidate objects by ``-E_aff``, average precision over distinct score
  thresholds (ties are not broken in anyone's favour; ``zhu.average_precision``);
* **AUC** — the probability that an affording object scores better than a non-affording one,
  ties counting one half;
* **top-1** — seeded 5-candidate episodes (1 affording + 4 distinct non-affording objects), the
  share won by the affording one; a tie for the best energy counts ``1 / (tied candidates)``,
  the expectation of a random tie-break (a saturated energy earns no credit for its ties).

Objects or verbs a bundle lacks get ``E_aff = 0`` (no path); the JSON lists them. Every table
has a **chance** row (AP = positive rate, AUC 0.5, top-1 0.2) and a **label-oracle** row (the
labels themselves as energies: 1, 1, 1 — a check of the harness, and the ceiling).

**Leave-verbs-out** (choosing an E_aff form on dev evidence without fooling ourselves): the
(label set, verb) units are split into ``folds`` seeded folds; per bundle and fold, the form with
the best mean AP on the other folds is *chosen*, and every form's mean AP on the held-out fold is
reported, so a reader sees whether the choice holds on verbs it was not chosen on.

Label sets: ``zhu`` (the public Zhu et al. 2014 matrix, 62 objects x 15 affordances),
``sim-dev`` (``artifacts/labels/sim_dev_labels.csv``; candidates = the sim catalogue's object
names), ``sim-val`` (``artifacts/labels/sim_val_labels.csv``: the 30 sim verbs sim-dev lacks,
written after every default was chosen, so a check rather than a basis for choosing), or a
file: ``{"verb": ["object", ...]}`` JSON (candidates: its ``"_objects"`` list, else
``--objects``, else the ImageNet vocabulary) or a ``verb,object`` CSV over sim assets. Everything
is deterministic: episodes come from a generator seeded by ``(seed, crc32(label set),
crc32(verb))``.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ...files import read_json, sha256_file
from ...paths import KB_DIR, SIM_DEV_LABELS, SIM_VAL_LABELS, VOCAB_DIR, shared_dir
from ..grounding.energies import ENERGY_FORMS, EnergyForm
from ..grounding.grounder import normalize_verb_name
from .common import (
    MethodResult,
    SkippedMethod,
    markdown_table,
    verb_object_lists,
)
from .methods import NoMethodToRunError, nothing_runs
from .zhu import ZhuMatrixError, average_precision, read_zhu_matrix

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

CANDIDATES = 5
METRICS = ("ap", "auc", "top1")
METRIC_LABELS = {"ap": "AP", "auc": "AUC", "top1": "top-1"}
DEFAULT_KBS = [KB_DIR / "craft-e-default", KB_DIR / "direct-llm", KB_DIR / "conceptnet"]


class KBLabelsError(ValueError):
    """A labels file is malformed or names objects outside its candidate set."""


def _norm(name: str) -> str:
    from ...schemas.names import normalize_name

    try:
        return normalize_name(name)
    except ValueError:
        return " ".join(name.strip().lower().split())


@dataclass(frozen=True)
class LabelSet:
    """Candidates ``objects`` and, per verb, which of them afford it (``positives[v]`` ``[O]``)."""

    name: str
    source: str
    objects: list[str]
    positives: dict[str, BoolArray]
    sha256: str = ""


def _from_names(name: str, source: Path, objects: Sequence[str], pairs: dict[str, list[str]]) -> LabelSet:
    objs = list(dict.fromkeys(_norm(o) for o in objects))
    index = {o: i for i, o in enumerate(objs)}
    positives: dict[str, BoolArray] = {}
    for verb, names in pairs.items():
        unknown = sorted({_norm(n) for n in names} - index.keys())
        if unknown:
            raise KBLabelsError(f"{source}: {verb!r} names objects outside the candidates: {', '.join(unknown)}")
        mask = np.zeros(len(objs), dtype=bool)
        mask[[index[_norm(n)] for n in names]] = True
        positives[normalize_verb_name(verb)] = mask
    if not positives:
        raise KBLabelsError(f"{source}: no verbs")
    return LabelSet(name, str(source), objs, positives, sha256_file(source))


def zhu_labels(path: Path | None = None) -> LabelSet:
    """The Zhu et al. matrix (first column a WordNet synset; our names as ``eval zhu`` reads them)."""
    src = path or shared_dir() / "data/affordance_dev/zhu2014_affordance_matrix.csv"
    if not src.is_file():
        raise FileNotFoundError(f"{src}: Zhu matrix not found (set CRAFT_SHARED)")
    try:
        m = read_zhu_matrix(src)
    except ZhuMatrixError as exc:
        raise KBLabelsError(str(exc)) from None
    shown = "$CRAFT_SHARED/data/affordance_dev/zhu2014_affordance_matrix.csv" if path is None else str(src)
    return LabelSet("zhu", shown, list(m.objects), dict(m.labels), sha256_file(src))


def sim_labels(path: Path, name: str = "sim-dev") -> LabelSet:
    """A ``verb,object`` CSV over sim assets; candidates = every sim catalogue object name."""
    from ..sim.assets import object_catalog
    from .imagenet import LabelsError
    from .sim_eval import load_sim_labels

    try:
        labels = load_sim_labels(path)
    except LabelsError as exc:
        raise KBLabelsError(str(exc)) from None
    catalog = object_catalog()
    objects = sorted({a.name for a in catalog.values()})
    pairs = {v: sorted({catalog[a].name for a in assets}) for v, assets in labels.affording.items()}
    return _from_names(name, path, objects, pairs)


def json_labels(path: Path, objects: Sequence[str] | None = None) -> LabelSet:
    """``{"verb": [...]}``; candidates: ``"_objects"`` in the file, ``objects``, or ImageNet's.

    Checked as ``craft eval imagenet`` checks its labels (``imagenet.load_labels``): a blank
    verb, a verb with no objects (its AP and AUC would be NaN, left out of every mean) and two
    keys naming one verb (the second list silently replaced the first) are errors."""
    raw = read_json(path, "labels file", KBLabelsError, unique_keys=True)
    pairs = {key: names for key, _, names in verb_object_lists(
        path, raw, KBLabelsError, "its AP and AUC would be NaN, left out of every mean; list the objects that afford it")}
    listed = raw.get("_objects")
    if listed is not None and not (isinstance(listed, list) and all(isinstance(o, str) for o in listed)):
        raise KBLabelsError(f'{path}: "_objects" must be a list of object names')
    candidates = listed or objects
    if candidates is None:
        from .common import read_artifact_names

        candidates = read_artifact_names(VOCAB_DIR / "imagenet_objects.txt", "the ImageNet objects vocabulary")
    return _from_names(path.stem, path, list(candidates), pairs)


def resolve_labels(spec: str, objects: Sequence[str] | None = None) -> LabelSet:
    """``zhu`` | ``sim-dev`` | ``sim-val`` | a ``.json`` or ``.csv`` path (see the module docstring)."""
    if spec == "zhu":
        return zhu_labels()
    if spec == "sim-dev":
        return sim_labels(SIM_DEV_LABELS)
    if spec == "sim-val":
        return sim_labels(SIM_VAL_LABELS, "sim-val")
    path = Path(spec)
    if path.suffix.lower() == ".csv":
        return sim_labels(path, path.stem)
    if path.suffix.lower() == ".json":
        return json_labels(path, objects)
    raise KBLabelsError(f"--labels {spec!r}: use zhu, sim-dev, sim-val, a .json or a .csv file")


# ---------------------------------------------------------------------------------------------
# metrics


def auc(scores: FloatArray, positives: BoolArray) -> float:
    """P(score of an affording object > a non-affording one), ties 1/2; NaN without both kinds."""
    pos, neg = scores[positives], scores[~positives]
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    greater = (pos[:, None] > neg[None, :]).sum()
    ties = (pos[:, None] == neg[None, :]).sum()
    return float((greater + 0.5 * ties) / (len(pos) * len(neg)))


def episodes(labels: LabelSet, verb: str, n: int, seed: int) -> npt.NDArray[np.intp] | None:
    """``[n, 5]`` candidate indices, the affording one in column 0 (None: too few objects)."""
    pos = np.flatnonzero(labels.positives[verb])
    neg = np.flatnonzero(~labels.positives[verb])
    if len(pos) == 0 or len(neg) < CANDIDATES - 1:
        return None
    rng = np.random.default_rng(np.random.SeedSequence(
        [seed, zlib.crc32(labels.name.encode()), zlib.crc32(verb.encode())]))
    out = np.zeros((n, CANDIDATES), dtype=np.intp)
    for e in range(n):
        out[e, 0] = rng.choice(pos)
        out[e, 1:] = rng.choice(neg, CANDIDATES - 1, replace=False)
    return out


def episode_top1(energy: FloatArray, eps: npt.NDArray[np.intp]) -> float:
    """Mean credit of the affording candidate (column 0): 1 / (number tied for the best)."""
    e = energy[eps]  # [E, 5]
    best = e.min(axis=1, keepdims=True)
    winners = e == best  # [E, 5]
    credit = np.where(winners[:, 0], 1.0 / winners.sum(axis=1), 0.0)
    return float(credit.mean())


def score_energy(energy: FloatArray, labels: LabelSet, verb: str, eps: npt.NDArray[np.intp] | None) -> dict[str, float]:
    """AP, AUC and episode top-1 of one verb's energies ``[O]`` (lower = more affordant)."""
    pos = labels.positives[verb]
    out = {"ap": average_precision(-energy, pos), "auc": auc(-energy, pos)}
    if eps is not None:
        out["top1"] = episode_top1(energy, eps)
    return out


# ---------------------------------------------------------------------------------------------
# bundles


def energy_for_labels(table: npt.NDArray[Any], verb_index: dict[str, int], object_index: dict[str, int],
                      labels: LabelSet) -> tuple[dict[str, FloatArray], list[str], list[str]]:
    """Per labelled verb, ``E_aff`` over the label set's objects (missing -> 0), and the verbs and
    objects the bundle lacks."""
    cols = np.array([object_index.get(o, -1) for o in labels.objects])
    known = cols >= 0
    out: dict[str, FloatArray] = {}
    missing_verbs = []
    for verb in labels.positives:
        row = np.zeros(len(labels.objects), dtype=np.float64)
        vi = verb_index.get(verb)
        if vi is None:
            missing_verbs.append(verb)
        else:
            row[known] = table[vi, cols[known]]
        out[verb] = row
    return out, missing_verbs, [o for o, k in zip(labels.objects, known, strict=True) if not k]


@dataclass
class Scored:
    """One row: a method (bundle + form, or chance/oracle) on every label set."""

    name: str
    kb: str
    form: str
    per_verb: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)  # set -> verb -> metric
    notes: list[str] = field(default_factory=list)

    def mean(self, label_set: str, metric: str, verbs: Sequence[str] | None = None) -> float:
        rows = self.per_verb.get(label_set, {})
        vals = [rows[v][metric] for v in (verbs if verbs is not None else rows) if v in rows and metric in rows[v]]
        vals = [x for x in vals if not np.isnan(x)]
        return float(np.mean(vals)) if vals else float("nan")


def _nanmean(values: Sequence[float]) -> float:
    vals = [v for v in values if not np.isnan(v)]
    return float(np.mean(vals)) if vals else float("nan")


@dataclass
class KBEvalReport:
    label_sets: list[LabelSet]
    rows: list[Scored]
    skipped: list[SkippedMethod]
    lvo: dict[str, Any]
    config: dict[str, Any]

    def units(self) -> list[tuple[str, str]]:
        return [(ls.name, v) for ls in self.label_sets for v in ls.positives]

    def headline(self, row: Scored) -> dict[str, float]:
        metrics = {f"{ls.name}_{m}": row.mean(ls.name, m) for ls in self.label_sets for m in METRICS}
        lvo = self.lvo.get("bundles", {}).get(row.kb, {}).get("held_out_mean_ap", {})
        if row.form in lvo:
            metrics["lvo_ap"] = lvo[row.form]
        return {k: v for k, v in metrics.items() if not np.isnan(v)}

    def to_dict(self) -> dict[str, Any]:
        return {
            "benchmark": "kb (E_aff with perfect recognition)",
            "config": self.config,
            "label_sets": {ls.name: {"source": ls.source, "sha256": ls.sha256, "objects": len(ls.objects),
                                     "verbs": len(ls.positives),
                                     "positive_rate": _nanmean([float(p.mean()) for p in ls.positives.values()])}
                           for ls in self.label_sets},
            "methods": [{"name": r.name, "kb": r.kb, "form": r.form, "means": self.headline(r),
                         "per_verb": r.per_verb, "notes": r.notes} for r in self.rows],
            "skipped_methods": [{"method": s.name, "reason": s.reason} for s in self.skipped],
            "leave_verbs_out": self.lvo,
        }

    def to_markdown(self) -> str:
        c = self.config
        columns = [(f"{ls.name}_{m}", f"{ls.name} {METRIC_LABELS[m]}") for ls in self.label_sets for m in METRICS]
        columns.append(("lvo_ap", "LVO held-out AP"))
        results = [MethodResult(r.name, r.form, self.headline(r), notes=r.notes) for r in self.rows]
        sets = ", ".join(f"`{ls.name}` ({len(ls.positives)} verbs, {len(ls.objects)} objects)" for ls in self.label_sets)
        out = [
            "### Knowledge alone: E_aff with perfect recognition (`craft eval kb`)",
            "",
            f"Label sets: {sets}. Means over verbs, percent. top-1: {c['episodes']} seeded "
            f"5-candidate episodes per verb (1 affording + 4 not; ties share the credit), seed "
            f"{c['seed']}. LVO: leave-verbs-out mean AP of the form on held-out verbs "
            f"({c['folds']} folds over all label sets' verbs).",
            "",
            "Command: `craft eval kb " + " ".join(
                [f"--kb {b}" for b in c["bundles"]] + [f"--labels {x}" for x in c["labels"]]
                + ([f"--energy-form {f}" for f in c["forms"]] if list(c["forms"]) != list(ENERGY_FORMS) else [])
                + ([f"--seed {c['seed']}"] if c["seed"] else [])) + "`",
            "",
            markdown_table(results, self.skipped, columns).rstrip("\n"),
            "",
        ]
        for kb, entry in self.lvo.get("bundles", {}).items():
            forms = entry["forms"]
            out += [f"#### Leave-verbs-out, `{kb}`: choose the form with the best mean AP on "
                    f"{c['folds'] - 1}/{c['folds']} of the verbs, score it on the rest", "",
                    "| fold | held-out verbs | chosen form | " + " | ".join(forms) + " |",
                    "|---|---:|---|" + "---:|" * len(forms)]
            for f in entry["folds"]:
                cells = [f"**{100 * f['held_out_ap'][x]:.2f}**" if x == f["chosen"] else f"{100 * f['held_out_ap'][x]:.2f}"
                         for x in forms]
                out.append(f"| {f['fold']} | {f['verbs']} | {f['chosen']} | " + " | ".join(cells) + " |")
            means = [f"{100 * entry['held_out_mean_ap'][x]:.2f}" for x in forms]
            out.append(f"| mean | | chosen: **{100 * entry['chosen_held_out_mean_ap']:.2f}** | " + " | ".join(means) + " |")
            out.append("")
        return "\n".join(out)


def _bundle_rows(bundle: Any, forms: Sequence[EnergyForm], label_sets: Sequence[LabelSet],
                 eps: dict[tuple[str, str], npt.NDArray[np.intp] | None]) -> list[Scored]:
    """One row per form; what the bundle lacks is noted once, on its first row."""
    from ..grounding.grounder import affordance_energy_in_form

    m = bundle.manifest
    rows: list[Scored] = []
    notes: list[str] = []
    for form in forms:
        table = affordance_energy_in_form(bundle, form)  # [V, O]
        row = Scored(f"{m.kb_name} ({form})", m.kb_name, form)
        for ls in label_sets:
            energies, missing_v, missing_o = energy_for_labels(table, bundle.verb_index, bundle.object_index, ls)
            row.per_verb[ls.name] = {v: score_energy(e, ls, v, eps[(ls.name, v)]) for v, e in energies.items()}
            if not rows and missing_v:
                notes.append(f"{ls.name}: {len(missing_v)} verb(s) not in the KB (E_aff = 0): {', '.join(missing_v)}")
            if not rows and missing_o:
                notes.append(f"{ls.name}: {len(missing_o)} object(s) not in the KB (E_aff = 0)")
        rows.append(row)
    if len(rows) > 1 and _one_property_per_verb(bundle):
        notes.append("one property per verb: every form ranks objects alike")
    if rows:
        rows[0].notes = notes
    return rows


def _one_property_per_verb(bundle: Any) -> bool:
    counts = [len(edges) for edges in bundle.graph.verb_properties.values()]
    return bool(counts) and max(counts) == 1


def _reference_rows(label_sets: Sequence[LabelSet], eps: dict[tuple[str, str], npt.NDArray[np.intp] | None]) -> list[Scored]:
    chance = Scored("chance", "chance", "—")
    oracle = Scored("label oracle", "oracle", "—")
    for ls in label_sets:
        chance.per_verb[ls.name] = {}
        oracle.per_verb[ls.name] = {}
        for v, pos in ls.positives.items():
            row = {"ap": float(pos.mean()), "auc": 0.5}
            if eps[(ls.name, v)] is not None:
                row["top1"] = 1.0 / CANDIDATES
            chance.per_verb[ls.name][v] = row
            oracle.per_verb[ls.name][v] = score_energy(-pos.astype(np.float64), ls, v, eps[(ls.name, v)])
    return [chance, oracle]


def _fold_mean_ap(row: Scored, fold_of: dict[tuple[str, str], int], fold: int, held: bool) -> float:
    """Mean AP of ``row`` over the units in (``held``) or outside (not ``held``) ``fold``."""
    return _nanmean([row.per_verb[s][v]["ap"] for (s, v), k in fold_of.items() if (k == fold) == held])


def leave_verbs_out(rows: Sequence[Scored], units: Sequence[tuple[str, str]], forms: Sequence[str],
                    folds: int, seed: int) -> dict[str, Any]:
    """Per bundle: per fold, the form with the best mean AP on the other folds, and every form's
    mean AP on the held-out fold (see the module docstring)."""
    order = np.random.default_rng(seed).permutation(len(units))
    fold_of = {units[i]: k % folds for k, i in enumerate(order.tolist())}
    by_kb: dict[str, dict[str, Scored]] = {}
    for r in rows:
        by_kb.setdefault(r.kb, {})[r.form] = r
    out: dict[str, Any] = {}
    for kb, rows_by_form in by_kb.items():
        present = [f for f in forms if f in rows_by_form]
        if len(present) < 1:
            continue

        fold_rows: list[dict[str, Any]] = []
        for k in range(folds):
            train = {f: _fold_mean_ap(rows_by_form[f], fold_of, k, held=False) for f in present}
            chosen = max(present, key=lambda f: (train[f], -present.index(f)))  # ties: table order
            fold_rows.append({"fold": k + 1, "verbs": sum(1 for x in fold_of.values() if x == k),
                              "chosen": chosen, "train_ap": train,
                              "held_out_ap": {f: _fold_mean_ap(rows_by_form[f], fold_of, k, held=True)
                                              for f in present}})
        out[kb] = {
            "forms": present,
            "folds": fold_rows,
            "held_out_mean_ap": {f: _nanmean([fr["held_out_ap"][f] for fr in fold_rows]) for f in present},
            "chosen_held_out_mean_ap": _nanmean([fr["held_out_ap"][fr["chosen"]] for fr in fold_rows]),
            "chosen_counts": {f: sum(1 for fr in fold_rows if fr["chosen"] == f) for f in present},
        }
    return {"folds": folds, "seed": seed, "metric": "ap", "units": len(units), "bundles": out}


def evaluate_kbs(
    bundles: Sequence[Path],
    label_specs: Sequence[str],
    *,
    forms: Sequence[EnergyForm] = ENERGY_FORMS,
    episodes_per_verb: int = 100,
    seed: int = 0,
    folds: int = 5,
    objects: Sequence[str] | None = None,
) -> KBEvalReport:
    """Every bundle x form on every label set, chance and oracle rows, leave-verbs-out."""
    from ..kb.bundle import BundleError, load_bundle

    label_sets = [resolve_labels(s, objects) for s in label_specs]
    names = [ls.name for ls in label_sets]
    if len(set(names)) != len(names):
        raise KBLabelsError(f"label sets must have distinct names, got {names}")
    units = [(ls.name, v) for ls in label_sets for v in ls.positives]
    if len(units) < 2:
        raise KBLabelsError(f"leave-verbs-out needs at least 2 labelled verbs, the labels have {len(units)}")
    folds = min(folds, len(units))  # every fold holds a verb (an empty fold has no mean: NaN)
    eps = {(ls.name, v): episodes(ls, v, episodes_per_verb, seed) for ls in label_sets for v in ls.positives}
    rows = _reference_rows(label_sets, eps)
    skipped: list[SkippedMethod] = []
    for path in bundles:
        try:
            bundle = load_bundle(path, check_encoder=False)
        except BundleError as exc:
            skipped.append(SkippedMethod(str(path), f"bundle unavailable: {exc}"))
            continue
        rows += _bundle_rows(bundle, forms, label_sets, eps)
    if bundles and len(skipped) == len(bundles):  # a table of the reference rows alone compares nothing
        raise NoMethodToRunError(nothing_runs(bundles, skipped))
    lvo = leave_verbs_out([r for r in rows if r.kb not in ("chance", "oracle")], units, forms, folds, seed)
    config = {"episodes": episodes_per_verb, "seed": seed, "folds": folds, "forms": list(forms),
              "bundles": [str(b) for b in bundles], "labels": list(label_specs), "candidates": CANDIDATES}
    return KBEvalReport(label_sets, rows, skipped, lvo, config)
