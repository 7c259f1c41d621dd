"""``GroundingSettings``: every option of ``ground`` in one frozen, validated object.

The options (energy weights, temperature, how E_aff is read, the scene vocabulary) are resolved
once — from the command line, a request body or a caller's code — into this model and then passed
whole to the ``Grounder``, the evaluators and the server, and stored in every result. Nothing
downstream re-checks a string: an invalid value is a ``ValueError`` here, naming the option.
"""

from __future__ import annotations

from typing import Any, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from .energies import ENERGY_FORMS, EnergyForm

AffMode = Literal["expected", "argmax"]
AFF_MODES: tuple[AffMode, ...] = get_args(AffMode)
#: How each verb's E_aff row is scaled (``Grounder``): ``none`` as the bundle computes it;
#: ``verb-best`` divided by its best (most negative) value over the bundle's objects, so every
#: verb's best KB object sits at -1 as under the paper's saturating sum-tanh.
AffNorm = Literal["none", "verb-best"]
AFF_NORMS: tuple[AffNorm, ...] = get_args(AffNorm)

#: Softmax temperature of p(o | r), fixed a priori: a round value at which a cosine gap of 0.1
#: between two object names multiplies their odds by e. It is fitted to no image set. (The former
#: 0.06 was calibrated on the 218 shared ImageNet photos, i.e. on the benchmark's own test images,
#: and is retired for that reason; ``imagenet.calibrate_temperature`` may be run on other images,
#: such as the testbed's renders, never on the benchmark's.)
DEFAULT_TEMPERATURE = 0.1

#: The image classifier's softmax temperature for ConSE's weights (``encoders/conse.py``, whose
#: ``DEFAULT_CONSE_TEMPERATURE`` a test keeps equal): 2, chosen on the dev renders, the sim-dev
#: scenes and the ImageNet dev labels (``docs/recognition.md``); 1 is ConSE's own weighting.
DEFAULT_CONSE_TEMPERATURE = 2.0

#: The energy weights (paper eq. 1) and E_aff's scaling. The paper sets alpha = beta = gamma = 1
#: for its sum-tanh E_aff, whose affording objects saturate at -1. Our KB's E_aff (the normalized
#: product, issue 9) rarely reaches -1, and how far below it a verb's best object stays depends on
#: the verb: -0.98 for *hammer* or *pour*, -0.6 to -0.7 for verbs whose properties are
#: alternatives (*play*, *serve*, *carry*; benchmarks/verb_best_energy.py). So each verb's row is
#: scaled by its best object in the bundle (``aff_norm`` "verb-best"), and the weights were
#: chosen with it: leave-one-verb-out over the dev units (ImageNet dev, sim-dev and sim-val
#: rendered scenes; 41 verbs) from beta in {1, 1.5, 2, 3, 4, 6, 8, 12, 16} x gamma in {0.5, 1},
#: with and without the scaling, picks (8, 1) with it in 39 of 41 folds (held-out mean 57.3;
#: unscaled, the best procedure scores 56.6 and its choice sits at the grid's edge):
#: docs/energy_weights.md. Until 2026-12-04 the default was beta 3, gamma 0.5, unscaled.
DEFAULT_AFF_NORM: AffNorm = "verb-best"
#: How much of a glossed name's text embedding is its gloss's in p(o | r) (``grounding/senses.py``):
#: an even mix, the first of the two weights tried on the testbed's renders (0.25, 0.5) and the
#: better of them; 0 reads names alone, as every result stored before 2026-12-06's change.
DEFAULT_SENSE_WEIGHT = 0.5
DEFAULT_ALPHA = 1.0
DEFAULT_BETA = 8.0
DEFAULT_GAMMA = 1.0

_CHOICES: dict[str, tuple[str, ...]] = {"aff_mode": AFF_MODES, "energy_form": ENERGY_FORMS, "aff_norm": AFF_NORMS}


class GroundingSettings(BaseModel):
    """How ``ground(verb, rois)`` scores ROIs (paper eq. 1): ``alpha * E_grasp + beta * E_aff +
    gamma * E_align``, with ``p(o | r)`` at ``temperature`` over ``vocabulary`` (``None``: the
    KB's objects) and E_aff in ``energy_form`` (``None``: the form the bundle was built with),
    read as an expectation over hypotheses or at the arg-max (``aff_mode``)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    # weights of a sum of energies: finite and not negative (a negative weight rewards the energy
    # it should penalise; NaN would rank every ROI as NaN)
    alpha: float = Field(DEFAULT_ALPHA, ge=0.0, allow_inf_nan=False)
    beta: float = Field(DEFAULT_BETA, ge=0.0, allow_inf_nan=False)
    gamma: float = Field(DEFAULT_GAMMA, ge=0.0, allow_inf_nan=False)
    temperature: float = Field(DEFAULT_TEMPERATURE, gt=0)
    aff_mode: AffMode = "expected"
    #: ``verb-best``: scale each verb's E_aff so its best object in the bundle is -1 (see ``AffNorm``).
    #: The normalized product rewards the share of a verb's property weight an object covers, and
    #: a verb whose properties are alternatives ("a toy" or "game equipment" or "an instrument",
    #: for *play*) is never covered by one object: its best object sits near -0.6 where a verb
    #: with one defining property reaches -0.98. Unscaled, the grasp and alignment terms outvote
    #: the knowledge of the first kind of verb twice as easily (``docs/energy_weights.md``).
    aff_norm: AffNorm = DEFAULT_AFF_NORM
    energy_form: EnergyForm | None = None
    open_vocab: bool = False
    vocabulary: tuple[str, ...] | None = None
    #: p(o | r) also weighs each ROI's extents, measured from depth, against the objects' typical
    #: sizes (``grounding/size_cue.py``). ``None`` (default): wherever it can — the bundle has a
    #: size for every vocabulary object, and only ROIs that carry extents are affected; ``True``:
    #: required (a bundle without the sizes is an error); ``False``: off.
    size_cue: bool | None = None
    #: p(o | r) also weighs each ROI's colour shares against the objects' typical colours
    #: (``grounding/colour_cue.py``). Opt-in: ``True`` turns it on (a bundle without the colours
    #: is an error); ``None`` (default) and ``False``: off. It raises recognition of isolated
    #: renders but lowered CRAFT-E's Detect on the dev episodes (the testbed's drill, spoon and
    #: plate are not the colours a typical one is), so it is not the default
    #: (``docs/recognition.md``).
    colour_cue: bool | None = None
    #: p(o | r) also weighs each ROI's top ImageNet classes against the classes each object's
    #: photos get (the bundle's ``object_lookalikes.json``; ``grounding/lookalike_cue.py``).
    #: Opt-in: ``True`` turns it on (a bundle without look-alikes for every vocabulary name is an
    #: error); ``None``/``False``: off. It names rendered objects better but did not make CRAFT-E
    #: choose better on the dev scenes (``docs/recognition.md``).
    lookalikes: bool | None = None
    #: p(o | r) also weighs each ROI's open cavity, measured from depth, against the knowledge
    #: base's "is concave" weights (``grounding/cavity_cue.py``). ``None`` (default) and ``True``:
    #: on for every bundle whose graph defines that property and holds every vocabulary name (the
    #: others, direct-LLM's and ConceptNet's, ground without it), and only ROIs that carry a
    #: measured cavity are affected; ``False``: off (results stored before 2026-12-05's cue).
    cavity_cue: bool | None = None
    #: p(o | r) reads each cosine less half the name's hubness, its mean cosine to its 10 nearest
    #: labels of the image encoder (CSLS; ``grounding/hubness.py``). ``None`` (default): on for
    #: every bundle in ConSE's text space (the labels are its ImageNet class names); ``True``:
    #: required (a bundle in another space is an error); ``False``: off (results stored before
    #: 2026-12-06's correction).
    hubness: bool | None = None
    #: p(o | r) reads each vocabulary name with the gloss it was asked in: its text embedding is the
    #: unit mean of the name's and the gloss's, the gloss weighing ``sense_weight``
    #: (``grounding/senses.py``). Glosses come from the bundle's graph, or from the caller
    #: (``Grounder(senses=...)``: the evaluations give every method the vocabulary's own, so that
    #: perception is the same for all); names without one are read alone. 0: names alone.
    sense_weight: float = Field(DEFAULT_SENSE_WEIGHT, ge=0.0, le=1.0, allow_inf_nan=False)
    #: How the image encoder's ImageNet class names are read: the same unit mean with each class's
    #: WordNet gloss (``encoders/conse.py``), which the hubness correction's reference follows and
    #: the evaluations build their ConSE encoder with. ``None`` (default): ``sense_weight``, so one
    #: weight reads the names on both sides of ConSE's cosine; a number: that weight for the class
    #: names alone (0: the bare class names, as every result stored before 2026-12-06, session 33).
    class_sense_weight: float | None = Field(None, ge=0.0, le=1.0, allow_inf_nan=False)
    #: The softmax temperature of the image classifier's probabilities that weigh ConSE's mean of
    #: class names (``encoders/conse.py``), which the evaluations, ``craft sim demo`` and ``craft
    #: serve`` build their encoder with. 1: ConSE's own weights (every result stored before
    #: 2026-12-06, session 34). It shapes the image embedding, not the grounder.
    conse_temperature: float = Field(DEFAULT_CONSE_TEMPERATURE, gt=0.0, allow_inf_nan=False)

    @property
    def class_senses(self) -> float:
        """The weight the class names are read with (``class_sense_weight``, else ``sense_weight``)."""
        return self.sense_weight if self.class_sense_weight is None else self.class_sense_weight

    @field_validator("temperature", mode="before")
    @classmethod
    def _default_temperature(cls, value: Any) -> Any:
        """``None`` (an option left unset) means the default temperature."""
        return DEFAULT_TEMPERATURE if value is None else value

    @field_validator("sense_weight", mode="before")
    @classmethod
    def _default_sense_weight(cls, value: Any) -> Any:
        """``None`` (an option left unset) means the default weight."""
        return DEFAULT_SENSE_WEIGHT if value is None else value

    @field_validator("conse_temperature", mode="before")
    @classmethod
    def _default_conse_temperature(cls, value: Any) -> Any:
        """``None`` (an option left unset) means the default temperature."""
        return DEFAULT_CONSE_TEMPERATURE if value is None else value

    @field_validator("aff_norm", mode="before")
    @classmethod
    def _default_aff_norm(cls, value: Any) -> Any:
        """``None`` (an option left unset) means the default scaling."""
        return DEFAULT_AFF_NORM if value is None else value

    @classmethod
    def of(cls, **options: Any) -> GroundingSettings:
        """Validated settings, or a ``ValueError`` that names the option as a user spells it
        (``--aff-mode 'x': use one of expected, argmax``)."""
        try:
            return cls(**options)
        except ValidationError as exc:
            first = exc.errors()[0]
            name = str(first["loc"][0]) if first["loc"] else "settings"
            value = options.get(name)
            flag = "--" + name.replace("_", "-")
            if name in _CHOICES:
                raise ValueError(f"{flag} {value!r}: use one of {', '.join(_CHOICES[name])}") from None
            raise ValueError(f"{flag} {value!r}: {first['msg']}") from None

    def with_form(self, default_form: EnergyForm) -> GroundingSettings:
        """These settings with ``energy_form`` filled in (a bundle's own form when unset)."""
        return self if self.energy_form is not None else self.model_copy(update={"energy_form": default_form})

    @property
    def form(self) -> EnergyForm:
        """The E_aff form of resolved settings (``with_form`` was applied)."""
        if self.energy_form is None:
            raise ValueError("settings not resolved against a bundle: energy_form is unset")
        return self.energy_form

    def energy_dict(self) -> dict[str, Any]:
        """The energy part as results store it (``"settings"`` of a grounding)."""
        out: dict[str, Any] = {"alpha": self.alpha, "beta": self.beta, "gamma": self.gamma,
                               "temperature": self.temperature, "aff_mode": self.aff_mode,
                               "energy_form": self.energy_form}
        if self.aff_norm != "none":  # only when on: results stored before the option read the same
            out["aff_norm"] = self.aff_norm
        if self.size_cue is not None:  # only when set: results stored before the option read the same
            out["size_cue"] = self.size_cue
        if self.colour_cue is not None:
            out["colour_cue"] = self.colour_cue
        if self.lookalikes is not None:
            out["lookalikes"] = self.lookalikes
        if self.cavity_cue is not None:
            out["cavity_cue"] = self.cavity_cue
        if self.hubness is not None:
            out["hubness"] = self.hubness
        if self.sense_weight > 0:  # only when on: results stored before the names' senses read the same
            out["sense_weight"] = self.sense_weight
        if self.class_senses > 0:  # likewise for the class names' (2026-12-06, session 33)
            out["class_sense_weight"] = self.class_senses
        if self.conse_temperature != 1.0:  # likewise for ConSE's temperature (session 34)
            out["conse_temperature"] = self.conse_temperature
        return out
