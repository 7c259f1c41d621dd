"""The paper's energies (eq. 1-5). Lower is better; alpha = beta = gamma = 1 by default.

``E_aff`` has two forms. The paper writes ``tanh(-sum_p w_vp + w_po)`` with ambiguous brackets;
our default reading is ``tanh(-sum_{p in P_v(o)} (w_vp + w_po))`` where ``P_v(o)`` are the
properties linking v to o with ``w_po >= tau``. The option ``normalized-product`` is
``-sum_p w_vp * w_po / sum_p w_vp`` over v's properties, in [-1, 0], which does not reward an
object merely for sharing many weak properties.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
import numpy.typing as npt

EnergyForm = Literal["sum-tanh", "normalized-product"]
FloatArray = npt.NDArray[np.float32]
DEFAULT_TAU = 0.5
FORBIDDEN_ENERGY = 1.0  # "never pick X for V": the worst possible E_aff (as the compiler writes it)


def affordance_energy_matrix(
    w_vp: FloatArray, w_po: FloatArray, *, tau: float = DEFAULT_TAU, form: EnergyForm = "sum-tanh"
) -> FloatArray:
    """E_aff for every verb x object pair.

    ``w_vp``: ``[V, P]`` verb->property weights (0 = no edge); ``w_po``: ``[P, O]``
    property->object weights (0 = no edge). Returns ``[V, O]`` float32.
    """
    w_vp64 = w_vp.astype(np.float64)
    link = (w_po >= tau) & (w_po > 0)  # [P, O] edges that count
    w_po_linked = np.where(link, w_po, 0.0).astype(np.float64)  # [P, O]
    if form == "sum-tanh":
        has_vp = (w_vp64 > 0).astype(np.float64)  # [V, P]
        total = w_vp64 @ link.astype(np.float64) + has_vp @ w_po_linked  # [V, O]
        result: FloatArray = np.tanh(-total).astype(np.float32)
        return result
    if form == "normalized-product":
        norm = np.maximum(w_vp64.sum(axis=1, keepdims=True), 1e-12)  # [V, 1]
        normalized: FloatArray = (-(w_vp64 @ w_po_linked) / norm).astype(np.float32)
        return normalized
    raise ValueError(f"unknown E_aff form {form!r}; use 'sum-tanh' or 'normalized-product'")


def grasp_energy(scores: npt.NDArray[np.floating] | list[float]) -> float:
    """E_grasp = -log(max_j s_ij), scores clipped to [1e-6, 1]; no grasp -> +inf (excluded)."""
    arr = np.asarray(scores, dtype=np.float64)
    if arr.size == 0:
        return float("inf")
    return float(-np.log(np.clip(arr.max(), 1e-6, 1.0)))


def align_energy(cosine: float | FloatArray) -> float | FloatArray:
    """E_align = tanh(-cos(phi_I(r), phi_T(v)))."""
    return np.tanh(-np.asarray(cosine)) if isinstance(cosine, np.ndarray) else float(np.tanh(-cosine))


def weight_matrices_from_graph(
    graph: dict[str, Any], verbs: list[str], properties: list[str], objects: list[str]
) -> tuple[FloatArray, FloatArray]:
    """``w_vp [V, P]`` and ``w_po [P, O]`` read back from a bundle's node-link ``graph.json``.

    The runtime needs the raw weights to score a bundle under the *other* E_aff form than the
    one its ``affordance_energy.npy`` was built with; the compiler is not importable here, so
    the matrices are rebuilt from the edges (ids ``verb:``, ``prop:``, ``obj:``) in one pass.
    """
    v_index = {f"verb:{v}": i for i, v in enumerate(verbs)}
    p_index = {f"prop:{p}": i for i, p in enumerate(properties)}
    o_index = {f"obj:{o}": i for i, o in enumerate(objects)}
    w_vp = np.zeros((len(verbs), len(properties)), dtype=np.float32)  # [V, P]
    w_po = np.zeros((len(properties), len(objects)), dtype=np.float32)  # [P, O]
    for edge in graph.get("edges", []):
        src, dst, weight = edge["source"], edge["target"], float(edge["weight"])
        if src in v_index and dst in p_index:
            w_vp[v_index[src], p_index[dst]] = weight
        elif src in p_index and dst in o_index:
            w_po[p_index[src], o_index[dst]] = weight
    return w_vp, w_po


def forbidden_pairs(graph: dict[str, Any]) -> list[tuple[str, str]]:
    """``(verb, object)`` pairs a KB author marked "never pick" (verb attribute ``forbidden_objects``)."""
    pairs: list[tuple[str, str]] = []
    for node in graph.get("nodes", []):
        if node.get("kind") == "verb":
            for obj in node.get("forbidden_objects", []):
                pairs.append((str(node["name"]), str(obj)))
    return pairs


def object_hypotheses(cosine: FloatArray, temperature: float) -> FloatArray:
    """p(o | r) = softmax(cos(phi_I(r), phi_T(o)) / T) over the last axis (``[N, O]`` -> ``[N, O]``).

    Max-subtracted so a small temperature cannot overflow ``exp``.
    """
    if temperature <= 0:
        raise ValueError(f"temperature must be > 0, got {temperature}")
    logits = cosine / np.float32(temperature)  # [N, O]
    logits = logits - logits.max(axis=-1, keepdims=True)
    weights = np.exp(logits)
    out: FloatArray = (weights / weights.sum(axis=-1, keepdims=True)).astype(np.float32)
    return out
