"""Discrimination diagnostics of a KB: does its E_aff tell objects apart, or call everything affordant?

A KB can be accurate about each edge and still be useless for choosing: if generic properties
("has a handle", "fits in one hand") link most verbs to most objects, every object looks
affordant, the paper's sum-tanh saturates at -1, and a few hub objects win for almost any verb.
These numbers make that visible in ``report.json`` and in ``craftc diff`` (issue 9):

* ``affordant_share`` — share of verb x object cells with ``E_aff < 0`` (some path links them);
* ``saturated_share`` — share with ``E_aff <= -0.99`` (the energy can no longer rank them);
* ``hubs`` — the objects in the most verbs' top 5, with that share of verbs (objects tied at the
  5th place share the remaining places, so a saturated energy does not crown names early in
  the alphabet);
* ``properties_reaching_no_object`` — properties with no object edge ``w_po >= tau``;
* ``margins`` — per verb, ``E_aff`` of its 10th best object minus that of its best (0: the best
  object is not separated from the rest).

Pure functions over arrays (no bundle I/O, no compiler import), so the compiler can put them in
``report.json`` at build time and ``craftc diff`` / ``craftc diagnose`` can compute them for any
existing bundle. The margin ranking breaks ties by object name, as ``craftc diff`` does, so
the numbers are deterministic; values are rounded to 6 decimals so the report's bytes do not depend on the last
bit of a float sum.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

SATURATED = -0.99
TOP_K = 5
N_HUBS = 10
MARGIN_RANK = 10
DECIMALS = 6


def _r(x: float) -> float:
    return round(float(x), DECIMALS) + 0.0  # + 0.0: never -0.0 in JSON


def ranked_objects(energy_row: npt.NDArray[Any], objects: Sequence[str]) -> list[int]:
    """Object indices, lowest ``E_aff`` first, ties by object name."""
    return sorted(range(len(objects)), key=lambda i: (float(energy_row[i]), objects[i]))


def top_k_credit(energy_row: npt.NDArray[Any], k: int) -> npt.NDArray[np.float64]:
    """``[O]`` how much each object is in this verb's top ``k``: 1 strictly inside, and the
    objects tied at the boundary share the remaining slots equally (a saturated row with 40
    objects at -1.0 gives each 5/40, not the first five names 1). Only ``E_aff < 0`` counts."""
    row = np.asarray(energy_row, dtype=np.float64)
    credit = np.zeros(row.shape, dtype=np.float64)
    reach = row < 0.0
    if not reach.any():
        return credit
    values = np.sort(row[reach])
    if len(values) <= k:
        credit[reach] = 1.0
        return credit
    cut = values[k - 1]  # the k-th best energy
    inside = reach & (row < cut)
    tied = reach & (row == cut)
    credit[inside] = 1.0
    credit[tied] = (k - int(inside.sum())) / int(tied.sum())
    return credit


def discrimination_diagnostics(
    energy: npt.NDArray[Any],
    w_vp: npt.NDArray[Any],
    w_po: npt.NDArray[Any],
    verbs: Sequence[str],
    properties: Sequence[str],
    objects: Sequence[str],
    *,
    tau: float = 0.5,
    top_k: int = TOP_K,
    n_hubs: int = N_HUBS,
    margin_rank: int = MARGIN_RANK,
) -> dict[str, Any]:
    """The diagnostics above as a JSON-ready dict (the ``diagnostics`` of ``report.json``).

    ``energy`` ``[V, O]`` (any E_aff form; a "never pick" cell is +1 and counts as not
    affordant), ``w_vp`` ``[V, P]``, ``w_po`` ``[P, O]``. Only objects a verb reaches
    (``E_aff < 0``) enter its top ``top_k`` for the hub count. A verb with fewer than
    ``margin_rank`` objects uses its last one.
    """
    e = np.asarray(energy, dtype=np.float64)  # [V, O]
    n_v, n_o = e.shape
    if (n_v, n_o) != (len(verbs), len(objects)):
        raise ValueError(f"energy is {e.shape}, names give ({len(verbs)}, {len(objects)})")
    if w_vp.shape != (n_v, len(properties)) or w_po.shape != (len(properties), n_o):
        raise ValueError(f"w_vp {w_vp.shape} / w_po {w_po.shape} do not match {n_v} verbs, "
                         f"{len(properties)} properties, {n_o} objects")
    cells = max(e.size, 1)
    in_top = np.zeros(n_o, dtype=np.float64)  # [O] verbs whose top-k holds the object
    margins: dict[str, float] = {}
    # ranked_objects' order (energy, then name) as one lexsort per verb: O(V O log O) in C
    # rather than a Python sort (seconds at 1,000 x 10,000); only two ranks are read.
    name_rank = np.empty(n_o, dtype=np.int64)
    name_rank[sorted(range(n_o), key=objects.__getitem__)] = np.arange(n_o)
    for v, verb in enumerate(verbs):
        in_top += top_k_credit(e[v], top_k)
        if n_o:
            order = np.lexsort((name_rank, e[v]))
            last = int(order[min(margin_rank, n_o) - 1])
            margins[verb] = _r(e[v, last] - e[v, int(order[0])])
    shares = [_r(c / max(n_v, 1)) for c in in_top.tolist()]  # [O]
    hub_order = sorted(range(n_o), key=lambda i: (-shares[i], objects[i]))
    hubs = [{"object": objects[i], "top_k_share": shares[i]} for i in hub_order[:n_hubs] if shares[i] > 0]
    linked_arr: npt.NDArray[np.bool_] = np.asarray(((w_po >= tau) & (w_po > 0)).any(axis=1), dtype=bool)
    linked: list[bool] = linked_arr.tolist()  # [P]
    margin_values = list(margins.values())
    return {
        "affordant_share": _r((e < 0.0).sum() / cells),
        "saturated_share": _r((e <= SATURATED).sum() / cells),
        "top_k": top_k,
        "hubs": hubs,
        "max_hub_share": hubs[0]["top_k_share"] if hubs else 0.0,
        "properties_reaching_no_object": sorted(
            p for p, ok in zip(properties, linked, strict=True) if not ok
        ),
        "margin_rank": margin_rank,
        "margin_median": _r(float(np.median(margin_values))) if margin_values else 0.0,
        "margins": dict(sorted(margins.items())),
    }


def bundle_diagnostics(bundle: Any, energy: npt.NDArray[Any] | None = None) -> dict[str, Any]:
    """:func:`discrimination_diagnostics` of a loaded bundle (``energy``: another form's matrix,
    default the bundle's own ``affordance_energy.npy``)."""
    from ..grounding.energies import weight_matrices_from_graph

    m = bundle.manifest
    w_vp, w_po = weight_matrices_from_graph(bundle.graph, m.verbs, m.properties, m.objects)
    return discrimination_diagnostics(
        bundle.energy if energy is None else energy, w_vp, w_po, m.verbs, m.properties, m.objects,
        tau=m.energy.tau,
    )


def dead_property_notes(bundle: Any, names: Sequence[str], strongest: int = 3) -> list[str]:
    """One line per property in ``names`` (ones reaching no object): the verbs that lean on it
    with their ``w_vp``, and its strongest object edges, all below the bundle's tau.

    Why: a count says the KB has a dead end, not what to do about it. The strongest edges tell a
    KB author whether the vocabulary lacks such objects (the stage-2 answers scored the nearest
    ones low, as they should) or whether an answer missed an object that has the property."""
    from ..grounding.energies import weight_matrices_from_graph

    m = bundle.manifest
    w_vp, w_po = weight_matrices_from_graph(bundle.graph, m.verbs, m.properties, m.objects)
    lines = []
    for name in names:
        p = m.properties.index(name)
        verbs = [f"{m.verbs[v]} ({w_vp[v, p]:.2f})" for v in np.flatnonzero(w_vp[:, p] > 0).tolist()]
        order = np.argsort(-w_po[p], kind="stable")[:strongest].tolist()  # ties: manifest order
        best = [f"{m.objects[o]} {w_po[p, o]:.2f}" for o in order if w_po[p, o] > 0]
        lines.append(f"- {name}: used by {', '.join(verbs) or 'no verb'}; strongest object edges "
                     f"{', '.join(best) or 'none'} (tau {m.energy.tau:g})")
    return lines


#: Headline rows of a diagnostics comparison: (key, label, lower is better?).
HEADLINE = (
    ("affordant_share", "affordant cells (E_aff < 0)", True),
    ("saturated_share", "saturated cells (E_aff <= -0.99)", True),
    ("max_hub_share", "biggest hub: share of verbs with it in their top 5", True),
    ("properties_reaching_no_object", "properties reaching no object", True),
    ("margin_median", "median margin best vs 10th object", False),
)


def headline_value(diag: dict[str, Any], key: str) -> float:
    value = diag.get(key, 0.0)
    return float(len(value)) if isinstance(value, list) else float(value)


def markdown_summary(columns: dict[str, dict[str, Any]]) -> str:
    """A Markdown table: one column per diagnostics dict (e.g. before/after, or per form)."""
    names = list(columns)
    lines = ["| diagnostic | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for key, label, _ in HEADLINE:
        cells = []
        for n in names:
            v = headline_value(columns[n], key)
            cells.append(f"{v:.0f}" if key == "properties_reaching_no_object" else
                         f"{100 * v:.1f} %" if key.endswith("share") else f"{v:.3f}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append("")
    for n in names:
        hubs = ", ".join(f"{h['object']} ({100 * h['top_k_share']:.0f} %)" for h in columns[n].get("hubs", []))
        lines.append(f"- top hubs, {n}: {hubs or '—'}")
    return "\n".join(lines) + "\n"


def diagnostics_model(*args: Any, **kwargs: Any) -> Any:
    """:func:`discrimination_diagnostics` as the report's pydantic ``Diagnostics`` model."""
    from ...schemas.v1.bundle import Diagnostics

    return Diagnostics.model_validate(discrimination_diagnostics(*args, **kwargs))
