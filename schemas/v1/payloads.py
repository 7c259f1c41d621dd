"""Structured answers the LLM prompts ask for (the ``response_schema`` of every prompt).

An answer that does not validate is retried and then reported; it is never coerced. Weights are
probabilities of relevance in [0, 1] as in the paper (w_vp, w_po).
"""

from __future__ import annotations

from itertools import pairwise
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

Weight = Annotated[float, Field(ge=0.0, le=1.0)]
Phrase = Annotated[str, Field(min_length=1, max_length=64)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ScoredProperty(_Strict):
    """One property of a verb (stage 1): how important it is for doing the verb (w_vp)."""

    name: Phrase
    weight: Weight


class VerbProperties(_Strict):
    """Stage 1 answer: the k descriptive properties of objects that afford ``verb``."""

    verb: Phrase
    properties: list[ScoredProperty] = Field(min_length=1, max_length=20)

    @field_validator("properties")
    @classmethod
    def _unique(cls, value: list[ScoredProperty]) -> list[ScoredProperty]:
        names = [p.name.strip().lower() for p in value]
        if len(set(names)) != len(names):
            raise ValueError("property names must be unique")
        return value


Role = Literal["required", "helpful"]


class DefinedProperty(_Strict):
    """One stage-1 (v2) property: its sense fixed by a definition, and how the verb needs it.

    ``required``: the action fails without it (a missing required property can veto an object);
    ``helpful``: it makes an object better suited but is not needed.
    """

    name: Annotated[str, Field(min_length=1, max_length=48)]
    definition: Annotated[str, Field(min_length=3, max_length=200)]
    role: Role
    weight: Weight


class VerbPropertiesV2(_Strict):
    """Stage 1 answer (prompt v2): 3..k discriminating, defined properties for ``verb``."""

    verb: Phrase
    properties: list[DefinedProperty] = Field(min_length=1, max_length=20)

    @field_validator("properties")
    @classmethod
    def _unique(cls, value: list[DefinedProperty]) -> list[DefinedProperty]:
        names = [p.name.strip().lower() for p in value]
        if len(set(names)) != len(names):
            raise ValueError("property names must be unique")
        return value


class PropertyScore(_Strict):
    """One property an object has (stage 2): how well the object satisfies it (w_po)."""

    property: Phrase
    weight: Weight


class ObjectProperties(_Strict):
    """Stage 2 answer: the properties (from the prompt's named set) that ``object`` has.

    Sparse on purpose: properties the object lacks are left out rather than scored 0.
    """

    object: Phrase
    scores: list[PropertyScore] = Field(max_length=400)

    @field_validator("scores")
    @classmethod
    def _unique(cls, value: list[PropertyScore]) -> list[PropertyScore]:
        names = [s.property.strip().lower() for s in value]
        if len(set(names)) != len(names):
            raise ValueError("each property may be scored once")
        return value


class ObjectScore(_Strict):
    """One object that has a property (stage 2b): how well it satisfies the definition (w_po)."""

    object: Phrase
    weight: Weight


class PropertyObjects(_Strict):
    """Stage 2b answer: the objects (from the prompt's named set) that have ``property``.

    The per-property pass judges every object against one definition, so weights are
    comparable across objects; sparse on purpose, like the per-object answer.
    """

    property: Annotated[str, Field(min_length=1, max_length=48)]
    scores: list[ObjectScore] = Field(max_length=2000)

    @field_validator("scores")
    @classmethod
    def _unique(cls, value: list[ObjectScore]) -> list[ObjectScore]:
        names = [s.object.strip().lower() for s in value]
        if len(set(names)) != len(names):
            raise ValueError("each object may be scored once")
        return value


class RankedObject(_Strict):
    """One object of the direct-LLM baseline answer, with the model's confidence."""

    object: Phrase
    score: Weight


class VerbObjects(_Strict):
    """Direct-LLM baseline: objects of the vocabulary one can ``verb`` with, best first."""

    verb: Phrase
    ranking: list[RankedObject] = Field(max_length=500)

    @field_validator("ranking")
    @classmethod
    def _unique(cls, value: list[RankedObject]) -> list[RankedObject]:
        names = [r.object.strip().lower() for r in value]
        if len(set(names)) != len(names):
            raise ValueError("each object may appear once in the ranking")
        return value


Centimetres = Annotated[float, Field(gt=0.0, le=10_000.0)]
Variability = Literal["low", "medium", "high"]


class ObjectSize(_Strict):
    """Perception knowledge: the physical size of a typical ``object`` (prompt ``object_size``).

    ``dimensions_cm``: the three edges of the smallest box that holds a typical instance, longest
    first. A depth camera measures an ROI's extents, so a size says which names an ROI can be
    (an apple is not 30 cm long) without any picture of the object. ``variability`` says how far
    instances stray from it (a marker: low; a toy: high), and sets how much a mismatch counts.
    """

    object: Phrase
    dimensions_cm: list[Centimetres] = Field(min_length=3, max_length=3)
    variability: Variability
    note: Annotated[str, Field(max_length=200)] = ""

    @field_validator("dimensions_cm")
    @classmethod
    def _longest_first(cls, value: list[float]) -> list[float]:
        if any(a < b for a, b in pairwise(value)):
            raise ValueError(f"dimensions_cm must be longest first, got {value}")
        return value


def _distinct_shares(what: str, names: list[str], shares: list[float]) -> None:
    """Shares of a whole (a surface, photos): each ``what`` named once, adding up to 1 or less."""
    if len(set(names)) != len(names):
        raise ValueError(f"each {what} may appear once, got {names}")
    total = sum(shares)
    if total > 1.0 + 1e-6:
        raise ValueError(f"the shares add up to {total:g}; they must add up to 1 or less")


#: The eleven basic colour terms (Berlin & Kay): the only words ``object_colour`` answers use, so
#: the runtime can sort an ROI's pixels into the same bins (``perception/colours.py``).
ColourTerm = Literal["black", "white", "grey", "red", "orange", "yellow", "green", "blue", "purple",
                     "pink", "brown"]


class ColourShare(_Strict):
    """One colour of an object's visible surface and the share of it that colour covers."""

    colour: ColourTerm
    share: Annotated[float, Field(gt=0.0, le=1.0)]


class ObjectColour(_Strict):
    """Perception knowledge: the colours a typical ``object`` shows from above (prompt ``object_colour``).

    A colour camera sees what the ImageNet label space may not name: a rendered orange that the
    image encoder calls a "bowl" is still orange. ``colours``: one to three basic terms with the
    share of the visible surface each covers (they add up to 1 or less; the rest is detail).
    ``variability`` says how much instances stray from them (a banana: low; a mug: high) and sets
    how much a mismatch counts.
    """

    object: Phrase
    colours: list[ColourShare] = Field(min_length=1, max_length=3)
    variability: Variability
    note: Annotated[str, Field(max_length=200)] = ""

    @field_validator("colours")
    @classmethod
    def _distinct_and_at_most_whole(cls, value: list[ColourShare]) -> list[ColourShare]:
        _distinct_shares("colour", [c.colour for c in value], [c.share for c in value])
        return value


class ClassShare(_Strict):
    """One ImageNet-1k class an image classifier gives photos of an object, and its expected share."""

    imagenet_class: Annotated[str, Field(min_length=1, max_length=80)]
    share: Annotated[float, Field(gt=0.0, le=1.0)]


class ObjectLookalikes(_Strict):
    """Perception knowledge: the ImageNet-1k classes photos of a typical ``object`` get (prompt
    ``object_lookalike``).

    The robot's image recogniser only knows the ImageNet-1k label space, and where that space has
    no class for an object it answers with a class of something that looks alike (a stapler may
    come back as a "computer mouse"). ConSE maps the answer to the nearest vocabulary name by
    *text* similarity, which lands on the wrong name whenever the look-alike's name means
    something else. ``classes``: one to five class names, written exactly as in the classifier's
    list (``craftc curate record`` checks them), each with the share of photos expected to get it
    (they add up to 1 or less).
    """

    object: Phrase
    classes: list[ClassShare] = Field(min_length=1, max_length=5)
    note: Annotated[str, Field(max_length=240)] = ""

    @field_validator("classes")
    @classmethod
    def _distinct_and_at_most_whole(cls, value: list[ClassShare]) -> list[ClassShare]:
        _distinct_shares("class", [c.imagenet_class for c in value], [c.share for c in value])
        return value
