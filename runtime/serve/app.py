"""``craft serve``: the grounder behind a small HTTP API, for robot stacks that are not Python.

One process, one verified bundle, one ``Grounder`` per energy form, all built before the port is
bound: a bundle that fails verification never answers a request, and no request pays for
loading. Endpoints:

* ``POST /ground`` — ``{verb, rois: [{box_xywh, grasp_scores, image_embedding | null, label?}],
  options?}`` -> the ``Grounding`` as JSON (ranked ROIs with their three energies, the chosen
  grasp, explanation paths with record ids, excluded ROIs with reasons);
* ``POST /ground_image`` — the same with a base64 PNG/JPEG and boxes: crops are embedded here
  with the image encoder (ConSE by default), for clients without one;
* ``POST /perceive`` — one RGB-D frame (base64 PNG/JPEG colour, ``.npy`` or 16-bit PNG depth, the
  camera's pinhole model): perceived as the testbed's robot perceives (``runtime/frame.py``:
  regions, grasps, the size and cavity cues) and grounded, with the chosen grasp in metres;
* ``GET /healthz`` — KB name, version, content hash, dimensions (a load balancer's probe);
* ``GET /verbs`` — the verbs the KB knows.

Input is validated before it reaches the grounder, and every rejection says why (4xx, never 500):
schema errors are FastAPI's 422 with pydantic's ``detail``; a wrong embedding length is 422 naming
the bundle's dimension; an unknown verb is 404 with close matches (the request is well formed,
the KB lacks the verb: the fix is a KB rebuild or ``--open-vocab``, not a client change); more
ROIs than ``max_rois`` is 422 naming the bound; a body over ``max_body_bytes`` is 413 before it
is parsed. Non-finite numbers are rejected (Python's JSON parser accepts ``NaN``), since one NaN
would silently poison the ranking.

Numbers must also fit what they become: embedding components and box coordinates beyond
``MAX_ABS_VALUE`` (e.g. 1e39, which float32 turns into inf) are a 422, never a 500. The image
endpoint bounds its work before decoding: at most ``max_image_boxes`` boxes (422), images of at
most ``max_image_pixels`` pixels (413, read from the header before any pixel is decoded), and
at most ``max_concurrent_images`` decodes at once (503 with ``Retry-After`` at once, instead of
queueing gigabytes). An ROI whose grasp scores are all 0.0 cannot be picked up: it is excluded
with that reason, never chosen. ``/docs`` is a self-contained page (no CDN scripts: the robot has
no network); ``/openapi.json`` is the machine-readable schema.

Per-request weights (``alpha``, ``beta``, ``gamma``) do not rebuild anything: they only scale
the three energies, so a shallow copy of the prebuilt grounder with other weights shares every
precomputed matrix (see ``GroundingService.grounder``).
"""

from __future__ import annotations

import html
import io
import json
import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, TypeVar

import numpy as np
import numpy.typing as npt
from fastapi import FastAPI, HTTPException, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from ..encoders.base import ImageEncoder
from ..grounding.energies import ENERGY_FORMS, EnergyForm
from ..grounding.grounder import (
    Grounder,
    Grounding,
    UnknownVerbError,
)
from ..grounding.settings import GroundingSettings
from ..kb.bundle import Bundle, load_bundle
from ..kb.colours import COLOUR_TERMS
from ..perception.roi import ROI, BoxSpec, RoiError, boxes_past_the_image, build_rois
from .frames import CameraIn, WorkspaceIn, decode_base64

if TYPE_CHECKING:
    from ..encoders.image import ImageEncoder as RobotEncoder
    from ..frame import FrameGrounding, PerceivedFrame
    from ..sim.clearance import HandBox
    from ..sim.pipeline import PipelineConfig

#: Candidate regions per request. A tabletop scene has a handful; the bound keeps one request's
#: cost (and a hostile client's) small, and is reported in the 422 when exceeded.
DEFAULT_MAX_ROIS = 64
#: Grasp candidates per ROI (grasp networks keep tens of peaks; thousands means a bug upstream).
MAX_GRASPS_PER_ROI = 1024
MAX_EXTENT_M = 10.0  # m: a region's edge; larger is not an object a hand picks up
#: Request bodies larger than this are refused with 413 before parsing. 64 ROIs x 384 floats as
#: JSON is ~0.5 MB; the image endpoint needs room for a base64 photo.
DEFAULT_MAX_BODY_BYTES = 2 * 1024 * 1024
DEFAULT_MAX_IMAGE_BODY_BYTES = 24 * 1024 * 1024
#: Decoded image size bound (pixels): a PNG of a few KB can claim gigapixels (decompression bomb).
#: 16.7 MP (4096 x 4096) is more than any robot camera sends; one decode is then <= 50 MB RGB.
MAX_IMAGE_PIXELS = 4096 * 4096
#: Boxes per /ground_image request: each crop costs an encoder forward pass (tens of ms).
DEFAULT_MAX_IMAGE_BOXES = 16
#: Image decodes running at once; more get 503 + Retry-After instead of piling up in memory.
DEFAULT_MAX_CONCURRENT_IMAGES = 2
#: Largest magnitude of an embedding component or a box coordinate. float32 overflows to inf
#: above 3.4e38; embeddings are unit-scale and boxes are pixels, so 1e6 is generous for both.
MAX_ABS_VALUE = 1e6
IMAGE_FORMATS = ("PNG", "JPEG")
MAX_VERB_CHARS = 100
MAX_LABEL_CHARS = 200
#: Scene vocabulary entries per request, and grounders kept for recent vocabularies.
MAX_OBJECTS = 512
VOCABULARY_CACHE = 16

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


class GroundOptions(BaseModel):
    """Per-request settings; anything left out uses the server's (by default alpha = 1, beta = 8,
    gamma = 1 with each verb's E_aff scaled by its best object, ``grounding/settings.py``, and the
    bundle's energy form). The scaling is the server's, not a per-request option."""

    model_config = _STRICT

    alpha: Annotated[float, Field(ge=0.0, le=1e3, description="Weight of E_grasp.")] | None = None
    beta: Annotated[float, Field(ge=0.0, le=1e3, description="Weight of E_aff.")] | None = None
    gamma: Annotated[float, Field(ge=0.0, le=1e3, description="Weight of E_align.")] | None = None
    energy_form: EnergyForm | None = Field(
        None, description="sum-tanh | normalized-product (default: the bundle's)."
    )
    top_k: Annotated[int, Field(ge=1, description="Return only the k best ranked ROIs.")] | None = None
    colour_cue: bool | None = Field(None, description=(
        "Weigh p(o | r) by each ROI's `colours` against the objects' typical colours (opt-in; needs "
        "`objects` whose every name has typical colours in the bundle)."))
    lookalikes: bool | None = Field(None, description=(
        "Weigh p(o | r) by each ROI's `imagenet_classes` against the ImageNet classes each object's photos "
        "get (the look-alike cue; opt-in; needs `objects` whose every name has look-alike classes in the "
        "bundle). /ground_image measures the classes itself."))


Box = tuple[float, float, float, float]


def _check_box(box: Box) -> Box:
    if any(abs(v) > MAX_ABS_VALUE for v in box):
        raise ValueError(f"box_xywh: coordinates must lie within +-{MAX_ABS_VALUE:g} pixels")
    if box[2] <= 0 or box[3] <= 0:
        raise ValueError(f"box_xywh {list(box)}: width and height must be > 0 (pixels)")
    return box


def _check_embedding(values: list[float] | None) -> list[float] | None:
    if values is not None and any(abs(v) > MAX_ABS_VALUE for v in values):
        raise ValueError(
            f"image_embedding: components must lie within +-{MAX_ABS_VALUE:g} (float32 "
            "overflows above 3.4e38; embeddings are unit-scale)"
        )
    return values


def _check_verb(verb: str) -> str:
    if not verb.strip():
        raise ValueError("verb is blank; name the action, e.g. cut")
    return verb


def _check_scores(scores: list[float]) -> list[float]:
    bad = [s for s in scores if not 0.0 <= s <= 1.0]
    if bad:
        raise ValueError(
            f"grasp scores must lie in [0, 1] (qualities, not logits); got {bad[0]!r}"
        )
    return scores


def _check_extents(values: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
    if values is None:
        return None
    if not all(math.isfinite(v) and 0.0 < v <= MAX_EXTENT_M for v in values):
        raise ValueError(f"extents_m {list(values)}: three edges in metres, each > 0 and at most "
                         f"{MAX_EXTENT_M:g}")
    a, b, c = sorted(values, reverse=True)
    return a, b, c


def _check_classes(values: dict[str, float] | None) -> dict[str, float] | None:
    """An ROI's ImageNet classes: names the classifier can output, probabilities in [0, 1]."""
    if values is None:
        return None
    from ..encoders.conse import CLASS_TOP_K, imagenet_class_index

    unknown = sorted(set(values) - imagenet_class_index().keys())
    if unknown:
        raise ValueError(f"imagenet_classes {unknown[:3]}: not ImageNet-1k class names of the image encoder")
    if not 1 <= len(values) <= CLASS_TOP_K:
        raise ValueError(f"imagenet_classes: one to {CLASS_TOP_K} classes, got {len(values)}")
    if not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in values.values()) or sum(values.values()) > 1 + 1e-6:
        raise ValueError(f"imagenet_classes {values}: each probability in [0, 1], adding up to 1 or less")
    return values


def _class_top(values: dict[str, float] | None) -> tuple[tuple[int, float], ...] | None:
    """A request's classes as the runtime carries them: (class index, probability), most probable first."""
    if values is None:
        return None
    from ..encoders.conse import imagenet_class_index

    index = imagenet_class_index()
    return tuple(sorted(((index[n], float(p)) for n, p in values.items()), key=lambda cp: (-cp[1], cp[0])))


def _check_cavity(value: float | None) -> float | None:
    if value is None:
        return None
    if not (math.isfinite(value) and abs(value) <= MAX_EXTENT_M):
        raise ValueError(f"cavity_m {value!r}: metres from the rim down to the inside (negative for a dome), "
                         f"at most {MAX_EXTENT_M:g} either way")
    return value


def _check_colours(values: dict[str, float] | None) -> dict[str, float] | None:
    if values is None:
        return None
    unknown = sorted(set(values) - set(COLOUR_TERMS))
    if unknown or not values:
        raise ValueError(f"colours {sorted(values)}: shares by basic colour term, one or more of "
                         f"{', '.join(COLOUR_TERMS)}")
    if not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in values.values()) or not 0.99 <= sum(values.values()) <= 1.01:
        raise ValueError(f"colours {values}: each share in [0, 1], adding up to 1 (the region's pixels)")
    return values


def _colour_shares(values: dict[str, float] | None) -> tuple[float, ...] | None:
    """A request's colour shares in the runtime's term order (``kb.colours.COLOUR_TERMS``)."""
    return None if values is None else tuple(float(values.get(t, 0.0)) for t in COLOUR_TERMS)


class RoiIn(BaseModel):
    """One candidate region as a client sends it."""

    model_config = _STRICT

    box_xywh: Box = Field(description="x, y, width, height in pixels.")
    grasp_scores: list[float] = Field(
        default_factory=list, max_length=MAX_GRASPS_PER_ROI,
        description="Qualities in [0, 1] of the grasp candidates; empty: the ROI is excluded.",
    )
    image_embedding: list[float] | None = Field(
        None, description="phi_I(r) in the bundle's text space (GET /healthz: dim); null: excluded."
    )
    label: str | None = Field(None, max_length=MAX_LABEL_CHARS, description="Echoed back.")
    extents_m: tuple[float, float, float] | None = Field(None, description=(
        "The region's box edges in metres, measured from depth (any order). With a scene vocabulary "
        "(`objects`) whose every name has a typical size in the bundle, p(o | r) also weighs how "
        "well they fit (the size cue); null: not measured."))
    colours: dict[str, float] | None = Field(None, description=(
        "The share of the region's pixels in each basic colour term (black, white, grey, red, orange, "
        "yellow, green, blue, purple, pink, brown; they add up to 1). With a scene vocabulary whose every "
        "name has typical colours in the bundle, p(o | r) also weighs how well they fit (the colour cue); "
        "null: not measured."))
    cavity_m: float | None = Field(None, description=(
        "How far the region's inside lies below its rim, metres, from depth (`perception/cavity.py`; negative "
        "for a dome). With a bundle whose graph defines 'is concave' for every name of `objects`, p(o | r) also "
        "weighs it against those weights (the cavity cue, on by default); null: not measured."))
    imagenet_classes: dict[str, float] | None = Field(None, description=(
        "The image classifier's most probable ImageNet-1k classes on the region's crop (class name -> "
        "probability, at most 10). With `options.lookalikes`, p(o | r) also weighs how well they fit the "
        "classes each object's photos get (the look-alike cue); null: not measured."))

    _box = field_validator("box_xywh")(_check_box)
    _scores = field_validator("grasp_scores")(_check_scores)
    _embedding = field_validator("image_embedding")(_check_embedding)
    _extents = field_validator("extents_m")(_check_extents)
    _colours = field_validator("colours")(_check_colours)
    _cavity = field_validator("cavity_m")(_check_cavity)
    _classes = field_validator("imagenet_classes")(_check_classes)


class GroundRequest(BaseModel):
    model_config = _STRICT

    verb: str = Field(min_length=1, max_length=MAX_VERB_CHARS, description=(
        "The action, e.g. cut; with --open-vocab also a verb the KB lacks or a free request "
        "(\"dig a hole\"), mapped to properties or abstained on."))
    rois: list[RoiIn] = Field(min_length=1)
    objects: list[Annotated[str, Field(min_length=1, max_length=MAX_LABEL_CHARS)]] | None = Field(
        None, max_length=MAX_OBJECTS, description=(
            "The scene's object vocabulary for p(o | r) (default: the KB's objects). Names the KB "
            "lacks are inferred from similar KB objects, or flagged as unknown (E_aff = 0)."))
    options: GroundOptions | None = None

    _verb = field_validator("verb")(_check_verb)


class BoxIn(BaseModel):
    """A region of the posted image; its crop is embedded by the server."""

    model_config = _STRICT

    box_xywh: Box
    grasp_scores: list[float] = Field(default_factory=list, max_length=MAX_GRASPS_PER_ROI)
    label: str | None = Field(None, max_length=MAX_LABEL_CHARS)

    _box = field_validator("box_xywh")(_check_box)
    _scores = field_validator("grasp_scores")(_check_scores)


class GroundImageRequest(BaseModel):
    model_config = _STRICT

    verb: str = Field(min_length=1, max_length=MAX_VERB_CHARS)
    image_b64: str = Field(min_length=1, description="Base64 of a PNG or JPEG file (RGB).")
    boxes: list[BoxIn] = Field(min_length=1)
    options: GroundOptions | None = None

    _verb = field_validator("verb")(_check_verb)


class PerceiveRequest(BaseModel):
    model_config = _STRICT

    verb: str = Field(min_length=1, max_length=MAX_VERB_CHARS)
    rgb_b64: str = Field(min_length=1, description="Base64 of a PNG or JPEG file (RGB), registered to the depth.")
    depth_b64: str = Field(min_length=1, description=(
        "Base64 of a .npy file (H x W, metres; 0 = no reading) or of a 16-bit PNG (with depth_scale)."))
    depth_scale: Annotated[float, Field(gt=0.0, le=10.0, strict=True, description=(
        "Metres per depth unit: 0.001 for a RealSense's raw millimetres; left out, float depth is metres "
        "and integer depth is refused."))] | None = None
    camera: CameraIn
    objects: list[Annotated[str, Field(min_length=1, max_length=MAX_LABEL_CHARS)]] | None = Field(
        None, max_length=MAX_OBJECTS, description=(
            "The objects the robot may meet, for p(o | r) (default: the KB's). The size cue needs a "
            "typical size in the bundle for every one (the testbed's 62 names have one)."))
    workspace: WorkspaceIn | None = Field(None, description=(
        "Perceive only what stands inside this x-y box of the table (metres, in camera.cam_to_world's "
        "frame, which it needs): the robot's base, the floor and the table's edge are left out."))
    mask_b64: str | None = Field(None, min_length=1, description=(
        "Base64 of a PNG of the frame's size: non-zero pixels are perceived, zero ones ignored (e.g. the "
        "robot's own body)."))
    options: GroundOptions | None = None

    _verb = field_validator("verb")(_check_verb)


#: ``POST /perceive``'s field for each input a ``frame.FrameError`` blames (``FrameError.part``)
FRAME_FIELDS: dict[str, list[str]] = {"rgb": ["rgb_b64"], "depth": ["depth_b64"], "camera": ["camera"],
                                      "cam_to_world": ["camera", "cam_to_world"], "mask": ["mask_b64"],
                                      "workspace": ["workspace"]}


class ServeError(ValueError):
    """The server cannot start with this configuration (bundle, encoder); names the fix."""


def _error(status: int, kind: str, message: str, **extra: Any) -> HTTPException:
    return HTTPException(status, detail={"error": kind, "message": message, **extra})


def _invalid(loc: Sequence[str | int], message: str, kind: str) -> HTTPException:
    """A 422 shaped like FastAPI's own validation errors, so clients parse one format."""
    return HTTPException(422, detail=[{"loc": ["body", *loc], "msg": message, "type": kind}])


@dataclass
class GroundingService:
    """Everything built once at startup: the bundle, a grounder per energy form, the encoder.

    ``ground`` turns validated requests into ``Grounding`` dicts; FastAPI glue lives in
    ``create_app``. Grounding runs on the event loop (one thread), so the grounders' lazy caches
    see no concurrent writers; only image embedding runs in worker threads, under a lock, since
    the encoder's torch thread setting is process-global.
    """

    bundle: Bundle
    grounders: dict[EnergyForm, Grounder]
    default_form: EnergyForm
    image_encoder: ImageEncoder | None
    max_rois: int
    started: float = field(default_factory=time.time)
    max_image_boxes: int = DEFAULT_MAX_IMAGE_BOXES
    max_image_pixels: int = MAX_IMAGE_PIXELS
    max_concurrent_images: int = DEFAULT_MAX_CONCURRENT_IMAGES
    #: ``POST /perceive``: the robot's encoder (whole square crops, ``sim_eval.default_encoder``),
    #: its pipeline settings and the hand's boxes; None: the endpoint answers 503
    frame_encoder: RobotEncoder | None = None
    frame_config: PipelineConfig | None = None
    hand_boxes: tuple[HandBox, ...] = ()
    _encoder_lock: threading.Lock = field(default_factory=threading.Lock)
    _vocab_grounders: dict[tuple[str, tuple[str, ...], bool, bool], Grounder] = field(default_factory=dict, repr=False)
    _image_slots: threading.BoundedSemaphore | None = field(default=None, repr=False)

    def image_slot(self) -> threading.BoundedSemaphore:
        if self._image_slots is None:
            self._image_slots = threading.BoundedSemaphore(self.max_concurrent_images)
        return self._image_slots

    @property
    def dim(self) -> int:
        return self.grounders[self.default_form].dim

    def health(self) -> dict[str, Any]:
        m = self.bundle.manifest
        return {
            "status": "ok", "kb": m.kb_name, "version": m.kb_version,
            "content_sha256": m.content_sha256, "verbs": len(m.verbs), "objects": len(m.objects),
            "dim": self.dim, "text_encoder": m.text_encoder.id, "energy_form": self.default_form,
            "image_encoder": self.image_encoder.id if self.image_encoder is not None else None, "max_rois": self.max_rois,
            "uptime_s": round(time.time() - self.started, 3),
        }

    def vocabulary_grounder(self, base: Grounder, form: EnergyForm, objects: list[str],
                            colour_cue: bool = False, lookalikes: bool = False) -> Grounder:
        """A grounder over a request's scene vocabulary (unknown names inferred), kept for the
        last ``VOCABULARY_CACHE`` vocabularies; shares the server's text encoder."""
        key = (form, tuple(objects), colour_cue, lookalikes)
        found = self._vocab_grounders.pop(key, None)
        if found is None:
            update: dict[str, object] = {"energy_form": form, "vocabulary": tuple(objects)}
            if colour_cue:
                update["colour_cue"] = True
            if lookalikes:
                update["lookalikes"] = True
            try:
                found = Grounder(self.bundle, base.settings.model_copy(update=update),
                                 text_encoder=base._text_encoder)
            except ValueError as exc:
                raise _invalid(["objects"], str(exc), "invalid_vocabulary") from None
            if base._text_encoder is None:
                base._text_encoder = found._text_encoder
        self._vocab_grounders[key] = found  # most recent last
        while len(self._vocab_grounders) > VOCABULARY_CACHE:
            self._vocab_grounders.pop(next(iter(self._vocab_grounders)))
        return found

    def grounder(self, options: GroundOptions | None, objects: list[str] | None = None) -> Grounder:
        """The prebuilt grounder of the requested form, re-weighted if asked.

        ``alpha``/``beta``/``gamma`` are read only when energies are combined, so a shallow copy
        with other weights shares the precomputed affordance matrix, embeddings and caches.
        """
        form = (options.energy_form if options else None) or self.default_form
        base = self.grounders[form]
        colour_cue = bool(options is not None and options.colour_cue)
        if colour_cue and objects is None:
            raise _invalid(["options", "colour_cue"], "the colour cue needs the scene's `objects`, each with "
                           "typical colours in the bundle", "colour_cue_unavailable")
        lookalikes = bool(options is not None and options.lookalikes)
        if lookalikes and objects is None:
            raise _invalid(["options", "lookalikes"], "the look-alike cue needs the scene's `objects`, each "
                           "with look-alike classes in the bundle", "lookalike_cue_unavailable")
        if objects is not None:
            base = self.vocabulary_grounder(base, form, objects, colour_cue, lookalikes)
        if options is None or (options.alpha, options.beta, options.gamma) == (None, None, None):
            return base
        return base.with_weights(
            base.alpha if options.alpha is None else options.alpha,
            base.beta if options.beta is None else options.beta,
            base.gamma if options.gamma is None else options.gamma,
        )

    def check_rois(self, count: int, field_name: str) -> None:
        if count > self.max_rois:
            raise _invalid([field_name], f"{count} regions in one request; this server accepts at "
                           f"most {self.max_rois} (craft serve --max-rois)", "too_many_rois")

    def rois_from_request(self, req: GroundRequest) -> list[ROI]:
        self.check_rois(len(req.rois), "rois")
        rois: list[ROI] = []
        for i, r in enumerate(req.rois):
            emb = None
            if r.image_embedding is not None:
                emb = np.asarray(r.image_embedding, dtype=np.float32)  # [d]
                if emb.shape[0] != self.dim:
                    raise _invalid(["rois", i, "image_embedding"],
                                   f"expected {self.dim} floats (the bundle's text space, "
                                   f"{self.bundle.manifest.text_encoder.id}), got {emb.shape[0]}",
                                   "embedding_dimension")
                if not np.any(emb):
                    raise _invalid(["rois", i, "image_embedding"],
                                   "the embedding is all zeros: no direction, no object hypothesis",
                                   "embedding_zero")
            rois.append(ROI(box_xywh=r.box_xywh, grasp_scores=list(r.grasp_scores),
                            image_embedding=emb, label=r.label, extents_m=r.extents_m,
                            colours=_colour_shares(r.colours), classes=_class_top(r.imagenet_classes),
                            cavity_m=r.cavity_m))
        return rois

    def check_image_boxes(self, count: int) -> None:
        self.check_rois(count, "boxes")
        if count > self.max_image_boxes:
            raise _invalid(["boxes"], f"{count} boxes in one image request; this server embeds at "
                           f"most {self.max_image_boxes} crops per request (split the request, or "
                           "embed crops client-side and POST /ground)", "too_many_boxes")

    def rois_from_image(self, req: GroundImageRequest) -> tuple[list[ROI], dict[str, int]]:
        """Decode the image, crop every box, embed the crops in one batch (``build_rois``)."""
        self.check_image_boxes(len(req.boxes))
        if self.image_encoder is None:
            raise _error(503, "image_encoder_disabled",
                         "this server runs without an image encoder (craft serve --image-encoder "
                         "none); embed crops client-side and POST /ground")
        rgb = decode_image(req.image_b64, self.max_image_pixels, colour_only=True)
        specs = [BoxSpec(b.box_xywh, list(b.grasp_scores), b.label) for b in req.boxes]
        try:
            with self._encoder_lock:
                rois = build_rois(rgb, specs, self.image_encoder)
        except RoiError as exc:
            raise _invalid(["boxes", exc.index, "box_xywh"], str(exc), "box_outside_image") from None
        return rois, {"width": int(rgb.shape[1]), "height": int(rgb.shape[0])}

    def perceive_frame(self, req: PerceiveRequest, colours: bool, cavity: bool) -> PerceivedFrame:
        """Decode the frame and perceive it (``frame.perceive``); a 422 naming the field for
        anything that is not a frame, 503 when the server has no robot encoder."""
        from ..frame import FrameError, perceive

        if self.frame_encoder is None or self.frame_config is None:
            raise _error(503, "perception_disabled",
                         "this server runs without the robot's perception (craft serve --image-encoder none); "
                         "perceive on the robot (craft perceive) and POST /ground")
        rgb = decode_image(req.rgb_b64, self.max_image_pixels, "rgb_b64", colour_only=True)
        raw = decode_base64(req.depth_b64)
        if raw is None:
            raise _invalid(["depth_b64"], "not valid base64", "depth_base64")
        try:
            from ..frame import FrameTooLargeError, decode_depth

            # the pixel bound is read from a PNG's header: a 10000 x 10000 one took 7.5 s and 1.5 GB to refuse
            depth = decode_depth(raw, req.depth_scale, self.max_image_pixels)
        except FrameTooLargeError as exc:
            raise _error(413, "image_too_large", str(exc), limit_pixels=exc.limit) from None
        except FrameError as exc:
            raise _invalid(["depth_b64"], str(exc), "depth_decode") from None
        if depth.shape != rgb.shape[:2]:
            raise _invalid(["depth_b64"], f"depth is {depth.shape[1]}x{depth.shape[0]} pixels, the colour image "
                           f"{rgb.shape[1]}x{rgb.shape[0]}: send both from one registered frame", "frame_shape")
        intrinsics = req.camera.intrinsics(int(rgb.shape[1]), int(rgb.shape[0]))
        keep = None
        if req.mask_b64 is not None:
            from ..perception.workspace import mask_from_image

            keep = mask_from_image(decode_image(req.mask_b64, self.max_image_pixels, "mask_b64", png_only=True))
        try:
            with self._encoder_lock:
                return perceive(self.frame_encoder, self.frame_config, rgb, depth, intrinsics,
                                req.camera.cam_to_world, colours=colours, cavity=cavity, mask=keep,
                                workspace=None if req.workspace is None else req.workspace.workspace())
        except FrameError as exc:  # the field at fault: a camera model or pose is not the depth's fault
            raise _invalid(FRAME_FIELDS.get(exc.part, ["depth_b64"]), str(exc), "frame") from None

    def check_verb(self, grounder: Grounder, verb: str) -> None:
        """404 with close matches for a verb ``grounder`` cannot ground, as ``ground`` answers."""
        try:
            grounder.check_verb(verb)
        except UnknownVerbError as exc:
            raise _error(404, "unknown_verb", str(exc), verb=exc.verb, close_matches=exc.close_matches) from None

    def choose_in_frame(self, grounder: Grounder, frame: PerceivedFrame, verb: str,
                        options: GroundOptions | None) -> dict[str, Any]:
        """``frame.choose`` on the event loop, as JSON: ``/ground``'s answer plus the frame's."""
        from ..frame import choose

        try:
            found: FrameGrounding = choose(grounder, frame, verb, self.hand_boxes)
        except UnknownVerbError as exc:
            raise _error(404, "unknown_verb", str(exc), verb=exc.verb, close_matches=exc.close_matches) from None
        except ValueError as exc:
            raise _error(422, "invalid_input", str(exc)) from None
        data = grounding_json(found.grounding, self.bundle, options)
        data.update(found.frame_dict())
        data["image"] = {"width": frame.obs.shape[1], "height": frame.obs.shape[0],
                         "encoder": self.frame_encoder.id if self.frame_encoder is not None else None}
        return data

    def ground(self, verb: str, rois: list[ROI], options: GroundOptions | None,
               objects: list[str] | None = None) -> dict[str, Any]:
        grounder = self.grounder(options, objects)
        # All-zero grasp scores mean no feasible grasp: E_grasp would be clipped to -log(1e-6)
        # and a strong affordance could still make the ROI the choice. Exclude it instead.
        no_grasp = {i for i, r in enumerate(rois) if r.grasp_scores and max(r.grasp_scores) <= 0.0}
        if no_grasp:
            rois = [replace(r, grasp_scores=[]) if i in no_grasp else r for i, r in enumerate(rois)]
        try:
            result = grounder.ground(verb, rois)
        except UnknownVerbError as exc:
            raise _error(404, "unknown_verb", str(exc), verb=exc.verb,
                         close_matches=exc.close_matches) from None
        except ValueError as exc:  # anything else the grounder refuses is the input's fault
            raise _error(422, "invalid_input", str(exc)) from None
        data = grounding_json(result, self.bundle, options)
        for entry in data["excluded"]:
            if entry["index"] in no_grasp:
                entry["reason"] = ("every grasp score is 0.0: no feasible grasp, the robot cannot "
                                   "pick it up")
        return data


def grounding_json(result: Grounding, bundle: Bundle, options: GroundOptions | None) -> dict[str, Any]:
    """``Grounding.to_dict`` plus the chosen grasp spelled out, the KB hash, ``top_k``."""
    data = result.to_dict()
    best = result.chosen
    data["chosen_grasp"] = None if best is None else {
        "roi": best.index, "grasp_index": best.grasp_index,
        "grasp_score": float(best.roi.grasp_scores[best.grasp_index]),
    }
    data["kb_content_sha256"] = bundle.manifest.content_sha256
    data["ranked_total"] = len(data["ranked"])
    if options is not None and options.top_k is not None:
        data["ranked"] = data["ranked"][: options.top_k]
    return data


def decode_image(b64: str, max_pixels: int = MAX_IMAGE_PIXELS, name: str = "image_b64", *,
                 colour_only: bool = False, png_only: bool = False) -> npt.NDArray[np.uint8]:
    """Base64 PNG/JPEG -> ``HxWx3`` uint8; a 422 naming the problem (and the field ``name``)
    otherwise (413: too many pixels, judged from the header before anything is decoded).
    ``colour_only`` (both endpoints' colour images): a 16-bit or float single-channel image is a
    422 too, since converting it to RGB clips it to white (a depth PNG sent as the colour
    image was perceived into another grasp, silently). ``png_only`` (a mask): JPEG is a 422, since
    its compression leaves non-zero pixels beside a mask's edges."""
    from PIL import Image, UnidentifiedImageError

    raw = decode_base64(b64)
    if raw is None:
        raise _invalid([name], "not valid base64", "image_base64")
    try:
        with Image.open(io.BytesIO(raw)) as img:
            if img.format not in IMAGE_FORMATS or (png_only and img.format != "PNG"):
                raise _invalid([name], f"image format {img.format}; send {'a PNG' if png_only else 'PNG or JPEG'}",
                               "image_format")
            if img.width * img.height > max_pixels:
                raise _error(413, "image_too_large", f"image is {img.width}x{img.height} pixels; "
                             f"this server decodes at most {max_pixels} pixels (downscale it)",
                             limit_pixels=max_pixels)
            if colour_only and (img.mode.startswith("I") or img.mode == "F"):
                raise _invalid([name], f"a single-channel {img.mode} image, not 8-bit colour (the depth image?); "
                               "send the colour image as 8-bit RGB PNG or JPEG", "image_mode")
            return np.asarray(img.convert("RGB"), dtype=np.uint8)  # [H, W, 3]
    except UnidentifiedImageError:
        raise _invalid([name], "not a readable PNG/JPEG (the decoded bytes are no image)",
                       "image_decode") from None
    except Image.DecompressionBombError:  # PIL's own bound, met in the header before ours: too large too
        raise _error(413, "image_too_large", "the image claims more pixels than its decoder takes; this server "
                     f"decodes at most {max_pixels} pixels (downscale it)", limit_pixels=max_pixels) from None
    except OSError as exc:
        raise _invalid([name], f"not a readable PNG/JPEG ({exc})", "image_decode") from None


def build_service(
    kb: Path | str | Bundle,
    *,
    image_encoder: ImageEncoder | None = None,
    max_rois: int = DEFAULT_MAX_ROIS,
    settings: GroundingSettings | None = None,
    trusted_keys: Sequence[bytes | str] | None = None,
) -> GroundingService:
    """Load and verify the bundle (``BundleError`` on failure), build a grounder per energy form.

    ``image_encoder`` must embed into the bundle's text space (else ``ServeError``): cosines
    across spaces would rank garbage without any error. Both energy forms are prepared here so
    that a request choosing the other form does not stall on recomputing the ``[V, O]`` matrix.
    ``settings`` (temperature, open vocabulary) apply to every request; a request may choose
    another energy form and weights.
    """
    settings = settings or GroundingSettings()
    if max_rois < 1:
        raise ServeError(f"max_rois must be >= 1, got {max_rois}")
    encoder_id = image_encoder.text_encoder_id if image_encoder is not None else None
    bundle = kb if isinstance(kb, Bundle) else load_bundle(kb, encoder_id=encoder_id, trusted_keys=trusted_keys)
    space = bundle.manifest.text_encoder.id
    if image_encoder is not None and encoder_id != space:
        raise ServeError(f"image encoder {image_encoder.id} embeds into {encoder_id}, "
                         f"the bundle's text encoder is {space}; serve a matching bundle")
    text_encoder = None
    if settings.open_vocab:  # load the text encoder now, not on the first unknown verb
        from ..encoders.text import load_text_encoder

        text_encoder = load_text_encoder(space)
    default: EnergyForm = bundle.manifest.energy.form
    forms: tuple[EnergyForm, ...] = ENERGY_FORMS
    grounders = {
        form: Grounder(bundle, settings.model_copy(update={"energy_form": form}), text_encoder=text_encoder)
        for form in forms
    }
    return GroundingService(bundle, grounders, default, image_encoder, max_rois)


def enable_perception(service: GroundingService, encoder: RobotEncoder, gripper: str = "panda",
                      threads: int = 1) -> None:
    """Give ``service`` the robot's perception for ``POST /perceive``: ``encoder`` (the robot's,
    ``sim_eval.default_encoder``, in the bundle's text space, else ``ServeError``), the default
    pipeline with ``gripper``'s fingers, and its hand's boxes for the approach check."""
    from ..frame import FRAME_SEGMENT
    from ..sim.episode import sim_configs
    from ..sim.hands import hand_spec
    from ..sim.pipeline import PipelineConfig

    space = service.bundle.manifest.text_encoder.id
    if encoder.text_encoder_id != space:
        raise ServeError(f"image encoder {encoder.id} embeds into {encoder.text_encoder_id}, "
                         f"the bundle's text encoder is {space}; serve a matching bundle")
    try:
        _, pick, fingers = sim_configs(gripper, wrist_look=False)
    except ValueError as exc:
        raise ServeError(str(exc)) from None
    service.frame_encoder = encoder
    service.frame_config = PipelineConfig(torch_threads=threads, pick=pick, fingers=fingers, segment=FRAME_SEGMENT)
    service.hand_boxes = hand_spec(gripper).clearance_boxes


class BodyLimit:
    """ASGI middleware: refuse POST bodies over a per-path bound with 413, before parsing.

    A declared ``Content-Length`` is checked without reading anything; a chunked body is
    buffered only up to the bound. Pure ASGI rather than ``BaseHTTPMiddleware``, which costs a
    task and a stream per request (measurable at thousands of requests per second on 2 cores).
    """

    def __init__(self, app: ASGIApp, limits: dict[str, int], default: int) -> None:
        self.app = app
        self.limits = limits
        self.default = default

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "POST":
            await self.app(scope, receive, send)
            return
        bound = self.limits.get(scope["path"], self.default)
        length = dict(scope["headers"]).get(b"content-length")
        if length is not None:
            try:
                size = int(length)
            except ValueError:
                await _reject(400, "bad_content_length", "Content-Length is not a number", scope, receive, send)
                return
            if size > bound:
                await _too_large(size, bound, scope, receive, send)
                return
            await self.app(scope, receive, send)
            return
        chunks: list[bytes] = []
        size = 0
        while True:
            message = await receive()
            if message["type"] != "http.request":
                return  # the client went away
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > bound:
                await _too_large(size, bound, scope, receive, send)
                return
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        body = b"".join(chunks)
        replayed = False

        async def replay() -> Message:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


async def _reject(status: int, kind: str, message: str, scope: Scope, receive: Receive, send: Send,
                  **extra: Any) -> None:
    response = JSONResponse({"detail": {"error": kind, "message": message, **extra}}, status)
    await response(scope, receive, send)


async def _too_large(size: int, bound: int, scope: Scope, receive: Receive, send: Send) -> None:
    await _reject(413, "body_too_large", f"request body of at least {size} bytes; this endpoint "
                  f"accepts at most {bound} (craft serve --max-body-bytes)", scope, receive, send,
                  limit_bytes=bound)


async def _validation_error(request: Request, exc: Exception) -> JSONResponse:
    """422 with ``loc``/``msg``/``type`` per error, without echoing the offending input.

    FastAPI's default handler echoes ``input``: a rejected NaN then fails JSON encoding (a 500
    instead of the 422), and a wrong-length embedding is sent back whole.
    """
    errors = exc.errors() if isinstance(exc, RequestValidationError) else []
    detail = [{"loc": list(e.get("loc", ())), "msg": str(e.get("msg", "")), "type": str(e.get("type", ""))}
              for e in errors]
    return JSONResponse({"detail": detail}, 422)


def create_app(
    kb: Path | str | Bundle | GroundingService,
    *,
    image_encoder: ImageEncoder | None = None,
    max_rois: int = DEFAULT_MAX_ROIS,
    settings: GroundingSettings | None = None,
    trusted_keys: Sequence[bytes | str] | None = None,
    max_body_bytes: int = DEFAULT_MAX_BODY_BYTES,
    max_image_body_bytes: int = DEFAULT_MAX_IMAGE_BODY_BYTES,
    max_image_boxes: int | None = None,
    max_image_pixels: int | None = None,
    max_concurrent_images: int | None = None,
    frame_encoder: RobotEncoder | None = None,
    gripper: str = "panda",
) -> FastAPI:
    """The FastAPI app over a verified bundle (loaded here, before any request); the keyword
    arguments other than the body and image limits are ``build_service``'s (ignored for a
    service). Image limits left as None keep the service's (the module defaults).
    ``frame_encoder`` (the robot's, ``sim_eval.default_encoder``) and ``gripper`` enable ``POST
    /perceive``: the frame's perception as ``craft perceive`` runs it."""
    service = kb if isinstance(kb, GroundingService) else build_service(
        kb, image_encoder=image_encoder, max_rois=max_rois, settings=settings,
        trusted_keys=trusted_keys)
    if frame_encoder is not None:
        enable_perception(service, frame_encoder, gripper)
    if max_image_boxes is not None:
        service.max_image_boxes = max_image_boxes
    if max_image_pixels is not None:
        service.max_image_pixels = max_image_pixels
    if max_concurrent_images is not None:
        service.max_concurrent_images = max_concurrent_images
        service._image_slots = None
    m = service.bundle.manifest
    # docs_url/redoc_url None: FastAPI's pages load Swagger UI / ReDoc from a CDN, which a robot
    # without network cannot reach; /docs below is a self-contained page instead.
    app = FastAPI(title="CRAFT-E grounding", version=m.kb_version, docs_url=None, redoc_url=None,
                  description=f"Grounds verbs in scenes with KB {m.kb_name}@{m.kb_version} "
                              f"(content sha256 {m.content_sha256[:16]}...). No network access.")
    app.state.service = service
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_middleware(BodyLimit, limits={"/ground_image": max_image_body_bytes, "/perceive": max_image_body_bytes},
                       default=max_body_bytes)

    @app.get("/healthz")
    def healthz() -> dict[str, Any]:
        """KB identity and dimensions; 200 means the bundle was verified and is loaded."""
        return service.health()

    @app.get("/verbs")
    def verbs() -> dict[str, Any]:
        """The verbs this KB grounds (others get 404 unless the server runs --open-vocab)."""
        return {"kb": f"{m.kb_name}@{m.kb_version}", "verbs": list(m.verbs),
                "open_vocab": service.grounders[service.default_form].open_vocab}

    @app.post("/ground", openapi_extra=_body_doc(GroundRequest), response_class=JSONResponse)
    async def ground(request: Request) -> Response:
        """Rank ROIs with precomputed image embeddings for a verb (lowest energy first).

        Runs on the event loop: the whole request is ~1 ms of numpy, less than a thread hand-off.
        """
        req = await _parse(request, GroundRequest)
        return _json(service.ground(req.verb, service.rois_from_request(req), req.options, req.objects))

    @app.post("/ground_image", openapi_extra=_body_doc(GroundImageRequest), response_class=JSONResponse)
    async def ground_image(request: Request) -> Response:
        """Rank boxes of a posted image; crops are embedded server-side (image encoder).

        Decoding and the encoder's forward pass (tens of ms per crop) run in the thread pool so
        that ``/ground`` and ``/healthz`` keep answering meanwhile.
        """
        slot = service.image_slot()
        if not slot.acquire(blocking=False):
            return _busy(service)
        try:
            req = await _parse(request, GroundImageRequest)
            service.check_image_boxes(len(req.boxes))  # before decoding anything
            rois, size = await run_in_threadpool(service.rois_from_image, req)
        finally:
            slot.release()
        data = service.ground(req.verb, rois, req.options)
        data["notes"] = [*data.get("notes", []), *boxes_past_the_image([b.box_xywh for b in req.boxes], size["width"], size["height"])]
        data["image"] = {**size, "encoder": service.image_encoder.id if service.image_encoder is not None else None}
        return _json(data)

    @app.post("/perceive", openapi_extra=_body_doc(PerceiveRequest), response_class=JSONResponse)
    async def perceive_frame(request: Request) -> Response:
        """Perceive one RGB-D frame as the robot does and choose the object and grasp for a verb.

        Segmentation, one grasp-network pass, the crops' embeddings and the depth cues run in the
        thread pool (``benchmarks/bench_perception.py`` times the same stages); the choice runs on
        the event loop.
        No robot model: the grasp is checked against the open hand and its approach against the
        depth, not planned (no IK)."""
        slot = service.image_slot()
        if not slot.acquire(blocking=False):
            return _busy(service)
        try:
            req = await _parse(request, PerceiveRequest)
            grounder = service.grounder(req.options, req.objects)
            service.check_verb(grounder, req.verb)  # a 404 before decoding anything
            frame = await run_in_threadpool(service.perceive_frame, req, grounder.colour_cue_active,
                                            grounder.cavity_cue_active)
        finally:
            slot.release()
        return _json(service.choose_in_frame(grounder, frame, req.verb, req.options))

    @app.get("/docs", include_in_schema=False, response_class=HTMLResponse)
    def docs() -> HTMLResponse:
        """A self-contained API page: no scripts, no CDN, works with no network."""
        return HTMLResponse(_docs_page(app))

    _document_bodies(app, (GroundRequest, GroundImageRequest, PerceiveRequest))
    return app


def _busy(service: GroundingService) -> JSONResponse:
    """503 with ``Retry-After`` when ``max_concurrent_images`` images are being decoded already
    (``/ground_image``, ``/perceive``): refused at once instead of queueing their memory."""
    return JSONResponse({"detail": {
        "error": "busy", "message": f"{service.max_concurrent_images} images are being "
        "decoded already; retry in a moment", "limit": service.max_concurrent_images}},
        503, headers={"Retry-After": "1"})


def _docs_page(app: FastAPI) -> str:
    """Endpoints and their summaries from the OpenAPI schema, as plain HTML (no assets)."""
    schema = app.openapi()
    rows = []
    for path, methods in schema.get("paths", {}).items():
        for method, op in methods.items():
            summary = html.escape(str(op.get("summary", "")))
            text = html.escape(str(op.get("description", ""))).replace("\n\n", "<br>")
            rows.append(f"<tr><td><code>{method.upper()} {html.escape(path)}</code></td>"
                        f"<td><b>{summary}</b><br>{text}</td></tr>")
    info = schema.get("info", {})
    return ("<!doctype html><html><head><meta charset='utf-8'><title>"
            f"{html.escape(str(info.get('title', '')))}</title></head><body>"
            f"<h1>{html.escape(str(info.get('title', '')))} {html.escape(str(info.get('version', '')))}</h1>"
            f"<p>{html.escape(str(info.get('description', '')))}</p>"
            "<p>Machine-readable schema: <a href='/openapi.json'>/openapi.json</a>.</p>"
            f"<table border='1' cellpadding='4'>{''.join(rows)}</table></body></html>")


ModelT = TypeVar("ModelT", bound=BaseModel)


async def _parse(request: Request, model: type[ModelT]) -> ModelT:
    """Validate the raw body with pydantic-core's JSON parser.

    About 4x faster than FastAPI's ``json.loads`` + validate on a 10-ROI body (40 KB of floats),
    and it rejects ``NaN``/``Infinity`` in the JSON itself. Errors become FastAPI's 422 shape.
    """
    body = await request.body()
    try:
        return model.model_validate_json(body)
    except ValidationError as exc:
        errors = [{**e, "loc": ("body", *e["loc"])} for e in exc.errors(include_url=False)]
        raise RequestValidationError(errors) from None


def _json(data: dict[str, Any]) -> Response:
    """Serialize once with ``json.dumps`` (FastAPI's ``jsonable_encoder`` walk costs ~0.9 ms)."""
    body = json.dumps(data, allow_nan=False, separators=(",", ":")).encode()
    return Response(body, media_type="application/json")


def _body_doc(model: type[BaseModel]) -> dict[str, Any]:
    """OpenAPI request body of a manually parsed endpoint (``_document_bodies`` adds the schema)."""
    ref = {"$ref": f"#/components/schemas/{model.__name__}"}
    return {"requestBody": {"required": True, "content": {"application/json": {"schema": ref}}}}


def _document_bodies(app: FastAPI, models: Sequence[type[BaseModel]]) -> None:
    """Add the request models' JSON Schemas to ``/openapi.json`` components (for client codegen)."""
    plain = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = plain()
            components = schema.setdefault("components", {}).setdefault("schemas", {})
            for model in models:
                doc = model.model_json_schema(ref_template="#/components/schemas/{model}")
                components.update(doc.pop("$defs", {}))
                components[model.__name__] = doc
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


ImageEncoderChoice = Literal["conse", "none"]


def load_image_encoder(name: ImageEncoderChoice, threads: int | None = 1,
                       sense_weight: float | None = None, temperature: float | None = None) -> ImageEncoder | None:
    """The image encoder for ``/ground_image`` (``none``: the endpoint answers 503).
    ``sense_weight``: how ConSE reads its class names (the server's
    ``GroundingSettings.class_senses``, which its hubness reference follows; None: the default);
    ``temperature``: its classifier's softmax temperature for ConSE's weights (the server's
    ``GroundingSettings.conse_temperature``; None: the default)."""
    if name == "none":
        return None
    from ..encoders.conse import ConSEImageEncoder

    return ConSEImageEncoder(threads=threads, sense_weight=sense_weight, temperature=temperature)


def robot_encoder(encoder: ImageEncoder | None) -> RobotEncoder | None:
    """``POST /perceive``'s encoder: ``encoder`` (``/ground_image``'s, from ``load_image_encoder``)
    reading whole square crops as the robot does (``sim_eval.default_encoder``), with the same
    classifier and class-name table in memory rather than a second copy of each. None without
    an image encoder (``/perceive`` then answers 503, as ``/ground_image`` does)."""
    if encoder is None:
        return None
    from ..encoders.conse import ROBOT_PREPROCESS, ConSEImageEncoder

    if not isinstance(encoder, ConSEImageEncoder):
        raise ServeError(f"POST /perceive reads the robot's ConSE encoder; {encoder.id} is not one")
    return encoder.with_preprocess(ROBOT_PREPROCESS)
