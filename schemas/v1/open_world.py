"""``open_world.json`` of a bundle: the fitted model for objects and requests the KB has never seen.

The compiler writes it (``runtime/grounding/open_world.fit_open_world``); the grounder reads the
object model (``ObjectModel.from_params``) and the request parameters (``map_request``). Without a
model of its shape, a document such as ``{"objects": 3}`` hashed, verified, was signed by
``craftc pack`` and installed by ``craft install``, and failed only when a robot first met an
unseen object. Verification now validates it against :class:`OpenWorld` (``runtime/kb/content.py``).

Every number the runtime computes with is a finite JSON number of the right kind (``strict``: a
``"5"`` or ``true`` is refused, never coerced); ``nearest_cosine`` is the x axis of ``np.interp``,
which gives nonsense without an error when it decreases, so it must not.
"""

from __future__ import annotations

from itertools import pairwise
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

OPEN_WORLD_SCHEMA_ID = "https://craft-e.dev/schemas/v1/open_world.json"

#: A finite JSON number (an integer is one too).
Finite = Annotated[float, Field(allow_inf_nan=False)]
#: A share or probability-like threshold.
Unit = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class OpenWorldGridPoint(_Strict):
    """One (k, temperature) of the cross-validated search, with its quality."""

    k: int = Field(ge=1)
    temperature: Finite = Field(gt=0.0)
    cv_quality: Finite


class OpenWorldConfidence(_Strict):
    """Nearest-neighbour cosine -> expected quality of an inferred property vector."""

    meaning: str = ""
    nearest_cosine: list[Finite] = Field(description="x of the curve, never decreasing")
    quality: list[Finite] = Field(description="y of the curve, one per nearest_cosine")
    prior_quality: Finite | None = None

    @model_validator(mode="after")
    def _curve(self) -> OpenWorldConfidence:
        if len(self.nearest_cosine) != len(self.quality):
            raise ValueError(f"nearest_cosine has {len(self.nearest_cosine)} points and quality "
                             f"{len(self.quality)}; the curve needs one quality per cosine")
        x = self.nearest_cosine
        if any(b < a for a, b in pairwise(x)):
            raise ValueError("nearest_cosine decreases; the curve's x must never decrease")
        return self


class OpenWorldObjects(_Strict):
    """The unseen-object model (k-nearest KB objects, kernel temperature, confidence curve)."""

    method: Literal["knn"] = "knn"
    k: int = Field(ge=1)
    temperature: Finite = Field(gt=0.0)
    tau: Unit | None = None
    cv_folds: int | None = Field(None, ge=1)
    cv_seed: int | None = None
    cv_quality: Finite | None = None
    grid: list[OpenWorldGridPoint] = Field(default_factory=list)
    confidence: OpenWorldConfidence
    min_confidence: Unit


class OpenWorldRequests(_Strict):
    """How a request outside the verb list is mapped to properties (defaults: the runtime's)."""

    verbs: int = Field(3, ge=1)
    properties: int = Field(5, ge=1)
    temperature: Finite = Field(0.05, gt=0.0)
    verb_share: Unit = 0.5
    min_confidence: Unit = 0.5


class OpenWorld(_Strict):
    """The whole ``open_world.json``."""

    model_config = ConfigDict(json_schema_extra={"$id": OPEN_WORLD_SCHEMA_ID})

    schema_: Literal["craft-e/open-world@1"] = Field(alias="schema")
    objects: OpenWorldObjects
    requests: OpenWorldRequests | None = None
