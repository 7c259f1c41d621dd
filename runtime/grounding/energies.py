"""The paper's energies (eq. 1-5). Lower is better; their weights are ``GroundingSettings``'.

``E_aff(v, o)`` comes in several forms, all computed from ``w_vp [V, P]``, ``w_po [P, O]`` and
the threshold ``tau`` (``P_v(o)`` = properties of v with ``w_po >= tau``):

* ``sum-tanh`` (the paper, our reading of its ambiguous brackets):
  ``tanh(-sum_{p in P_v(o)} (w_vp + w_po))``. It saturates: an object that shares three or four
  properties with the verb sits at -1, so it stops separating objects. Kept selectable and
  reported in every table.
* ``normalized-product``: ``-sum_p w_vp * w_po / sum_p w_vp`` over v's properties, in [-1, 0];
  an object is rewarded for the verb's *weight* it covers, not for the count of weak matches.
* ``specificity``: the normalized product with each property's w_vp scaled by an IDF-like
  factor ``s_p = log(O / df_p) / log(O)`` in [0, 1], ``df_p`` = objects with ``w_po >= tau``
  among the bundle's ``O`` objects. A property most objects have ("has a handle", "fits in one
  hand") says little about *which* object affords a verb, so it gets little weight; one only a
  few objects have gets nearly its full weight. A property no object has gets ``s_p = 1`` (it
  still counts in the denominator, as in the normalized product: the verb's knowledge that no
  object covers is not silently dropped).
* ``required-veto``: the normalized product, but an object lacking any of the verb's
  *required* properties (role ``required`` in the KB: without it the action fails) gets
  ``E_aff = 0`` — not affordant, whatever else it shares. A verb with no required property
  (every v1 bundle) falls back to the normalized product.
* ``specificity-veto``: ``specificity`` with the same veto.

Roles reach these functions as a boolean ``required [V, P]`` matrix (``None``: no roles known,
so the veto forms equal their base forms).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, Literal, Protocol, get_args

import numpy as np
import numpy.typing as npt

from ...schemas.v1.graph import Role


class WeightedGraph(Protocol):
    """What the weight matrices are read from: a bundle's ``KnowledgeGraph`` or its lighter
    ``GraphIndex`` (``runtime/kb/graph_index.py``), which give the same answers."""

    def vp_weights(self) -> dict[tuple[str, str], float]: ...

    def po_weights(self) -> dict[tuple[str, str], float]: ...

    def roles(self, verb: str) -> Mapping[str, Role]: ...

EnergyForm = Literal[
    "sum-tanh", "normalized-product", "specificity", "required-veto", "specificity-veto"
]
#: Every form, in table order (the paper's first).
ENERGY_FORMS: tuple[EnergyForm, ...] = get_args(EnergyForm)
FloatArray = npt.NDArray[np.float32]
BoolArray = npt.NDArray[np.bool_]
DEFAULT_TAU = 0.5
FORBIDDEN_ENERGY = 1.0  # "never pick X for V": the worst possible E_aff (as the compiler writes it)


def check_energy_form(form: str) -> EnergyForm:
    """``form`` as an :data:`EnergyForm`, or ``ValueError`` listing the valid ones."""
    if form not in ENERGY_FORMS:
        raise ValueError(f"unknown E_aff form {form!r}; use one of {', '.join(ENERGY_FORMS)}")
    return form


def property_specificity(w_po: FloatArray, *, tau: float = DEFAULT_TAU) -> npt.NDArray[np.float64]:
    """``[P]`` specificity ``log(O / df_p) / log(O)`` in [0, 1] (``df_p`` = objects linked to p).

    1 for a property of a single object (or of none), 0 for one every object has. With one
    object there is nothing to tell apart: every property gets 1.
    """
    n_obj = w_po.shape[1]
    df = ((w_po >= tau) & (w_po > 0)).sum(axis=1).astype(np.float64)  # [P]
    if n_obj <= 1:
        return np.ones(w_po.shape[0], dtype=np.float64)
    spec: npt.NDArray[np.float64] = np.log(n_obj / np.maximum(df, 1.0)) / np.log(n_obj)  # [P]
    out: npt.NDArray[np.float64] = np.clip(spec, 0.0, 1.0)
    return out


def _normalized_product(w_vp64: npt.NDArray[np.float64], w_po_linked: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    norm = np.maximum(w_vp64.sum(axis=1, keepdims=True), 1e-12)  # [V, 1]
    out: npt.NDArray[np.float64] = -(w_vp64 @ w_po_linked) / norm  # [V, O]
    return out


def affordance_energy_matrix(
    w_vp: FloatArray,
    w_po: FloatArray,
    *,
    tau: float = DEFAULT_TAU,
    form: EnergyForm = "sum-tanh",
    required: BoolArray | None = None,
) -> FloatArray:
    """E_aff for every verb x object pair (the forms are in the module docstring).

    ``w_vp``: ``[V, P]`` verb->property weights (0 = no edge); ``w_po``: ``[P, O]``
    property->object weights (0 = no edge); ``required``: ``[V, P]`` True where the verb's
    property has role ``required`` (only the veto forms read it). Returns ``[V, O]`` float32.
    """
    check_energy_form(form)
    w_vp64 = w_vp.astype(np.float64)
    link = (w_po >= tau) & (w_po > 0)  # [P, O] edges that count
    w_po_linked = np.where(link, w_po, 0.0).astype(np.float64)  # [P, O]
    if form == "sum-tanh":
        has_vp = (w_vp64 > 0).astype(np.float64)  # [V, P]
        total = w_vp64 @ link.astype(np.float64) + has_vp @ w_po_linked  # [V, O]
        result: FloatArray = np.tanh(-total).astype(np.float32)
        return result
    if form in ("specificity", "specificity-veto"):
        w_vp64 = w_vp64 * property_specificity(w_po, tau=tau)[None, :]  # [V, P]
    energy = _normalized_product(w_vp64, w_po_linked)  # [V, O]
    if form in ("required-veto", "specificity-veto") and required is not None:
        if required.shape != w_vp.shape:
            raise ValueError(f"required must be {w_vp.shape} like w_vp, got {required.shape}")
        req = (required & (w_vp > 0)).astype(np.float64)  # [V, P] only the verb's own properties
        # missing[v, o] = number of v's required properties that o lacks
        missing = req @ (~link).astype(np.float64)  # [V, O]
        energy = np.where(missing > 0, 0.0, energy)
    out: FloatArray = energy.astype(np.float32)
    return out


def energy_from_property_columns(
    w_vp: npt.NDArray[Any],
    q_weight: npt.NDArray[Any],
    q_link: npt.NDArray[Any],
    *,
    specificity: npt.NDArray[Any] | None,
    form: EnergyForm,
    required: BoolArray | None = None,
) -> FloatArray:
    """E_aff ``[V, N]`` of objects given as property columns rather than as KB objects.

    ``q_weight [P, N]`` is the (expected) linked weight ``w_po 1[w_po >= tau]`` and ``q_link
    [P, N]`` the (expected) link indicator; for a KB object they are its own linked column and
    0/1 indicator, and the result equals :func:`affordance_energy_matrix`'s column. Inferred
    objects (``runtime/grounding/open_world.py``) pass neighbour averages. ``specificity [P]`` is the
    *KB's* (an object added at run time must not change what a property says); ``None`` for
    the forms that do not read it. The veto counts a required property as missing when its link
    probability is below one half.
    """
    check_energy_form(form)
    w_vp64 = np.asarray(w_vp, dtype=np.float64)
    qw = np.asarray(q_weight, dtype=np.float64)
    ql = np.asarray(q_link, dtype=np.float64)
    if form == "sum-tanh":
        has_vp = (w_vp64 > 0).astype(np.float64)
        out_tanh: FloatArray = np.tanh(-(w_vp64 @ ql + has_vp @ qw)).astype(np.float32)
        return out_tanh
    if form in ("specificity", "specificity-veto"):
        if specificity is None:
            raise ValueError(f"form {form} needs the KB's property specificity")
        w_vp64 = w_vp64 * np.asarray(specificity, dtype=np.float64)[None, :]
    energy = _normalized_product(w_vp64, qw)
    if form in ("required-veto", "specificity-veto") and required is not None:
        req = (np.asarray(required) & (np.asarray(w_vp) > 0)).astype(np.float64)  # [V, P]
        missing = req @ (ql < 0.5).astype(np.float64)  # [V, N]
        energy = np.where(missing > 0, 0.0, energy)
    out: FloatArray = energy.astype(np.float32)
    return out


def verb_best_divisor(energy: npt.NDArray[Any]) -> FloatArray:
    """``[V, 1]`` divisors that put each row's most negative E_aff at -1 (``aff_norm`` "verb-best").

    ``energy [V, O]`` is the bundle's E_aff over *its own* objects, so a verb's scale is a fact of
    the KB, the same whatever scene vocabulary is grounded. A row with no affordant object (no
    negative value) keeps divisor 1: nothing to scale.
    """
    # the minimum of each row in the matrix's own type, then widened: the same values as
    # widening first (a minimum is one of the entries, and widening is exact), without a float64
    # copy of a [V, O] matrix (0.6 s of ``Grounder()`` at 1,000 x 10,000)
    best = -np.min(np.asarray(energy), axis=1, keepdims=True).astype(np.float64)  # [V, 1]
    out: FloatArray = np.where(best > 1e-9, best, 1.0).astype(np.float32)
    return out


def scale_negative(energy: npt.NDArray[Any], divisor: FloatArray) -> FloatArray:
    """``energy [V, N]`` with its negative (affordant) entries divided by ``divisor [V, 1]``.

    Positive entries are the forbidden value (``FORBIDDEN_ENERGY``, "never pick X for V") and
    stay as they are: scaling them would push them past the worst value a bundle can hold.
    """
    e = np.asarray(energy, dtype=np.float32)
    # one [V, N] result, divided where negative: the values of ``np.where(e < 0, e / divisor, e)``
    # without its two [V, N] temporaries (0.5 s of ``Grounder()`` at 1,000 x 10,000)
    out: FloatArray = e.copy()
    np.divide(e, divisor, out=out, where=e < 0)
    return out


def grasp_energy(scores: npt.NDArray[np.floating] | list[float]) -> float:
    """E_grasp = -log(max_j s_ij), scores clipped to [1e-6, 1]; no grasp -> +inf (excluded)."""
    arr = np.asarray(scores, dtype=np.float64)
    if arr.size == 0:
        return float("inf")
    return float(-np.log(np.clip(arr.max(), 1e-6, 1.0)))


def weight_matrices_from_graph(
    graph: WeightedGraph, verbs: list[str], properties: list[str], objects: list[str]
) -> tuple[FloatArray, FloatArray]:
    """``w_vp [V, P]`` and ``w_po [P, O]`` of a bundle's graph, in manifest order.

    The runtime needs the raw weights to score a bundle under the *other* E_aff form than the
    one its ``affordance_energy.npy`` was built with; the compiler is not importable here, so
    the matrices are rebuilt from the graph's edges.
    """
    v_index = {v: i for i, v in enumerate(verbs)}
    p_index = {p: i for i, p in enumerate(properties)}
    o_index = {o: i for i, o in enumerate(objects)}
    w_vp = np.zeros((len(verbs), len(properties)), dtype=np.float32)  # [V, P]
    w_po = np.zeros((len(properties), len(objects)), dtype=np.float32)  # [P, O]
    for (v, p), weight in graph.vp_weights().items():
        if v in v_index and p in p_index:
            w_vp[v_index[v], p_index[p]] = weight
    for (p, o), weight in graph.po_weights().items():
        if p in p_index and o in o_index:
            w_po[p_index[p], o_index[o]] = weight
    return w_vp, w_po


def required_matrix_from_graph(
    graph: WeightedGraph, verbs: list[str], properties: list[str]
) -> BoolArray:
    """``required [V, P]``: True where a verb -> property edge has ``role: "required"``.

    v2 KBs mark each of a verb's properties *required* (without it the action fails) or
    *helpful*; v1 bundles have no ``role`` attribute, read as helpful (all False), so the veto
    forms reduce to their base forms on them.
    """
    p_index = {p: i for i, p in enumerate(properties)}
    required = np.zeros((len(verbs), len(properties)), dtype=bool)  # [V, P]
    for vi, v in enumerate(verbs):
        for p, role in graph.roles(v).items():
            if role == "required" and p in p_index:
                required[vi, p_index[p]] = True
    return required


def energy_from_graph(
    graph: WeightedGraph,
    forbidden: Iterable[tuple[str, str]],
    verbs: list[str],
    properties: list[str],
    objects: list[str],
    *,
    tau: float,
    form: EnergyForm,
) -> FloatArray:
    """``[V, O]`` E_aff in ``form`` from a bundle's graph: its weights, its roles (only the veto
    forms read them) and its "never pick" pairs (``forbidden``: verb, object) at
    ``FORBIDDEN_ENERGY``, exactly as ``craftc build`` computes ``affordance_energy.npy``.

    Used to score a bundle in another form than it was built with, and by ``craftc validate`` /
    ``pack`` to check that the stored energies are its graph's (``runtime/kb/energy_check.py``).
    """
    w_vp, w_po = weight_matrices_from_graph(graph, verbs, properties, objects)
    required = required_matrix_from_graph(graph, verbs, properties)  # [V, P]
    energy = affordance_energy_matrix(w_vp, w_po, tau=tau, form=form, required=required)
    v_index = {v: i for i, v in enumerate(verbs)}
    o_index = {o: i for i, o in enumerate(objects)}
    for v, o in forbidden:
        if v in v_index and o in o_index:
            energy[v_index[v], o_index[o]] = FORBIDDEN_ENERGY
    return energy


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
