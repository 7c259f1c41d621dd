"""``craft ground``: rank the ROIs of one image for a verb and explain the choice.

Thin: options are resolved into :class:`GroundingSettings`, the image + boxes become ROIs through
``perception.roi.build_rois`` (the function the server and the benchmarks use), and the
``Grounder`` does the rest.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from ..grounding.settings import DEFAULT_ALPHA, DEFAULT_BETA, DEFAULT_GAMMA
from .common import (
    AffModeOpt,
    AffNormOpt,
    EnergyFormOpt,
    TemperatureOpt,
    checked_output_file,
    checked_plot_file,
    fail,
    grounding_settings,
    note,
    out,
    read_some_names,
)
from .episodes import LookalikesOpt

if TYPE_CHECKING:
    from ..perception.roi import BoxSpec


def parse_box(text: str) -> tuple[float, float, float, float]:
    """``"x,y,w,h"`` in pixels -> a 4-tuple; anything else is a usage error naming the text.

    ``float`` reads ``nan`` and ``inf``: a NaN box would be ranked (``box nan, nan, ...``) and
    written into ``--json`` as ``NaN``, an infinite one overflows the crop, so both are refused
    here, as ``read_rois_file`` refuses them in a ROIs file."""
    parts = [p for p in text.replace(" ", "").split(",") if p]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) == 4 and not all(math.isfinite(v) for v in values):
        raise ValueError(f"--box {text!r}: x,y,w,h must be finite numbers of pixels (not nan or inf)")
    if len(values) != 4 or values[2] <= 0 or values[3] <= 0:
        raise ValueError(f"--box {text!r}: expected x,y,w,h in pixels with w, h > 0")
    return values[0], values[1], values[2], values[3]


def read_rois_file(path: Path) -> list[BoxSpec]:
    """ROIs JSON: a list (or ``{"rois": [...]}``) of ``{"box": [x, y, w, h], "grasp_scores":
    [...] (optional), "label": "..." (optional)}``."""
    from ...files import read_json
    from ..perception.roi import BoxSpec

    data = read_json(path, "ROIs file", ValueError)
    items = data.get("rois") if isinstance(data, dict) else data
    if not isinstance(items, list) or not items:
        raise ValueError(f'{path}: expected a non-empty list of ROIs or {{"rois": [...]}}')
    rois: list[BoxSpec] = []

    def number(v: object) -> bool:  # JSON true/false are not numbers; NaN and inf are not sizes
        return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)

    for i, item in enumerate(items):
        if not isinstance(item, dict) or "box" not in item:
            raise ValueError(f"{path}: ROI {i}: expected an object with a 'box' [x, y, w, h]")
        box = item["box"]
        if not (isinstance(box, list) and len(box) == 4 and all(number(v) for v in box)):
            raise ValueError(f"{path}: ROI {i}: 'box' must be [x, y, w, h] finite numbers")
        if box[2] <= 0 or box[3] <= 0:
            raise ValueError(f"{path}: ROI {i}: 'box' {box}: width and height must be > 0 (pixels)")
        scores = item.get("grasp_scores")
        if scores is not None and not (isinstance(scores, list) and all(number(s) for s in scores)):
            raise ValueError(f"{path}: ROI {i}: 'grasp_scores' must be a list of finite numbers")
        if scores is not None and not all(0.0 <= s <= 1.0 for s in scores):
            raise ValueError(f"{path}: ROI {i}: 'grasp_scores' must lie in [0, 1] (qualities, not logits)")
        label = item.get("label")
        rois.append(BoxSpec((float(box[0]), float(box[1]), float(box[2]), float(box[3])),
                            None if scores is None else [float(s) for s in scores],
                            None if label is None else str(label)))
    return rois


def ground(
    kb: Annotated[Path, typer.Option(help="Bundle folder (or signed .craft file with --trusted-key).")],
    verb: Annotated[str, typer.Option(help="The action, e.g. cut.")],
    image: Annotated[Path, typer.Option(help="RGB image (png/jpg).")],
    box: Annotated[list[str] | None, typer.Option("--box", help="ROI as x,y,w,h pixels; repeatable.")] = None,
    rois: Annotated[Path | None, typer.Option(help="ROIs JSON (boxes, optional grasp_scores, labels).")] = None,
    depth: Annotated[Path | None, typer.Option(help="Depth .npy (HxW metres), for grasp prediction.")] = None,
    grasp: Annotated[str, typer.Option(help="Grasp backend with --depth: auto (antipodal) | grconvnet | ggcnn | ggcnn2 | antipodal.")] = "auto",
    plot: Annotated[Path | None, typer.Option(help="Write a figure (ROIs by energy + reasoning path).",
                                                        callback=checked_plot_file)] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the grounding as JSON.",
                                                                      callback=checked_output_file)] = None,
    alpha: Annotated[float, typer.Option(help="Weight of E_grasp.")] = DEFAULT_ALPHA,
    beta: Annotated[float, typer.Option(help="Weight of E_aff (the paper: 1; docs/energy_weights.md).")] = DEFAULT_BETA,
    gamma: Annotated[float, typer.Option(help="Weight of E_align (the paper: 1; docs/energy_weights.md).")] = DEFAULT_GAMMA,
    temperature: TemperatureOpt = None,
    aff_mode: AffModeOpt = "expected",
    aff_norm: AffNormOpt = None,
    energy_form: EnergyFormOpt = None,
    vocab: Annotated[Path | None, typer.Option(help="Scene object vocabulary file (one per line; default: the KB's objects).")] = None,
    open_vocab: Annotated[bool, typer.Option(help="Accept verbs the KB lacks and free requests (\"dig a hole\"): mapped to properties of similar verbs and properties, or abstained on.")] = False,
    image_encoder: Annotated[str, typer.Option(help="conse | clip-vit-b32 (needs --clip-weights/--clip-sha256).")] = "conse",
    clip_weights: Annotated[Path | None, typer.Option(help="CLIP ViT-B/32 weights (state dict or ONNX).")] = None,
    clip_sha256: Annotated[str | None, typer.Option(help="Expected sha256 of --clip-weights.")] = None,
    trusted_key: Annotated[list[Path] | None, typer.Option("--trusted-key", help="Signer key for a .craft package.")] = None,
    threads: Annotated[int | None, typer.Option(min=1, help="Torch threads for the image encoder (1 is fastest on busy hosts).")] = None,
    lookalikes: LookalikesOpt = None,
) -> None:
    """Rank ROIs of an image for a verb and explain the choice (no network access)."""
    import numpy as np

    from ...schemas.names import MAX_NAME_CHARS, shown
    from ..encoders import REGISTRY, EncoderError, load_image
    from ..encoders.image import load_image as read_image
    from ..grounding.grounder import Grounder
    from ..kb.bundle import BundleError, load_bundle
    from ..perception.roi import BoxSpec, RoiError, boxes_past_the_image, build_rois

    if len(verb) > MAX_NAME_CHARS:  # checked first: a huge --verb is never processed or echoed
        fail(f"--verb {shown(verb)} is longer than {MAX_NAME_CHARS} characters")
    if not verb.strip():
        fail("--verb is blank; name the action, e.g. --verb cut")
    if (box is None) == (rois is None):
        fail("give the ROIs either as --box x,y,w,h (repeatable) or as --rois FILE")
    vocabulary = read_some_names(vocab, "vocabulary", "--vocab") if vocab is not None else None
    settings = grounding_settings(alpha=alpha, beta=beta, gamma=gamma, temperature=temperature,
                                  aff_mode=aff_mode, aff_norm=aff_norm, energy_form=energy_form, open_vocab=open_vocab,
                                  vocabulary=vocabulary, lookalikes=lookalikes)
    try:
        specs = [BoxSpec(parse_box(b)) for b in box] if box else read_rois_file(rois) if rois else []
    except ValueError as exc:
        fail(str(exc))
    from ..grasp.predict import BACKENDS

    if grasp != "auto" and grasp not in BACKENDS:
        fail(f"--grasp {grasp!r}: use auto or one of {', '.join(BACKENDS)}")
    if grasp != "auto" and depth is None:
        fail(f"--grasp {grasp} predicts grasps from depth: pass --depth FILE.npy too")
    if image.is_dir():
        fail(f"{image}: is a folder; give an image file (png/jpg)")
    if not image.is_file():
        fail(f"{image}: image not found")
    try:
        rgb = read_image(str(image))
    except OSError as exc:
        fail(f"{image}: not a readable image ({exc})")
    depth_map = None
    if depth is not None:
        try:
            depth_map = np.load(depth, allow_pickle=False)
        except (OSError, ValueError) as exc:
            fail(f"{depth}: not a .npy depth map ({exc})")
        if depth_map.ndim != 2 or not np.issubdtype(depth_map.dtype, np.number):
            fail(f"{depth}: depth must be an H x W array of metres, got shape {depth_map.shape} "
                 f"({depth_map.dtype})")
        if depth_map.shape[:2] != rgb.shape[:2]:
            fail(f"{depth}: depth is {depth_map.shape[:2]}, image is {rgb.shape[:2]}")
    entry = REGISTRY.get(image_encoder)
    if entry is None or entry.kind != "image":
        fail(f"--image-encoder {image_encoder!r}: choose one of {', '.join(n for n, e in REGISTRY.items() if e.kind == 'image')}")
    try:  # the bundle must live in the text space the image encoder embeds into
        bundle = load_bundle(kb, encoder_id=entry.text_space,
                             trusted_keys=[str(k) for k in trusted_key] if trusted_key else None)
    except BundleError as exc:
        fail(str(exc))
    try:
        kwargs: dict[str, Any] = ({"weights": clip_weights, "sha256": clip_sha256} if image_encoder.startswith("clip")
                                  else {"threads": threads} if image_encoder == "conse" else {})
        encoder = load_image(image_encoder, **kwargs)
    except EncoderError as exc:
        fail(str(exc))
    if encoder.text_encoder_id != bundle.manifest.text_encoder.id:
        fail(f"{kb}/manifest.json: the bundle's text encoder is {bundle.manifest.text_encoder.id}, but image "
             f"encoder {image_encoder} embeds into {encoder.text_encoder_id}; use a matching bundle")

    try:
        roi_list = build_rois(rgb, specs, encoder, depth=depth_map,
                              grasp_backend="antipodal" if grasp == "auto" else grasp)
    except RoiError as exc:
        fail(str(exc))
    notes = boxes_past_the_image([s.box for s in specs], rgb.shape[1], rgb.shape[0])
    defaulted = [r for r, s in zip(roi_list, specs, strict=True) if s.grasp_scores is None and depth_map is None]
    for r in defaulted:
        r.grasp_scores = [1.0]
    if defaulted:
        notes.append(f"no grasp information for {len(defaulted)} ROI(s): grasp scores default to 1.0 (E_grasp = 0); "
                     "pass --depth (grasp prediction) or grasp_scores in --rois")
    try:
        grounder = Grounder(bundle, settings)
        result = grounder.ground(verb, roi_list)
    except ValueError as exc:  # UnknownVerbError included
        fail(str(exc))
    result.notes.extend(notes)
    if grounder.objects_without_knowledge:
        confident = [n for n in grounder.objects_without_knowledge if n in grounder.inferred and grounder.inferred[n].confident]
        unknown = [n for n in grounder.objects_without_knowledge if n not in confident]
        if confident:
            result.notes.append(f"vocabulary objects not in the KB, inferred from similar objects: {', '.join(confident)}")
        if unknown:
            result.notes.append(f"vocabulary objects not in the KB, no confident inference (E_aff = 0): {', '.join(unknown)}")
    out.print(result.render(), highlight=False, markup=False, soft_wrap=True)
    if json_out is not None:
        data = {"image": str(image), "image_encoder": encoder.id, **result.to_dict()}
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
        note(f"wrote {json_out}")
    if plot is not None:
        from ..grounding.plotting import plot_grounding

        plot_grounding(rgb, result, plot)
        note(f"wrote {plot}")
