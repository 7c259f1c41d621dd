"""``ground(verb, rois)``: pick the ROI that affords the verb and can be grasped, and say why.

Each ROI is scored with the paper's energy (eq. 1), lower is better:

    E(v, r) = alpha * E_grasp(G_r) + beta * E_aff(v, r) + gamma * E_align(r, v)

* ``E_grasp = -log(max_j s_j)``, scores clipped to [1e-6, 1]; an ROI without grasps cannot be
  acted on, so it is excluded (and listed with that reason, never dropped silently).
* ``E_aff(v, r) = sum_o p(o | r) E_aff(v, o)`` ("expected", default) or ``E_aff(v, argmax_o p)``
  ("argmax"), with ``p(o | r) = softmax(cos(phi_I(r), phi_T(o)) / T)`` over the scene's object
  vocabulary: the runtime never needs a class label, only a distribution over hypotheses.
* ``E_align = tanh(-cos(phi_I(r), phi_T(verb query)))``, the query embedded through the bundle's
  stored template ("something to {verb}").

Everything that depends only on the bundle and the options (normalized object embeddings, the
``[V, O]`` affordance matrix in the requested form, verb queries, path index) is computed once in
the ``Grounder`` constructor; ``ground`` is a few small matrix products (<1 ms for 10 ROIs and
400 objects).
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from ..encoders.base import TextEncoder
from ..encoders.conse import ClassTop, imagenet_class_names
from ..kb.bundle import Bundle, PathStep
from ..kb.colours import COLOUR_TERMS
from ..perception.roi import ROI
from .cavity_cue import (
    CONCAVE_PROPERTY,
    cavity_log_likelihood,
    cavity_table,
    with_cavity_cue,
)
from .colour_cue import (
    ColourCueUnavailableError,
    colour_log_likelihood,
    colour_table,
    with_colour_cue,
)
from .energies import (
    EnergyForm,
    check_energy_form,
    energy_from_graph,
    energy_from_property_columns,
    object_hypotheses,
    property_specificity,
    required_matrix_from_graph,
    scale_negative,
    verb_best_divisor,
    weight_matrices_from_graph,
)
from .hubness import HubnessUnavailableError, name_hubness, reference_for, with_hubness
from .lookalike_cue import (
    LookalikeCueUnavailableError,
    lookalike_log_likelihood,
    lookalike_table,
    with_lookalike_cue,
)
from .open_world import (
    REQUEST_MIN_CONFIDENCE,
    REQUEST_PROPERTIES,
    REQUEST_TEMPERATURE,
    REQUEST_VERBS,
    VERB_SHARE,
    ObjectInference,
    ObjectModel,
    OpenWorldError,
    RequestMapping,
    linked_weights,
    map_request,
    parse_request,
)
from .senses import embed_glosses, read_in_sense
from .settings import AffMode, GroundingSettings
from .size_cue import SizeCueUnavailableError, size_log_likelihood, size_table, with_size_cue

FloatArray = npt.NDArray[np.float32]
GRASP_SCORE_MIN = 1e-6


class UnknownVerbError(ValueError):
    """The verb is not in the bundle (and the open-vocabulary fallback is off)."""

    def __init__(self, verb: str, kb: str, close_matches: list[str]) -> None:
        self.verb = verb
        self.close_matches = close_matches
        hint = f"close matches: {', '.join(close_matches)}" if close_matches else "no close match"
        super().__init__(
            f"unknown verb {verb!r}: not in KB {kb} ({hint}); use one of the KB's verbs, rebuild "
            "the KB with it, or enable the open-vocabulary fallback (open_vocab=True / --open-vocab)"
        )


@dataclass(frozen=True)
class ObjectHypothesis:
    name: str
    probability: float


@dataclass(frozen=True)
class RankedROI:
    """One scored ROI. ``paths`` explain ``E_aff`` for the top object hypothesis."""

    index: int  # position in the ``rois`` passed to ``ground``
    roi: ROI
    e_grasp: float
    e_aff: float
    e_align: float
    total: float
    grasp_index: int
    hypotheses: list[ObjectHypothesis]
    paths: list[PathStep]
    forbidden: bool  # the top hypothesis is marked "never pick" for this verb
    inference: ObjectInference | None = None  # the top hypothesis is not in the KB (issue 11)

    @property
    def grasp(self) -> Any:
        """The chosen grasp object (``None`` when only scores were given)."""
        return self.roi.grasps[self.grasp_index] if self.grasp_index < len(self.roi.grasps) else None


@dataclass(frozen=True)
class ExcludedROI:
    index: int
    roi: ROI
    reason: str


@dataclass
class Grounding:
    """The result of ``ground``: ranked ROIs (best first), excluded ROIs with reasons, settings."""

    verb: str
    ranked: list[RankedROI]
    excluded: list[ExcludedROI]
    kb: str
    settings: GroundingSettings  # resolved: energy_form is the one used
    open_vocab_used: bool = False
    nearest_verbs: list[tuple[str, float]] = field(default_factory=list)  # (verb, weight)
    notes: list[str] = field(default_factory=list)
    request: RequestMapping | None = None  # a request outside the verb list, mapped (issue 11)
    property_names: list[str] = field(default_factory=list)
    #: p(o | r) weighed some ROI's measured extents against typical sizes (``size_cue.py``)
    size_cue_used: bool = False
    #: p(o | r) weighed some ROI's colours against typical colours (``colour_cue.py``)
    colour_cue_used: bool = False
    #: p(o | r) weighed some ROI's ImageNet classes against the objects' look-alikes
    #: (``lookalike_cue.py``)
    lookalike_cue_used: bool = False
    #: p(o | r) weighed some ROI's open cavity against the objects' "is concave" weights
    #: (``cavity_cue.py``)
    cavity_cue_used: bool = False
    #: p(o | r) read each cosine less the name's hubness among the image encoder's labels
    #: (``hubness.py``)
    hubness_used: bool = False
    #: p(o | r) read some vocabulary name with its gloss (``senses.py``)
    senses_used: bool = False

    @property
    def abstained(self) -> bool:
        """The request could not be mapped confidently: nothing is chosen (``ranked`` is by
        grasp and alignment alone, for information)."""
        return self.request is not None and self.request.abstained

    @property
    def chosen(self) -> RankedROI | None:
        """The lowest-energy ROI, or ``None`` when every ROI was excluded or the request was
        abstained on."""
        return self.ranked[0] if self.ranked and not self.abstained else None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (embeddings, masks and grasp objects left out)."""
        def roi_dict(r: RankedROI) -> dict[str, Any]:
            return {
                "index": r.index, "label": r.roi.label, "box_xywh": list(r.roi.box_xywh),
                "e_grasp": r.e_grasp, "e_aff": r.e_aff, "e_align": r.e_align, "total": r.total,
                "grasp_index": r.grasp_index, "forbidden": r.forbidden,
                "inferred": None if r.inference is None else r.inference.to_dict(),
                "grasp_score": float(r.roi.grasp_scores[r.grasp_index]),
                "hypotheses": [{"object": h.name, "p": h.probability} for h in r.hypotheses],
                "extents_cm": None if r.roi.extents_m is None else [round(100 * v, 1) for v in r.roi.extents_m],
                "colours": None if r.roi.colours is None else _named_colours(r.roi.colours),
                **({"cavity_cm": None if r.roi.cavity_m is None else round(100 * r.roi.cavity_m, 1)}
                   if self.cavity_cue_used else {}),
                "paths": [{"property": p.prop, "object": p.obj, "w_vp": p.w_vp, "w_po": p.w_po,
                           "records": list(p.provenance)} for p in r.paths],
            }
        return {
            "verb": self.verb, "kb": self.kb,
            "settings": self.settings.energy_dict(),
            "open_vocab_used": self.open_vocab_used,
            "size_cue_used": self.size_cue_used,
            "colour_cue_used": self.colour_cue_used,
            **({"lookalike_cue_used": True} if self.lookalike_cue_used else {}),
            **({"cavity_cue_used": True} if self.cavity_cue_used else {}),
            **({"hubness_used": True} if self.hubness_used else {}),
            **({"senses_used": True} if self.senses_used else {}),
            "nearest_verbs": [{"verb": v, "weight": w} for v, w in self.nearest_verbs],
            "chosen": self.chosen.index if self.chosen else None,
            "abstained": self.abstained,
            "request": None if self.request is None else self.request.to_dict(self.property_names),
            "ranked": [roi_dict(r) for r in self.ranked],
            "excluded": [{"index": e.index, "label": e.roi.label, "box_xywh": list(e.roi.box_xywh),
                          "reason": e.reason} for e in self.excluded],
            "notes": list(self.notes),
        }

    def render(self, max_paths: int = 5) -> str:
        """A terminal report: ranking with energies, exclusions, and the chosen ROI's paths."""
        st = self.settings
        lines = [f"verb {self.verb!r} with KB {self.kb}  (alpha={st.alpha:g} beta={st.beta:g} "
                 f"gamma={st.gamma:g}, T={st.temperature:g}, E_aff {st.energy_form}/{st.aff_mode}"
                 f"{', scaled per verb' if st.aff_norm == 'verb-best' else ''}"
                 f"{', size cue' if self.size_cue_used else ''}{', colour cue' if self.colour_cue_used else ''}"
                 f"{', look-alike cue' if self.lookalike_cue_used else ''}"
                 f"{', cavity cue' if self.cavity_cue_used else ''}"
                 f"{', hubness-corrected' if self.hubness_used else ''}"
                 f"{', names in their sense' if self.senses_used else ''})"]
        if self.request is not None:
            lines.append(f"open vocabulary: {self.request.message()}")
        elif self.open_vocab_used:
            near = ", ".join(f"{v} ({w:.2f})" for v, w in self.nearest_verbs)
            lines.append(f"open vocabulary: {self.verb!r} is not in the KB; E_aff borrowed from {near}")
        lines += [f"note: {n}" for n in self.notes]
        lines.append(f"{'rank':>4} {'roi':>4} {'label':<14} {'E_total':>8} {'E_grasp':>8} {'E_aff':>8} "
                     f"{'E_align':>8}  object hypotheses")
        for rank, r in enumerate(self.ranked, start=1):
            hyp = ", ".join(f"{h.name} {h.probability:.2f}" for h in r.hypotheses)
            flag = "  [forbidden]" if r.forbidden else ""
            if r.inference is not None:
                flag += "  [inferred]" if r.inference.confident else "  [unknown object: alignment only]"
            lines.append(f"{rank:>4} {r.index:>4} {(r.roi.label or '-')[:14]:<14} {r.total:>8.3f} "
                         f"{r.e_grasp:>8.3f} {r.e_aff:>8.3f} {r.e_align:>8.3f}  {hyp}{flag}")
        for e in self.excluded:
            lines.append(f"   - {e.index:>4} {(e.roi.label or '-')[:14]:<14} excluded: {e.reason}")
        best = self.chosen
        if best is None:
            lines.append(f"abstained: {self.request.message()}" if self.abstained and self.request
                         else "no ROI can be chosen")
            return "\n".join(lines)
        top = best.hypotheses[0].name if best.hypotheses else "?"
        lines.append(f"chosen: ROI {best.index} (box {', '.join(f'{v:g}' for v in best.roi.box_xywh)}), "
                     f"grasp #{best.grasp_index}, most likely a {top!r}")
        if self.size_cue_used and best.roi.extents_m is not None:
            lines.append("measured from depth: " + " x ".join(f"{100 * v:.1f}" for v in best.roi.extents_m)
                         + " cm (the size cue weighed it against each object's typical size)")
        if self.colour_cue_used and best.roi.colours is not None:
            seen = ", ".join(f"{t} {100 * v:.0f} %" for t, v in _named_colours(best.roi.colours).items())
            lines.append(f"colours seen: {seen} (the colour cue weighed them against each object's "
                         "typical colours)")
        if self.lookalike_cue_used and best.roi.classes:
            names = imagenet_class_names()
            seen = ", ".join(f"{names[c]!r} {p:.2f}" for c, p in best.roi.classes[:3])
            lines.append(f"the image classifier saw: {seen} (the look-alike cue weighed them against "
                         "the classes each object's photos get)")
        if self.cavity_cue_used and best.roi.cavity_m is not None:
            lines.append(f"open cavity from depth: {100 * best.roi.cavity_m:.1f} cm below the rim (the cavity "
                         f"cue weighed it against each object's {CONCAVE_PROPERTY!r} weight)")
        if best.inference is not None:
            lines.append(best.inference.describe())
        if best.paths:
            shown = best.paths[0].obj
            rank = next((i for i, h in enumerate(best.hypotheses) if h.name == shown), 0)
            who = (f"{shown!r}" if rank == 0 else f"{shown!r} (hypothesis {rank + 1}, p {best.hypotheses[rank].probability:.2f}; "
                   f"no path for {top!r})")
            lines.append(f"why {who} affords {self.verb!r}:")
            for p in sorted(best.paths, key=lambda p: -(p.w_vp + p.w_po))[:max_paths]:
                rec = ",".join(k[:8] for k in p.provenance)
                lines.append(f"  {p.verb} -({p.w_vp:.2f})-> {p.prop} -({p.w_po:.2f})-> {p.obj}   [{rec}]")
        else:
            lines.append(f"no verb -> property -> {top!r} path in the KB")
        return "\n".join(lines)


@dataclass(frozen=True)
class EnergyTerms:
    """Vectorized energies of ``N`` ROIs (``[N]`` each) and their hypotheses ``p`` ``[N, O]``."""

    e_grasp: FloatArray
    e_aff: FloatArray
    e_align: FloatArray
    total: FloatArray
    p_obj: FloatArray


@dataclass(frozen=True)
class _VerbPlan:
    """Everything ``ground`` needs about one verb: its E_aff row, query vector, explanation."""

    row: FloatArray  # [O] E_aff(v, o) over the vocabulary
    query: FloatArray  # [d] unit verb-query embedding
    explain_verb: str | None  # whose KB paths explain the choice
    open_vocab: bool
    nearest: list[tuple[str, float]]
    forbidden: frozenset[str]
    request: RequestMapping | None = None


def _named_colours(shares: Sequence[float]) -> dict[str, float]:
    """An ROI's colour shares by term, largest first, terms under 5 % left out (for display)."""
    named = sorted(zip(COLOUR_TERMS, shares, strict=True), key=lambda tv: -tv[1])
    return {t: round(float(v), 3) for t, v in named if v >= 0.05}


def _unit_rows(x: npt.NDArray[Any]) -> FloatArray:
    x = np.asarray(x, dtype=np.float32)
    out: FloatArray = x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), np.float32(1e-12))
    return out


def _top_k(p: FloatArray, k: int) -> npt.NDArray[np.intp]:
    """Indices of the ``k`` largest entries per row, largest first (``[N, O]`` -> ``[N, k]``);
    a partial sort, since only a few hypotheses are reported out of hundreds of objects."""
    k = min(k, p.shape[1])
    if k >= p.shape[1]:
        return np.argsort(-p, axis=1, kind="stable")
    part = np.argpartition(-p, k - 1, axis=1)[:, :k]  # [N, k] unordered
    order = np.argsort(-np.take_along_axis(p, part, axis=1), axis=1, kind="stable")
    out: npt.NDArray[np.intp] = np.take_along_axis(part, order, axis=1)
    return out


def normalize_verb_name(raw: str) -> str:
    """Verbs as the compiler writes them (lowercase, single spaces); never fails."""
    from ...schemas.names import normalize_verb

    try:
        return normalize_verb(raw)
    except ValueError:
        return " ".join(raw.strip().lower().split())



def affordance_energy_in_form(bundle: Bundle, form: EnergyForm) -> FloatArray:
    """``[V, O]`` E_aff in ``form``: the bundle's own ``.npy``, or recomputed from its graph
    (with the verb -> property roles, which only the veto forms read)."""
    m = bundle.manifest
    check_energy_form(form)
    if form == m.energy.form:
        return bundle.energy
    return energy_from_graph(bundle.index, bundle.index.forbidden_pairs(), m.verbs, m.properties, m.objects,
                             tau=m.energy.tau, form=form)

class Grounder:
    """Scores ROIs against verbs with one bundle; construct once, call ``ground`` per request.

    ``energy_form`` ``None`` uses the form the bundle was built with (its ``.npy``); any other
    form (``energies.ENERGY_FORMS``) is recomputed from the graph's edges once. ``vocabulary``
    is the scene's object vocabulary for ``p(o | r)`` (default: every bundle object); names the bundle does not know
    are embedded with the text encoder and get ``E_aff = 0`` (no path, the neutral value of every
    form), listed in ``objects_without_knowledge``. ``open_vocab`` lets unknown verbs borrow
    the E_aff rows of the KB verbs most similar in embedding space. ``senses`` (name -> gloss)
    gives the glosses p(o | r) reads the names in (``senses.py``; default: the bundle's own, the
    sense each object was asked in); the evaluations pass one vocabulary's to every method.

    Latency: ``ground`` is a handful of small matrix products. With OpenBLAS threads contending
    for busy cores they can take milliseconds; set ``OPENBLAS_NUM_THREADS=1`` (the ``craft`` CLI
    does) before numpy is imported in a latency-sensitive process.
    """

    def __init__(
        self,
        bundle: Bundle,
        settings: GroundingSettings | None = None,
        *,
        text_encoder: TextEncoder | None = None,
        top_k_hypotheses: int = 3,
        object_min_confidence: float | None = None,
        request_min_confidence: float | None = None,
        senses: Mapping[str, str] | None = None,
    ) -> None:
        m = bundle.manifest
        self.settings = (settings or GroundingSettings()).with_form(m.energy.form)
        form = self.settings.form
        vocabulary = self.settings.vocabulary
        self.bundle = bundle
        self.top_k_hypotheses = top_k_hypotheses
        self._text_encoder = text_encoder
        self.kb = f"{m.kb_name}@{m.kb_version}"
        self.verbs = list(m.verbs)
        self.verb_index = dict(bundle.verb_index)

        full = self._affordance_matrix(bundle, form)  # [V, O_bundle]
        names = list(m.objects) if vocabulary is None else [self._object_name(o) for o in vocabulary]
        if len(set(names)) != len(names):
            dupes = sorted({n for n in names if names.count(n) > 1})
            raise ValueError(f"vocabulary lists {', '.join(dupes)} more than once; keep one entry for each object")
        if not names:
            raise ValueError("the object vocabulary is empty")
        self.vocabulary = names
        cols = [bundle.object_index.get(n, -1) for n in names]
        known = np.array([c >= 0 for c in cols])
        self.objects_without_knowledge = [n for n, c in zip(names, cols, strict=True) if c < 0]
        obj_emb = np.zeros((len(names), bundle.embeddings["object"].shape[1]), dtype=np.float32)  # [O, d]
        idx = np.array([max(c, 0) for c in cols])
        obj_emb[known] = bundle.embeddings["object"][idx[known]]
        if self.objects_without_knowledge:
            obj_emb[~known] = self._encoder().embed(self.objects_without_knowledge)
        # p(o | r)'s side of each name: read in its sense (grounding/senses.py); the open-world
        # inference below compares names as names
        glosses = [(senses.get(n) if senses is not None else bundle.index.gloss(n)) or None for n in names]
        self.senses_read = sum(g is not None for g in glosses) if self.settings.sense_weight > 0 else 0
        sensed = read_in_sense(obj_emb, glosses, self.settings.sense_weight, self._embed_glosses)
        self._obj_emb_t = np.ascontiguousarray(_unit_rows(sensed).T)  # [d, O]
        self._eaff = full[:, idx].astype(np.float32, copy=False)  # [V, O] (a copy: fancy indexing)
        self._eaff[:, ~known] = 0.0  # no path to a name the bundle does not know
        self._verb_query = _unit_rows(bundle.embeddings["verb_query"])  # [V, d]
        self.dim = int(obj_emb.shape[1])
        self._size_table = size_table(names, bundle.sizes) if self.settings.size_cue is not False else None
        if self.settings.size_cue is True and self._size_table is None:
            raise SizeCueUnavailableError(self._uncovered("--size-cue", "typical size", names, bundle.sizes,
                                                          "object_size", "the size cue"))
        self._colour_table = colour_table(names, bundle.colours) if self.settings.colour_cue is True else None
        if self.settings.colour_cue is True and self._colour_table is None:
            raise ColourCueUnavailableError(self._uncovered("--colour-cue", "typical colours", names,
                                                            bundle.colours, "object_colour", "the colour cue"))
        self._lookalike_table = (lookalike_table(names, bundle.lookalikes, imagenet_class_names())
                                 if self.settings.lookalikes is True else None)
        if self.settings.lookalikes is True and self._lookalike_table is None:
            raise LookalikeCueUnavailableError(self._uncovered(
                "--lookalikes", "look-alike classes", names, bundle.lookalikes, "object_lookalike",
                "the look-alike cue"))
        # a property check: only a bundle whose graph defines the property takes it (see cavity_cue.py)
        self._cavity_table = cavity_table(names, bundle) if self.settings.cavity_cue is not False else None
        self._hubness = self._name_hubness(sensed)
        self._open_world(bundle, form, names, known, idx, obj_emb, object_min_confidence, request_min_confidence)
        if self.settings.aff_norm == "verb-best":  # each verb by its best object in the bundle itself
            self._eaff = scale_negative(self._eaff, verb_best_divisor(full))

        self._forbidden: dict[str, frozenset[str]] = {}
        for v, o in bundle.index.forbidden_pairs():
            self._forbidden[v] = self._forbidden.get(v, frozenset()) | {o}
        tau = m.energy.tau
        # record ids of the linking property -> object edges (w_po >= tau), for explanations
        self._po_records: dict[tuple[str, str], tuple[str, ...]] = {
            (p, e.target_name): tuple(e.provenance)
            for p, edges in bundle.index.property_objects.items() for e in edges if e.weight >= tau and e.weight > 0}
        self._paths: dict[tuple[str, str], list[PathStep]] = {}
        self._plans: dict[str, _VerbPlan] = {}

    # -- precomputation ------------------------------------------------------------------------

    def _name_hubness(self, obj_emb: FloatArray) -> FloatArray | None:
        """``[O]`` each vocabulary name's hubness among the image encoder's labels
        (``grounding/hubness.py``), or None when the correction is off or has no labels."""
        if self.settings.hubness is False:
            return None
        enc = self.bundle.manifest.text_encoder
        reference = reference_for(enc.id, enc.weights_sha256, self.settings.class_senses)
        if reference is None:
            if self.settings.hubness is True:
                raise HubnessUnavailableError(
                    f"--hubness: the bundle {self.kb} embeds text with {enc.id}, whose space no image "
                    "encoder here labels (the correction needs ConSE's MiniLM space); ground without --hubness")
            return None
        return name_hubness(obj_emb, reference)

    def _open_world(self, bundle: Bundle, form: EnergyForm, names: list[str], known: npt.NDArray[np.bool_],
                    idx: npt.NDArray[np.intp], obj_emb: FloatArray, object_min_confidence: float | None,
                    request_min_confidence: float | None) -> None:
        """Property columns of the vocabulary (KB objects: their own; unknown ones: inferred from
        similar KB objects, ``runtime/grounding/open_world.py``) and the request-mapping parameters."""
        m = bundle.manifest
        tau = m.energy.tau
        self._w_vp, w_po = weight_matrices_from_graph(bundle.index, m.verbs, m.properties, m.objects)
        self._required = required_matrix_from_graph(bundle.index, m.verbs, m.properties)
        self._spec = property_specificity(w_po, tau=tau)
        self.properties = list(m.properties)
        self._prop_index = {p: i for i, p in enumerate(self.properties)}
        self._vocab_index = {n: i for i, n in enumerate(names)}
        weight, link = linked_weights(w_po, tau)  # [P, O_bundle]
        self._bundle_w, self._bundle_l = weight, link  # a request's E_aff over the bundle (aff_norm)
        self._col_w = np.where(known[None, :], weight[:, idx], 0.0)  # [P, O]
        self._col_l = np.where(known[None, :], link[:, idx], 0.0)
        self.inferred: dict[str, ObjectInference] = {}
        ow = bundle.open_world or {}
        self._request_params: dict[str, Any] = dict(ow.get("requests") or {
            "verbs": REQUEST_VERBS, "properties": REQUEST_PROPERTIES,
            "temperature": REQUEST_TEMPERATURE, "verb_share": VERB_SHARE,
            "min_confidence": REQUEST_MIN_CONFIDENCE})
        if request_min_confidence is not None:
            self._request_params["min_confidence"] = float(request_min_confidence)
        self.open_world_available = bundle.open_world is not None
        unknown = ~known
        if not unknown.any() or bundle.open_world is None:
            return
        try:
            model = ObjectModel.from_params(bundle.open_world["objects"], m.objects, bundle.embeddings["object"],
                                            w_po, tau, object_min_confidence)
        except (KeyError, TypeError, OpenWorldError) as exc:
            raise ValueError(f"{bundle.path}/open_world.json: {exc}; rebuild the bundle") from None
        unknown_names = [n for n, k in zip(names, known.tolist(), strict=True) if not k]
        q_w, q_l, infos = model.infer(unknown_names, obj_emb[unknown])
        self._col_w[:, unknown] = q_w
        self._col_l[:, unknown] = q_l
        self._eaff[:, unknown] = energy_from_property_columns(
            self._w_vp, q_w, q_l, specificity=self._spec, form=form, required=self._required)
        self.inferred = {i.name: i for i in infos}

    @staticmethod
    def _object_name(raw: str) -> str:
        from ...schemas.names import normalize_name

        try:
            return normalize_name(raw)
        except ValueError:
            return raw.strip().lower()

    @staticmethod
    def _affordance_matrix(bundle: Bundle, form: EnergyForm) -> FloatArray:
        return affordance_energy_in_form(bundle, form)

    def _encoder(self) -> TextEncoder:
        """The bundle's text encoder, loaded on first need (unknown objects, open vocabulary)."""
        if self._text_encoder is None:
            from ..encoders.text import load_text_encoder

            self._text_encoder = load_text_encoder(self.bundle.manifest.text_encoder.id)
        return self._text_encoder

    def _embed_glosses(self, glosses: list[str]) -> FloatArray:
        """The glosses' embeddings (``senses.embed_glosses``): kept on disk when the bundle's text
        encoder is the shipped MiniLM and no stand-in was passed, so a restart or a worker reads
        them without loading the encoder."""
        from ..encoders.text import MINILM_ID, MINILM_SHA256, MiniLMTextEncoder

        enc = self.bundle.manifest.text_encoder
        shipped = (enc.id, enc.weights_sha256) == (MINILM_ID, MINILM_SHA256) and (
            self._text_encoder is None or isinstance(self._text_encoder, MiniLMTextEncoder))
        return embed_glosses(glosses, self._encoder, (enc.id, enc.weights_sha256) if shipped else None)

    def _plan(self, verb: str) -> _VerbPlan:
        cached = self._plans.get(verb)
        if cached is not None:
            return cached
        vi = self.verb_index.get(verb)
        if vi is not None:
            plan = _VerbPlan(self._eaff[vi], self._verb_query[vi], verb, False, [],
                             self._forbidden.get(verb, frozenset()))
        elif self.open_vocab:
            task = normalize_verb_name(parse_request(verb))
            plan = self._plan(task) if task in self.verb_index else self._request_plan(verb, task)
        else:
            raise UnknownVerbError(verb, self.kb, difflib.get_close_matches(verb, self.verbs, n=5, cutoff=0.6))
        self._plans[verb] = plan
        return plan

    def _request_plan(self, request: str, task: str) -> _VerbPlan:
        """A request outside the verb list: property weights from similar verbs and properties,
        or an abstention below the confidence floor (``open_world.map_request``)."""
        template = self.bundle.manifest.text_encoder.verb_template
        emb = _unit_rows(self._encoder().embed([task, template.format(verb=task)]))  # [2, d]
        e = self.bundle.embeddings
        mapping = map_request(
            request, task, emb[0], emb[1], verbs=self.verbs, verb_embeddings=e["verb"],
            verb_query_embeddings=e["verb_query"], properties=self.properties,
            property_embeddings=e["property"], w_vp=self._w_vp, required=self._required,
            params=self._request_params)
        if mapping.abstained:
            row: FloatArray = np.zeros(len(self.vocabulary), dtype=np.float32)
        else:
            row = energy_from_property_columns(
                mapping.weights[None, :], self._col_w, self._col_l, specificity=self._spec,
                form=self.energy_form, required=mapping.required[None, :])[0]
            if self.settings.aff_norm == "verb-best":  # scaled like a KB verb: by its best bundle object
                over_bundle = energy_from_property_columns(
                    mapping.weights[None, :], self._bundle_w, self._bundle_l, specificity=self._spec,
                    form=self.energy_form, required=mapping.required[None, :])  # [1, O_bundle]
                row = scale_negative(row[None, :], verb_best_divisor(over_bundle))[0]
        nearest = [(v, w) for v, w, _ in mapping.verbs]
        return _VerbPlan(row, emb[1], None, True, nearest, frozenset(), mapping)

    def _inferred_paths(self, plan: _VerbPlan, obj: str, limit: int = 5) -> list[PathStep]:
        """Paths of a request mapping (request -> property -> object), or of a KB verb to an
        inferred object; inferred edges carry the record id ``inferred``."""
        j = self._vocab_index.get(obj)
        if j is None:
            return []
        inferred = obj in self.inferred
        steps: list[PathStep] = []
        if plan.request is not None:
            w = plan.request.weights
            for p in np.flatnonzero(w > 0).tolist():
                w_po = float(self._col_w[p, j])
                if w_po <= 0:
                    continue
                prop = self.properties[p]
                records = self._po_records.get((prop, obj))
                prov = ("inferred",) if inferred or records is None else records
                steps.append(PathStep(plan.request.task, prop, obj, round(float(w[p]), 4), round(w_po, 4), prov))
        elif plan.explain_verb is not None and inferred:
            for vp in self.bundle.index.verb_properties.get(plan.explain_verb, []):
                w_po = float(self._col_w[self._prop_index[vp.target_name], j])
                if w_po > 0:
                    steps.append(PathStep(plan.explain_verb, vp.target_name, obj, vp.weight, round(w_po, 4),
                                          (*vp.provenance, "inferred")))
        steps.sort(key=lambda s: -(s.w_vp * s.w_po))
        return steps[:limit]

    def _explaining_paths(self, verb: str, hypotheses: Sequence[ObjectHypothesis]) -> list[PathStep]:
        """The paths of the most probable hypothesis that has any (E_aff is the expectation over
        hypotheses: a top name without a path adds nothing to it, and the next one explains it);
        none when no hypothesis shown has a path."""
        for h in hypotheses:
            if h.name in self.inferred:
                break  # an inferred object's support is not a path: the top-name rule applies
            found = self.paths(verb, h.name)
            if found:
                return found
        return []

    def paths(self, verb: str, obj: str) -> list[PathStep]:
        """verb -> property -> object paths (w_po >= tau) behind E_aff(verb, obj), cached."""
        key = (verb, obj)
        found = self._paths.get(key)
        if found is None:
            found = self._paths[key] = self.bundle.paths(verb, obj)
        return found

    def with_weights(self, alpha: float, beta: float, gamma: float) -> Grounder:
        """The same grounder with other energy weights, sharing every precomputed matrix.

        The weights are read only when the three energies are combined, so a shallow copy is
        enough; keep it that way if precomputation ever starts depending on them.
        """
        import copy

        variant = copy.copy(self)
        variant.settings = self.settings.model_copy(
            update={"alpha": float(alpha), "beta": float(beta), "gamma": float(gamma)})
        return variant

    # The settings, read where the scores are combined (``with_weights`` swaps them).
    @property
    def alpha(self) -> float:
        return self.settings.alpha

    @property
    def beta(self) -> float:
        return self.settings.beta

    def _uncovered(self, option: str, what: str, names: Sequence[str], known: Mapping[str, object],
                   prompt: str, cue: str) -> str:
        """The error of a required cue whose knowledge the bundle lacks for some of ``names``."""
        missing = [n for n in names if n not in known]
        return (f"{option}: {self.kb} has no {what} for {len(missing)} of the {len(names)} vocabulary objects "
                f"({', '.join(missing[:5])}{', ...' if len(missing) > 5 else ''}); record them (craftc curate "
                f"pending --prompt {prompt}) and rebuild the bundle, or ground without {cue}")

    @property
    def gamma(self) -> float:
        return self.settings.gamma

    @property
    def size_cue_active(self) -> bool:
        """Whether ``p(o | r)`` weighs measured extents (on, and every vocabulary object has a size)."""
        return self._size_table is not None

    @property
    def colour_cue_active(self) -> bool:
        """Whether ``p(o | r)`` weighs measured colours (on, and every vocabulary object has them)."""
        return self._colour_table is not None

    @property
    def lookalike_cue_active(self) -> bool:
        """Whether ``p(o | r)`` weighs the ROIs' ImageNet classes (on, and every vocabulary object
        has look-alike classes)."""
        return self._lookalike_table is not None

    @property
    def cavity_cue_active(self) -> bool:
        """Whether ``p(o | r)`` weighs the ROIs' open cavities (on, and the bundle's graph says
        which vocabulary objects are hollow)."""
        return self._cavity_table is not None

    @property
    def hubness_active(self) -> bool:
        """Whether ``p(o | r)`` reads cosines less the names' hubness (``grounding/hubness.py``)."""
        return self._hubness is not None

    @property
    def senses_active(self) -> bool:
        """Whether ``p(o | r)`` reads some vocabulary name with its gloss (``grounding/senses.py``)."""
        return self.senses_read > 0

    @property
    def temperature(self) -> float:
        return self.settings.temperature

    @property
    def aff_mode(self) -> AffMode:
        return self.settings.aff_mode

    @property
    def energy_form(self) -> EnergyForm:
        return self.settings.form

    @property
    def open_vocab(self) -> bool:
        return self.settings.open_vocab

    def knows_verb(self, verb: str) -> bool:
        """Whether ``verb`` is in the bundle (else ``ground`` needs the open-vocabulary fallback)."""
        return normalize_verb_name(verb) in self.verb_index

    # -- scoring -------------------------------------------------------------------------------

    def energies(self, verb: str, embeddings: npt.NDArray[Any], grasp_max: npt.NDArray[Any] | None = None,
                 p_obj: npt.NDArray[Any] | None = None, extents: npt.NDArray[Any] | None = None,
                 colours: npt.NDArray[Any] | None = None,
                 classes: Sequence[ClassTop | None] | None = None,
                 cavities: npt.NDArray[Any] | None = None) -> EnergyTerms:
        """The three energies for ``N`` ROIs at once: ``embeddings`` ``[N, d]``, ``grasp_max``
        ``[N]`` best grasp score per ROI (``None``: no grasp term, E_grasp = 0). ``p_obj``
        ``[N, O]`` over ``vocabulary`` replaces the perceived ``p(o | r)`` (diagnostics, e.g. the
        sim testbed's knowledge-vs-perception split with p set to the true class). ``extents``
        ``[N, 3]`` (metres, longest first; NaN rows: unmeasured) feed the size cue when it is on,
        ``colours`` ``[N, 11]`` (shares per colour term; NaN rows: unmeasured) the colour cue and
        ``classes`` (each ROI's top ImageNet classes, or None) the look-alike cue and ``cavities``
        ``[N]`` (metres; NaN: unmeasured) the cavity cue."""
        return self._energies(self._plan(normalize_verb_name(verb)), embeddings, grasp_max, p_obj, extents,
                              colours, classes, cavities)

    def image_hypotheses(self, embeddings: npt.NDArray[Any]) -> FloatArray:
        """``[N, O]`` p(o | r) over ``vocabulary`` from the image embeddings alone, read as
        ``energies`` reads it before any depth or colour cue: each name in its sense, less its
        hubness, softmax at ``temperature``. What a recognition score should rank, so that it
        measures the perception the grounder acts on."""
        return self._image_hypotheses(self._checked_unit_rows(embeddings))

    def _checked_roi(self, index: int, roi: ROI) -> FloatArray:
        """ROI ``index``'s embedding as a ``[d]`` vector, or a ``ValueError`` naming the ROI and
        the field: a vector of another width (numpy's own error named neither), and NaN or
        infinite embeddings or grasp scores, which ranked the ROI with a NaN total, silently."""
        vec = np.asarray(roi.image_embedding, dtype=np.float32).reshape(-1)
        if vec.shape[0] != self.dim:
            raise ValueError(f"ROI {index}: image_embedding has {vec.shape[0]} values, the bundle's text space "
                             f"{self.dim}; was the image encoder built for another text encoder?")
        if not np.isfinite(vec).all():
            raise ValueError(f"ROI {index}: image_embedding holds NaN or infinite values")
        if not np.isfinite(np.asarray(roi.grasp_scores, dtype=np.float64)).all():
            raise ValueError(f"ROI {index}: grasp_scores {list(roi.grasp_scores)} hold NaN or infinite values; "
                             "they are grasp qualities in [0, 1]")
        return vec

    def _checked_unit_rows(self, embeddings: npt.NDArray[Any]) -> FloatArray:
        emb = _unit_rows(embeddings)  # [N, d]
        if emb.ndim != 2 or emb.shape[1] != self.dim:
            raise ValueError(f"image embeddings must be [N, {self.dim}] (the bundle's text space), "
                             f"got {tuple(emb.shape)}; was the image encoder built for another text encoder?")
        if not np.isfinite(emb).all():  # NaN would rank silently (every total NaN)
            row = int(np.flatnonzero(~np.isfinite(emb).all(axis=1))[0])
            raise ValueError(f"image embeddings hold NaN or infinite values (row {row})")
        return emb

    def _image_hypotheses(self, emb: FloatArray) -> FloatArray:
        cosine = emb @ self._obj_emb_t  # [N, O]
        if self._hubness is not None:
            cosine = with_hubness(cosine, self._hubness)
        return object_hypotheses(cosine, self.temperature)  # [N, O]

    def _energies(self, plan: _VerbPlan, embeddings: npt.NDArray[Any], grasp_max: npt.NDArray[Any] | None,
                  p_obj: npt.NDArray[Any] | None = None, extents: npt.NDArray[Any] | None = None,
                  colours: npt.NDArray[Any] | None = None,
                  classes: Sequence[ClassTop | None] | None = None,
                  cavities: npt.NDArray[Any] | None = None) -> EnergyTerms:
        emb = self._checked_unit_rows(embeddings)  # [N, d]
        if p_obj is None:
            p = self._image_hypotheses(emb)  # [N, O]
            if self._size_table is not None and extents is not None:
                p = with_size_cue(p, size_log_likelihood(extents, self._size_table))
            if self._colour_table is not None and colours is not None:
                p = with_colour_cue(p, colour_log_likelihood(colours, self._colour_table))
            if self._lookalike_table is not None and classes is not None:
                p = with_lookalike_cue(p, lookalike_log_likelihood(classes, self._lookalike_table))
            if self._cavity_table is not None and cavities is not None:
                p = with_cavity_cue(p, cavity_log_likelihood(cavities, self._cavity_table))
        else:
            p = np.asarray(p_obj, dtype=np.float32)
            if p.shape != (len(emb), len(self.vocabulary)):
                raise ValueError(f"p_obj must be [{len(emb)}, {len(self.vocabulary)}], got {tuple(p.shape)}")
        # expected: sum_o p(o|r) E_aff(v, o); argmax: E_aff(v, most likely o)  -> [N]
        e_aff = p @ plan.row if self.aff_mode == "expected" else plan.row[np.argmax(p, axis=1)]
        e_align = np.tanh(-(emb @ plan.query))  # [N]
        e_grasp: FloatArray = np.zeros(len(emb), dtype=np.float32)  # [N]
        if grasp_max is not None:
            best = np.clip(np.asarray(grasp_max, dtype=np.float32), GRASP_SCORE_MIN, 1.0)  # [N]
            e_grasp = (0.0 - np.log(best)).astype(np.float32)  # 0.0 - ...: no -0.0 for s = 1
        total = self.alpha * e_grasp + self.beta * e_aff + self.gamma * e_align  # [N]
        f32 = np.float32
        return EnergyTerms(e_grasp.astype(f32), e_aff.astype(f32), e_align.astype(f32), total.astype(f32), p)

    def check_verb(self, verb: str) -> None:
        """Raise what ``ground`` would raise for ``verb`` (``UnknownVerbError`` with close matches),
        without any ROI: a caller about to perceive a frame (two network passes) asks first. The
        verb's plan is kept, so the grounding that follows does not make it again."""
        self._plan(normalize_verb_name(verb))

    def ground(self, verb: str, rois: Sequence[ROI]) -> Grounding:
        """Rank ``rois`` for ``verb`` (lowest total energy first); see the module docstring."""
        name = normalize_verb_name(verb)
        plan = self._plan(name)
        excluded: list[ExcludedROI] = []
        usable: list[int] = []
        for i, roi in enumerate(rois):
            if len(roi.grasp_scores) == 0:
                excluded.append(ExcludedROI(i, roi, "no grasp candidates: the robot cannot pick it up"))
            elif max(roi.grasp_scores) <= 0.0:  # E_grasp would clip 0 to 1e-6 and still rank it
                excluded.append(ExcludedROI(i, roi, "every grasp scored 0: no viable grasp"))
            elif roi.grasps and len(roi.grasps) != len(roi.grasp_scores):
                excluded.append(ExcludedROI(i, roi, f"{len(roi.grasps)} grasps but {len(roi.grasp_scores)} scores"))
            elif roi.image_embedding is None:
                excluded.append(ExcludedROI(i, roi, "no image embedding: no object hypothesis possible"))
            else:
                usable.append(i)
        ranked: list[RankedROI] = []
        size_cue_used = colour_cue_used = lookalike_cue_used = cavity_cue_used = False
        if usable:
            emb = np.stack([self._checked_roi(i, rois[i]) for i in usable])  # [N, d]
            best_grasp = [max(range(len(rois[i].grasp_scores)), key=rois[i].grasp_scores.__getitem__) for i in usable]
            gmax = np.array([rois[i].grasp_scores[g] for i, g in zip(usable, best_grasp, strict=True)], dtype=np.float32)
            # the cues' measurements, gathered only for a cue that is on (NaN rows: not measured)
            extents = None if self._size_table is None else np.array(
                [rois[i].extents_m if rois[i].extents_m is not None else (np.nan,) * 3 for i in usable],
                dtype=np.float64)  # [N, 3]
            colours = None if self._colour_table is None else np.array(
                [rois[i].colours if rois[i].colours is not None else (np.nan,) * len(COLOUR_TERMS) for i in usable],
                dtype=np.float64)  # [N, 11]
            size_cue_used = extents is not None and bool(np.isfinite(extents).all(axis=1).any())
            colour_cue_used = colours is not None and bool(np.isfinite(colours).all(axis=1).any())
            classes = None if self._lookalike_table is None else [rois[i].classes for i in usable]
            lookalike_cue_used = classes is not None and any(classes)
            cavities = None if self._cavity_table is None else np.array(
                [np.nan if rois[i].cavity_m is None else rois[i].cavity_m for i in usable], dtype=np.float64)  # [N]
            cavity_cue_used = cavities is not None and bool(np.isfinite(cavities).any())
            terms = self._energies(plan, emb, gmax, extents=extents, colours=colours, classes=classes,
                                   cavities=cavities)
            top = _top_k(terms.p_obj, self.top_k_hypotheses)  # [N, k]
            top_p = np.take_along_axis(terms.p_obj, top, axis=1).tolist()  # python floats, once
            top_i = top.tolist()
            e_grasp, e_aff = terms.e_grasp.tolist(), terms.e_aff.tolist()
            e_align, total = terms.e_align.tolist(), terms.total.tolist()
            for n in np.argsort(terms.total, kind="stable").tolist():
                hyps = [ObjectHypothesis(self.vocabulary[j], p) for j, p in zip(top_i[n], top_p[n], strict=True)]
                obj = hyps[0].name
                if plan.request is not None or obj in self.inferred:
                    paths = self._inferred_paths(plan, obj)
                else:
                    paths = self._explaining_paths(plan.explain_verb, hyps) if plan.explain_verb else []
                ranked.append(RankedROI(
                    index=usable[n], roi=rois[usable[n]], e_grasp=e_grasp[n], e_aff=e_aff[n],
                    e_align=e_align[n], total=total[n], grasp_index=best_grasp[n], hypotheses=hyps,
                    paths=paths, forbidden=obj in plan.forbidden, inference=self.inferred.get(obj),
                ))
        return Grounding(
            verb=name, ranked=ranked, excluded=excluded, kb=self.kb, settings=self.settings,
            open_vocab_used=plan.open_vocab, nearest_verbs=list(plan.nearest),
            request=plan.request, property_names=self.properties if plan.request is not None else [],
            notes=self._open_world_notes(plan, ranked), size_cue_used=size_cue_used,
            colour_cue_used=colour_cue_used, lookalike_cue_used=lookalike_cue_used, cavity_cue_used=cavity_cue_used,
            hubness_used=bool(usable) and self._hubness is not None,
            senses_used=bool(usable) and self.senses_active,
        )

    def _open_world_notes(self, plan: _VerbPlan, ranked: Sequence[RankedROI]) -> list[str]:
        notes: list[str] = []
        if plan.request is not None and plan.request.abstained:
            notes.append(plan.request.message())
        shown = {r.inference.name for r in ranked if r.inference is not None}
        for name in sorted(shown):
            notes.append(self.inferred[name].describe())
        if self.objects_without_knowledge and not self.open_world_available:
            notes.append("this bundle has no open-world model (open_world.json; built before issue 11): "
                         "objects outside the KB get E_aff = 0; rebuild it to infer them")
        return notes
