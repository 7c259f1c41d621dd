"""``craft eval open-world``: does the KB generalise to objects and verbs it has never seen?

Issue 11, item 5, on development labels only (the Zhu et al. matrix, the sim dev labels; label
loading and metrics are ``kb_eval``'s):

* **Leave-objects-out.** Every object of a label set is removed from the KB at once (its
  property column, and from the neighbour pool), the open-world object model is refitted on what
  is left exactly as ``craftc build`` fits it (``open_world.fit_open_world``), each removed object
  is inferred from its name's embedding, and the label set's verbs are scored (AP, AUC, top-1)
  on the inferred energies — against the same verbs scored with the objects in the KB. An
  object whose confidence is below the threshold is *abstained on*: it keeps ``E_aff = 0``.
* **Leave-verbs-out.** Every verb of a label set is removed at once (its verb -> property
  edges, and the properties no remaining verb uses), and each verb's *name* is mapped as a free
  request (``open_world.map_request``: nearest remaining verbs + nearest properties); below the
  threshold the request is abstained on (every object ``E_aff = 0``, AP = chance).

**Abstention precision**: the share of abstentions that were right to abstain, an abstention
being right when the inference it withheld was *bad*: for an object, its per-object AP over the
label set's verbs with the inferred energies is below the midpoint of chance (its positive rate)
and its in-KB per-object AP; for a verb, its mapped AP is below the midpoint of chance and its
in-KB AP. Thresholds and the verbs' share of a request are chosen here, on these dev sets, as
the largest threshold within 0.1 AP points of the best mean AP over the label sets (abstain
wherever it costs no dev AP); the chosen values are the constants in ``runtime/grounding/open_world.py``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ..grounding.energies import (
    EnergyForm,
    energy_from_property_columns,
    property_specificity,
    required_matrix_from_graph,
    weight_matrices_from_graph,
)
from ..grounding.open_world import (
    OBJECT_MIN_CONFIDENCE,
    REQUEST_MIN_CONFIDENCE,
    VERB_SHARE,
    ObjectModel,
    fit_open_world,
    linked_weights,
    map_request,
)
from .kb_eval import (
    LabelSet,
    episodes,
    resolve_labels,
    score_energy,
)
from .zhu import average_precision

F64 = npt.NDArray[np.float64]
OBJECT_THRESHOLDS = (0.0, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6)
REQUEST_THRESHOLDS = (0.0, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6)
VERB_SHARES = (0.0, 0.25, 0.5, 0.75, 1.0)


def pct(x: float) -> str:
    return "–" if np.isnan(x) else f"{100 * x:.1f}"


def _mean(values: Sequence[float]) -> float:
    vals = [v for v in values if not np.isnan(v)]
    return float(np.mean(vals)) if vals else float("nan")


@dataclass
class _KB:
    bundle: Any
    form: EnergyForm
    w_vp: F64
    w_po: F64
    required: npt.NDArray[np.bool_]
    tau: float


def _kb(bundle: Any, form: EnergyForm) -> _KB:
    m = bundle.manifest
    w_vp, w_po = weight_matrices_from_graph(bundle.graph, m.verbs, m.properties, m.objects)
    return _KB(bundle, form, w_vp.astype(np.float64), w_po.astype(np.float64),
               required_matrix_from_graph(bundle.graph, m.verbs, m.properties), m.energy.tau)


def _energy(kb: _KB, w_vp: F64, q_w: F64, q_l: F64, spec: F64, required: npt.NDArray[np.bool_]) -> F64:
    out: F64 = energy_from_property_columns(w_vp, q_w, q_l, specificity=spec, form=kb.form,
                                            required=required).astype(np.float64)
    return out


def _in_kb(kb: _KB, ls: LabelSet) -> F64:
    """``[V_ls, O_ls]`` E_aff of the label set's verbs x objects with everything in the KB."""
    from ..grounding.grounder import affordance_energy_in_form

    b = kb.bundle
    table = affordance_energy_in_form(b, kb.form)
    out = np.zeros((len(ls.positives), len(ls.objects)))
    for r, verb in enumerate(ls.positives):
        vi = b.verb_index.get(verb)
        for c, obj in enumerate(ls.objects):
            oi = b.object_index.get(obj)
            if vi is not None and oi is not None:
                out[r, c] = table[vi, oi]
    return out


def _score(ls: LabelSet, table: F64, eps: dict[str, Any]) -> dict[str, dict[str, float]]:
    return {v: score_energy(table[r], ls, v, eps[v]) for r, v in enumerate(ls.positives)}


def _object_ap(ls: LabelSet, table: F64) -> F64:
    """Per object: AP of ranking the label set's verbs by ``-E_aff`` (NaN without both kinds)."""
    pos = np.stack([ls.positives[v] for v in ls.positives])  # [V_ls, O]
    out = np.full(len(ls.objects), np.nan)
    for c in range(len(ls.objects)):
        if 0 < pos[:, c].sum() < len(pos):
            out[c] = average_precision(-table[:, c], pos[:, c])
    return out


def _abstention(abstain: npt.NDArray[np.bool_], bad: npt.NDArray[np.bool_], valid: npt.NDArray[np.bool_]) -> dict[str, float]:
    n = int(abstain.sum())
    judged = abstain & valid
    return {"abstained": n, "of": len(abstain), "rate": n / max(len(abstain), 1),
            "precision": float(bad[judged].mean()) if judged.any() else float("nan")}


def leave_objects_out(kb: _KB, ls: LabelSet, eps: dict[str, Any], text_encoder: Any | None = None) -> dict[str, Any]:
    b = kb.bundle
    m = b.manifest
    held = [b.object_index[o] for o in ls.objects if o in b.object_index]
    keep = np.setdiff1d(np.arange(len(m.objects)), held)
    emb = np.zeros((len(ls.objects), b.embeddings["object"].shape[1]), dtype=np.float32)
    missing = [i for i, o in enumerate(ls.objects) if o not in b.object_index]
    for i, o in enumerate(ls.objects):
        if o in b.object_index:
            emb[i] = b.embeddings["object"][b.object_index[o]]
    if missing:
        if text_encoder is None:
            from ..encoders.text import load_text_encoder

            text_encoder = load_text_encoder(m.text_encoder.id)
        emb[missing] = text_encoder.embed([ls.objects[i] for i in missing])
    pool_emb, pool_w = b.embeddings["object"][keep], kb.w_po[:, keep]
    params = fit_open_world(pool_emb, pool_w, tau=kb.tau)
    model = ObjectModel.from_params(params["objects"], [m.objects[i] for i in keep], pool_emb, pool_w,
                                    kb.tau, min_confidence=0.0)
    q_w, q_l, infos = model.infer(ls.objects, emb)
    conf = np.array([i.confidence for i in infos])
    spec = property_specificity(pool_w.astype(np.float32), tau=kb.tau)
    verbs = [v for v in ls.positives if v in b.verb_index]
    rows = [b.verb_index[v] for v in ls.positives if v in b.verb_index]
    inferred_all = np.zeros((len(ls.positives), len(ls.objects)))
    known_rows = [r for r, v in enumerate(ls.positives) if v in b.verb_index]
    inferred_all[known_rows] = _energy(kb, kb.w_vp[rows], q_w, q_l, spec, kb.required[rows])
    in_kb = _in_kb(kb, ls)
    obj_in, obj_inf = _object_ap(ls, in_kb), _object_ap(ls, inferred_all)
    chance_o = np.stack([ls.positives[v] for v in ls.positives]).mean(axis=0)
    valid = ~np.isnan(obj_in) & ~np.isnan(obj_inf)
    bad = np.where(valid, obj_inf < (chance_o + np.nan_to_num(obj_in)) / 2, False)
    grid = []
    for thr in OBJECT_THRESHOLDS:
        abstain = conf < thr
        table = np.where(abstain[None, :], 0.0, inferred_all)
        per_verb = _score(ls, table, eps)
        grid.append({"threshold": thr, "ap": _mean([r["ap"] for r in per_verb.values()]),
                     "auc": _mean([r["auc"] for r in per_verb.values()]),
                     "top1": _mean([r.get("top1", float("nan")) for r in per_verb.values()]),
                     **_abstention(abstain, bad, valid)})
    in_scores = _score(ls, in_kb, eps)
    return {
        "objects": len(ls.objects), "verbs_in_kb": verbs, "k": params["objects"]["k"],
        "temperature": params["objects"]["temperature"],
        "in_kb": {"ap": _mean([r["ap"] for r in in_scores.values()]),
                  "auc": _mean([r["auc"] for r in in_scores.values()]),
                  "top1": _mean([r.get("top1", float("nan")) for r in in_scores.values()])},
        "grid": grid,
        "per_object": [{"object": i.name, "confidence": i.confidence,
                        "neighbours": [n for n, _ in i.neighbours[:3]],
                        "ap_in_kb": float(a), "ap_inferred": float(x)}
                       for i, a, x in zip(infos, obj_in, obj_inf, strict=True)],
    }


def leave_verbs_out(kb: _KB, ls: LabelSet, eps: dict[str, Any]) -> dict[str, Any]:
    b = kb.bundle
    m = b.manifest
    held = [v for v in ls.positives if v in b.verb_index]
    vmask = np.ones(len(m.verbs), bool)
    vmask[[b.verb_index[v] for v in held]] = False
    pmask: npt.NDArray[np.bool_] = np.asarray((kb.w_vp[vmask] > 0).any(axis=0), dtype=bool)
    weight, link = linked_weights(kb.w_po, kb.tau)
    spec = property_specificity(kb.w_po.astype(np.float32), tau=kb.tau)
    cols = np.array([b.object_index.get(o, -1) for o in ls.objects])
    in_kb = _in_kb(kb, ls)
    in_scores = _score(ls, in_kb, eps)
    chance = {v: float(p.mean()) for v, p in ls.positives.items()}
    e = b.embeddings
    results: dict[float, dict[str, Any]] = {}
    mappings: dict[float, dict[str, Any]] = {}
    for share in VERB_SHARES:
        rows = np.zeros((len(ls.positives), len(ls.objects)))
        conf = np.zeros(len(ls.positives))
        maps: dict[str, Any] = {}
        for r, verb in enumerate(ls.positives):
            if verb not in b.verb_index:
                continue
            vi = b.verb_index[verb]
            mp = map_request(verb, verb, e["verb"][vi], e["verb_query"][vi], verbs=m.verbs,
                             verb_embeddings=e["verb"], verb_query_embeddings=e["verb_query"],
                             properties=m.properties, property_embeddings=e["property"], w_vp=kb.w_vp,
                             required=kb.required, verb_mask=vmask, property_mask=pmask,
                             params={"verb_share": share, "min_confidence": 0.0})
            energy = _energy(kb, mp.weights[None, :], weight, link, spec, mp.required[None, :])[0]
            rows[r] = np.where(cols >= 0, energy[np.maximum(cols, 0)], 0.0)
            conf[r] = mp.confidence
            maps[verb] = {"confidence": mp.confidence, "verbs": [v for v, _, _ in mp.verbs],
                          "properties": [p for p, _, _ in mp.properties]}
        results[share] = {"rows": rows, "conf": conf}
        mappings[share] = maps
    grid = []
    known = np.array([v in b.verb_index for v in ls.positives])
    for share in VERB_SHARES:
        rows, conf = results[share]["rows"], results[share]["conf"]
        mapped = _score(ls, rows, eps)
        bad = np.array([mapped[v]["ap"] < (chance[v] + in_scores[v]["ap"]) / 2 for v in ls.positives])
        for thr in REQUEST_THRESHOLDS:
            abstain = known & (conf < thr)
            table = np.where(abstain[:, None], 0.0, rows)
            per_verb = _score(ls, table, eps)
            grid.append({"verb_share": share, "threshold": thr,
                         "ap": _mean([r["ap"] for r in per_verb.values()]),
                         "auc": _mean([r["auc"] for r in per_verb.values()]),
                         "top1": _mean([r.get("top1", float("nan")) for r in per_verb.values()]),
                         **_abstention(abstain, bad, known)})
    return {"verbs": held, "properties_removed": int((~pmask).sum() - (~(kb.w_vp > 0).any(axis=0)).sum()),
            "in_kb": {"ap": _mean([in_scores[v]["ap"] for v in ls.positives])},
            "grid": grid, "mappings": mappings.get(VERB_SHARE, {})}


def _choose(grids: Sequence[Sequence[dict[str, Any]]], key: str, fixed: dict[str, Any] | None = None,
            tolerance: float = 0.001) -> dict[str, Any]:
    """The largest ``key`` whose mean AP over the label sets is within ``tolerance`` (0.1 AP
    points) of the best, among grid points matching ``fixed``."""
    points: dict[Any, list[float]] = {}
    for grid in grids:
        for g in grid:
            if all(g[k] == v for k, v in (fixed or {}).items()):
                points.setdefault(g[key], []).append(g["ap"])
    best = max(_mean(v) for v in points.values())
    chosen = max(p for p, v in points.items() if _mean(v) >= best - tolerance)
    return {key: chosen, **(fixed or {}), "mean_ap": _mean(points[chosen]), "best_mean_ap": best}


@dataclass
class OpenWorldReport:
    config: dict[str, Any]
    label_sets: list[LabelSet]
    objects: dict[str, dict[str, Any]]
    verbs: dict[str, dict[str, Any]]
    chosen_objects: dict[str, Any]
    chosen_requests: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return {"benchmark": "open world (issue 11): leave-objects-out, leave-verbs-out",
                "config": self.config,
                "label_sets": {ls.name: {"source": ls.source, "sha256": ls.sha256} for ls in self.label_sets},
                "chance_ap": {ls.name: _mean([float(p.mean()) for p in ls.positives.values()]) for ls in self.label_sets},
                "leave_objects_out": self.objects, "leave_verbs_out": self.verbs,
                "chosen": {"objects": self.chosen_objects, "requests": self.chosen_requests,
                           "shipped": {"object_min_confidence": OBJECT_MIN_CONFIDENCE,
                                       "request_min_confidence": REQUEST_MIN_CONFIDENCE,
                                       "verb_share": VERB_SHARE}}}

    def to_markdown(self) -> str:
        c = self.config
        out = ["### Open world: objects and verbs the KB has never seen (`craft eval open-world`)", "",
               f"KB `{c['kb']}`, E_aff form `{c['form']}`; development labels only. Command: "
               f"`{c['command']}`", "",
               "Mean AP % over the label set's verbs. *Leave-objects-out*: every labelled object removed "
               "from the KB at once and inferred from its name (k-NN over the remaining objects, refitted "
               "as `craftc build` fits it). *Leave-verbs-out*: every labelled verb removed at once (and the "
               "properties only it used) and its name mapped as a free request. Abstained items keep "
               "E_aff = 0. Abstention precision: share of abstentions whose withheld inference was bad "
               "(AP below the midpoint of chance and the in-KB AP).", "",
               "| label set | chance | in KB | leave-objects-out (shipped threshold) | share of chance→in-KB gap kept | "
               "objects abstained | abstention precision | leave-verbs-out (shipped) | verbs abstained | abstention precision |",
               "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for ls in self.label_sets:
            ch = _mean([float(p.mean()) for p in ls.positives.values()])
            lo = self.objects[ls.name]
            g = next(x for x in lo["grid"] if x["threshold"] == OBJECT_MIN_CONFIDENCE)
            lv = self.verbs[ls.name]
            h = next(x for x in lv["grid"] if x["threshold"] == REQUEST_MIN_CONFIDENCE and x["verb_share"] == VERB_SHARE)
            kept = (g["ap"] - ch) / (lo["in_kb"]["ap"] - ch) if lo["in_kb"]["ap"] > ch else float("nan")
            out.append(f"| {ls.name} | {pct(ch)} | {pct(lo['in_kb']['ap'])} | {pct(g['ap'])} | {pct(kept)} | "
                       f"{g['abstained']}/{g['of']} | {pct(g['precision'])} | {pct(h['ap'])} | "
                       f"{h['abstained']}/{h['of']} | {pct(h['precision'])} |")
        out += ["", f"Shipped: object confidence floor {OBJECT_MIN_CONFIDENCE}, request confidence floor "
                f"{REQUEST_MIN_CONFIDENCE}, verbs' share of a request {VERB_SHARE}. Best on these dev sets "
                f"(the largest threshold within 0.1 AP points of the best mean AP over the label sets): objects "
                f"{self.chosen_objects['threshold']} ({pct(self.chosen_objects['mean_ap'])}); requests at verb share "
                f"{VERB_SHARE}: {self.chosen_requests['threshold']} ({pct(self.chosen_requests['mean_ap'])}). Best mean "
                "leave-verbs-out AP by verbs' share: " + ", ".join(
                    f"{s}: {pct(a)}" for s, a in self.chosen_requests["best_by_verb_share"].items()) + ".", "",
                "#### Leave-objects-out by confidence threshold", "",
                "| label set | threshold | AP | AUC | top-1 | abstained | abstention precision |",
                "|---|---:|---:|---:|---:|---:|---:|"]
        for ls in self.label_sets:
            for g in self.objects[ls.name]["grid"]:
                out.append(f"| {ls.name} | {g['threshold']} | {pct(g['ap'])} | {pct(g['auc'])} | {pct(g['top1'])} | "
                           f"{g['abstained']}/{g['of']} | {pct(g['precision'])} |")
        out += ["", "#### Leave-verbs-out by verbs' share and confidence threshold", "",
                "| label set | verb share | threshold | AP | AUC | top-1 | abstained | abstention precision |",
                "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for ls in self.label_sets:
            for g in self.verbs[ls.name]["grid"]:
                out.append(f"| {ls.name} | {g['verb_share']} | {g['threshold']} | {pct(g['ap'])} | {pct(g['auc'])} | "
                           f"{pct(g['top1'])} | {g['abstained']}/{g['of']} | {pct(g['precision'])} |")
        out += ["", "#### Leave-verbs-out: what each held-out verb was mapped to (shipped verb share)", "",
                "| label set | verb | confidence | nearest remaining verbs | nearest properties |", "|---|---|---:|---|---|"]
        for ls in self.label_sets:
            for v, mp in self.verbs[ls.name]["mappings"].items():
                out.append(f"| {ls.name} | {v} | {mp['confidence']:.2f} | {', '.join(mp['verbs'])} | "
                           f"{', '.join(mp['properties'][:3])} |")
        return "\n".join(out) + "\n"


def evaluate_open_world(bundle_path: Path, label_specs: Sequence[str], *, form: EnergyForm | None = None,
                        episodes_per_verb: int = 100, seed: int = 0) -> OpenWorldReport:
    from ..kb.bundle import load_bundle

    bundle = load_bundle(bundle_path, check_encoder=False)
    kb = _kb(bundle, form or bundle.manifest.energy.form)
    label_sets = [resolve_labels(s) for s in label_specs]
    objects, verbs = {}, {}
    for ls in label_sets:
        eps = {v: episodes(ls, v, episodes_per_verb, seed) for v in ls.positives}
        objects[ls.name] = leave_objects_out(kb, ls, eps)
        verbs[ls.name] = leave_verbs_out(kb, ls, eps)
    chosen_o = _choose([o["grid"] for o in objects.values()], "threshold")
    chosen_r = _choose([v["grid"] for v in verbs.values()], "threshold", {"verb_share": VERB_SHARE})
    shares = {s: _choose([v["grid"] for v in verbs.values()], "threshold", {"verb_share": s})["best_mean_ap"]
              for s in VERB_SHARES}
    chosen_r["best_by_verb_share"] = shares
    command = ("craft eval open-world --kb " + str(bundle_path) + "".join(f" --labels {s}" for s in label_specs)
               + (f" --energy-form {form}" if form else "") + " --markdown docs/open_world_dev.md --json docs/open_world_dev.json")
    config = {"kb": f"{bundle.manifest.kb_name}@{bundle.manifest.kb_version}", "form": kb.form,
              "labels": list(label_specs), "episodes": episodes_per_verb, "seed": seed, "command": command}
    return OpenWorldReport(config, label_sets, objects, verbs, chosen_o, chosen_r)
