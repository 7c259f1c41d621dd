"""The paper's energies (eq. 1-5). Lower is better; alpha = beta = gamma = 1 by default.

``E_aff`` has two forms. The paper writes ``tanh(-sum_p w_vp + w_po)`` with ambiguous brackets;
our default reading is ``tanh(-sum_{p in P_v(o)} (w_vp + w_po))`` where ``P_v(o)`` are the
properties linking v to o with ``w_po >= tau``. The option ``normalized-product`` is
``-sum_p w_vp * w_po / sum_p w_vp`` over v's properties, in [-1, 0], which does not reward an
object merely for sharing many weak properties.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import numpy.typing as npt

EnergyForm = Literal["sum-tanh", "normalized-product"]
FloatArray = npt.NDArray[np.float32]
DEFAULT_TAU = 0.5


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
        return (-(w_vp64 @ w_po_linked) / norm).astype(np.float32)
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
