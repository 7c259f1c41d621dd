"""``craft``: the runtime's command line (grounding, evaluation, simulation, installs).

Commands are thin; the work lives in modules. Heavy imports (torch, matplotlib, encoders) happen
inside command bodies so ``craft --help`` stays fast, and the runtime CLI never imports the
compiler, httpx or rdflib.

Structure, so other modules can add commands without editing this file's commands:

* ``app`` — top level (``craft ground``, ``craft install``...);
* ``eval_app`` — ``craft eval <benchmark>`` (``imagenet`` here; ``sim``, ``static`` elsewhere);
* ``sim_app`` — ``craft sim <command>`` (``demo``...).

A module listed in ``COMMAND_MODULES`` defines ``register(app: typer.Typer) -> None`` and is
imported when this module is; it may also ``from craft_e.runtime.cli import eval_app, sim_app``
inside ``register``. A listed module that is missing or fails to import is an error, never a
silently absent command.

Exit codes: 0 ok; 2 bad input or usage (files, boxes, unknown verb, bundle refused); 1 a check
failed (reserved for verification commands).
"""

from __future__ import annotations

import os

# ``ground`` multiplies tiny matrices ([10, 384] x [384, 400]); multi-threaded OpenBLAS turns that
# into 1-20 ms of thread hand-offs on a busy 2-core host (0.3 ms single-threaded). Must be set
# before numpy is imported; a user's own setting wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import importlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import typer
from rich.console import Console
from rich.markup import escape

if TYPE_CHECKING:
    from craft_e.runtime.grounding import ROI

app = typer.Typer(help="CRAFT-E runtime: ground verbs in scenes, evaluate, simulate, install KBs.",
                  no_args_is_help=True, add_completion=False)
eval_app = typer.Typer(help="Benchmarks: JSON + Markdown tables.", no_args_is_help=True)
sim_app = typer.Typer(help="The simulated CR3 testbed.", no_args_is_help=True)
app.add_typer(eval_app, name="eval")
app.add_typer(sim_app, name="sim")

#: Modules that add commands (each has ``register(app)``); see the module docstring.
COMMAND_MODULES: list[str] = [
    "craft_e.runtime.cli_install",
    "craft_e.runtime.sim.cli",
    "craft_e.runtime.evaluation.cli_sim",
    "craft_e.runtime.evaluation.cli_static",
    "craft_e.runtime.cli_serve",
    "craft_e.runtime.cli_robustness",
    "craft_e.runtime.evaluation.cli_zhu",
    "craft_e.runtime.evaluation.cli_kb",
    "craft_e.runtime.evaluation.cli_open_world",
]

err = Console(stderr=True)
out = Console()
EXIT_CHECK_FAILED = 1
EXIT_BAD_INPUT = 2


def fail(message: str, code: int = EXIT_BAD_INPUT) -> NoReturn:
    err.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def parse_box(text: str) -> tuple[float, float, float, float]:
    """``"x,y,w,h"`` in pixels -> a 4-tuple; anything else is a usage error naming the text."""
    parts = [p for p in text.replace(" ", "").split(",") if p]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 4 or values[2] <= 0 or values[3] <= 0:
        raise ValueError(f"--box {text!r}: expected x,y,w,h in pixels with w, h > 0")
    return values[0], values[1], values[2], values[3]


@dataclass(frozen=True)
class RoiSpec:
    """One ROI as given on the command line or in a ROIs file."""

    box: tuple[float, float, float, float]
    grasp_scores: list[float] | None = None
    label: str | None = None


def read_rois_file(path: Path) -> list[RoiSpec]:
    """ROIs JSON: a list (or ``{"rois": [...]}``) of ``{"box": [x, y, w, h], "grasp_scores":
    [...] (optional), "label": "..." (optional)}``."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"{path}: ROIs file not found") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc.msg} at line {exc.lineno})") from None
    items = data.get("rois") if isinstance(data, dict) else data
    if not isinstance(items, list) or not items:
        raise ValueError(f'{path}: expected a non-empty list of ROIs or {{"rois": [...]}}')
    rois: list[RoiSpec] = []
    for i, item in enumerate(items):
        if not isinstance(item, dict) or "box" not in item:
            raise ValueError(f"{path}: ROI {i}: expected an object with a 'box' [x, y, w, h]")
        box = item["box"]
        if not (isinstance(box, list) and len(box) == 4 and all(isinstance(v, int | float) for v in box)):
            raise ValueError(f"{path}: ROI {i}: 'box' must be [x, y, w, h] numbers")
        scores = item.get("grasp_scores")
        if scores is not None and not (isinstance(scores, list) and all(isinstance(s, int | float) for s in scores)):
            raise ValueError(f"{path}: ROI {i}: 'grasp_scores' must be a list of numbers")
        label = item.get("label")
        rois.append(RoiSpec((float(box[0]), float(box[1]), float(box[2]), float(box[3])),
                            None if scores is None else [float(s) for s in scores],
                            None if label is None else str(label)))
    return rois


def _grasps_for(backend: str, rgb: Any, depth: Any, box: tuple[float, float, float, float]) -> tuple[list[Any], list[float]]:
    """Grasp candidates on the object inside ``box`` (``predict_grasps`` of the grasp module).

    The grasp backends want the object's own mask (the fingers need free space beside it), so
    the box is intersected with the pixels standing above the support plane; an empty result
    falls back to the whole box.
    """
    import numpy as np

    from craft_e.runtime.grasp import estimate_object_mask, predict_grasps

    box_mask = np.zeros(depth.shape[:2], dtype=bool)
    x, y, w, h = (round(v) for v in box)
    box_mask[max(0, y) : max(0, y + h), max(0, x) : max(0, x + w)] = True
    mask = estimate_object_mask(depth) & box_mask
    grasps = predict_grasps(backend, rgb, depth, mask if mask.any() else box_mask)
    return list(grasps), [float(g.quality) for g in grasps]


@app.command()
def ground(
    kb: Annotated[Path, typer.Option(help="Bundle folder (or signed .craft file with --trusted-key).")],
    verb: Annotated[str, typer.Option(help="The action, e.g. cut.")],
    image: Annotated[Path, typer.Option(help="RGB image (png/jpg).")],
    box: Annotated[list[str] | None, typer.Option("--box", help="ROI as x,y,w,h pixels; repeatable.")] = None,
    rois: Annotated[Path | None, typer.Option(help="ROIs JSON (boxes, optional grasp_scores, labels).")] = None,
    depth: Annotated[Path | None, typer.Option(help="Depth .npy (HxW metres), for grasp prediction.")] = None,
    grasp: Annotated[str, typer.Option(help="Grasp backend with --depth: auto (antipodal) | grconvnet | ggcnn | ggcnn2 | antipodal.")] = "auto",
    plot: Annotated[Path | None, typer.Option(help="Write a figure (ROIs by energy + reasoning path).")] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the grounding as JSON.")] = None,
    alpha: Annotated[float, typer.Option(help="Weight of E_grasp.")] = 1.0,
    beta: Annotated[float, typer.Option(help="Weight of E_aff.")] = 1.0,
    gamma: Annotated[float, typer.Option(help="Weight of E_align.")] = 1.0,
    temperature: Annotated[float | None, typer.Option(help="Softmax temperature of p(o|r) (default: calibrated).")] = None,
    aff_mode: Annotated[str, typer.Option(help="expected | argmax.")] = "expected",
    energy_form: Annotated[str | None, typer.Option(help="sum-tanh | normalized-product | specificity | required-veto | specificity-veto (default: the bundle's).")] = None,
    vocab: Annotated[Path | None, typer.Option(help="Scene object vocabulary file (one per line; default: the KB's objects).")] = None,
    open_vocab: Annotated[bool, typer.Option(help="Accept verbs the KB lacks and free requests (\"dig a hole\"): mapped to properties of similar verbs and properties, or abstained on.")] = False,
    image_encoder: Annotated[str, typer.Option(help="conse | clip-vit-b32 (needs --clip-weights/--clip-sha256).")] = "conse",
    clip_weights: Annotated[Path | None, typer.Option(help="CLIP ViT-B/32 weights (state dict or ONNX).")] = None,
    clip_sha256: Annotated[str | None, typer.Option(help="Expected sha256 of --clip-weights.")] = None,
    trusted_key: Annotated[list[Path] | None, typer.Option("--trusted-key", help="Signer key for a .craft package.")] = None,
    threads: Annotated[int | None, typer.Option(min=1, help="Torch threads for the image encoder (1 is fastest on busy hosts).")] = None,
) -> None:
    """Rank ROIs of an image for a verb and explain the choice (no network access)."""
    import numpy as np

    from craft_e.runtime.bundle import BundleError, load_bundle
    from craft_e.runtime.encoders import REGISTRY, EncoderError
    from craft_e.runtime.encoders import load as load_encoder
    from craft_e.runtime.encoders.image import crop_box, load_image
    from craft_e.runtime.grounding import DEFAULT_TEMPERATURE, ROI, Grounder, UnknownVerbError
    from craft_e.schemas.names import MAX_NAME_CHARS, shown

    if len(verb) > MAX_NAME_CHARS:  # checked first: a huge --verb is never processed or echoed
        fail(f"--verb {shown(verb)} is longer than {MAX_NAME_CHARS} characters")
    if (box is None) == (rois is None):
        fail("give the ROIs either as --box x,y,w,h (repeatable) or as --rois FILE")
    if aff_mode not in ("expected", "argmax"):
        fail(f"--aff-mode {aff_mode!r}: use expected or argmax")
    from craft_e.runtime.energies import ENERGY_FORMS

    if energy_form is not None and energy_form not in ENERGY_FORMS:
        fail(f"--energy-form {energy_form!r}: use one of {', '.join(ENERGY_FORMS)}")
    try:
        specs = [RoiSpec(parse_box(b)) for b in box] if box else read_rois_file(rois) if rois else []
    except ValueError as exc:
        fail(str(exc))
    if not image.is_file():
        fail(f"{image}: image not found")
    try:
        rgb = load_image(str(image))
    except OSError as exc:
        fail(f"{image}: not a readable image ({exc})")
    depth_map = None
    if depth is not None:
        try:
            depth_map = np.load(depth, allow_pickle=False)
        except (OSError, ValueError) as exc:
            fail(f"{depth}: not a .npy depth map ({exc})")
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
    vocabulary = None
    if vocab is not None:
        try:
            from craft_e.runtime.evaluation.common import read_name_list

            vocabulary = read_name_list(vocab)
        except OSError as exc:
            fail(f"{vocab}: cannot read the vocabulary ({exc})")
    try:
        kwargs: dict[str, Any] = ({"weights": clip_weights, "sha256": clip_sha256} if image_encoder.startswith("clip")
                                  else {"threads": threads} if image_encoder == "conse" else {})
        encoder = load_encoder(image_encoder, **kwargs)
    except EncoderError as exc:
        fail(str(exc))
    if getattr(encoder, "text_encoder_id", None) != bundle.manifest.text_encoder.id:
        fail(f"{kb}/manifest.json: the bundle's text encoder is {bundle.manifest.text_encoder.id}, but image "
             f"encoder {image_encoder} embeds into {getattr(encoder, 'text_encoder_id', '?')}; use a matching bundle")

    notes: list[str] = []
    try:
        crops = [crop_box(rgb, s.box) for s in specs]
    except ValueError as exc:
        fail(str(exc))
    embeddings = encoder.embed_images(crops)  # [N, d]
    roi_list: list[ROI] = []
    backend = "antipodal" if grasp == "auto" else grasp
    defaulted = 0
    for i, s in enumerate(specs):
        grasps: list[Any] = []
        if s.grasp_scores is not None:
            scores = [float(v) for v in s.grasp_scores]
        elif depth_map is not None:
            try:
                grasps, scores = _grasps_for(backend, rgb, depth_map, s.box)
            except (ValueError, RuntimeError) as exc:
                fail(f"grasp prediction ({backend}) failed for ROI {i}: {exc}")
        else:
            scores = [1.0]
            defaulted += 1
        roi_list.append(ROI(box_xywh=s.box, grasp_scores=scores, grasps=grasps,
                            image_embedding=embeddings[i], label=s.label))
    if defaulted:
        notes.append(f"no grasp information for {defaulted} ROI(s): grasp scores default to 1.0 (E_grasp = 0); "
                     "pass --depth (grasp prediction) or grasp_scores in --rois")
    try:
        grounder = Grounder(bundle, alpha=alpha, beta=beta, gamma=gamma,
                            temperature=DEFAULT_TEMPERATURE if temperature is None else temperature,
                            aff_mode=aff_mode,  # type: ignore[arg-type]
                            energy_form=energy_form,
                            vocabulary=vocabulary, open_vocab=open_vocab)
        result = grounder.ground(verb, roi_list)
    except UnknownVerbError as exc:
        fail(str(exc))
    except ValueError as exc:
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
        err.print(f"wrote {json_out}", highlight=False, markup=False)
    if plot is not None:
        from craft_e.runtime.plotting import plot_grounding

        plot_grounding(rgb, result, plot)
        err.print(f"wrote {plot}", highlight=False, markup=False)


@eval_app.command("imagenet")
def eval_imagenet(
    labels: Annotated[Path, typer.Option(help='Labels JSON {"verb": ["object", ...]}.')],
    kb: Annotated[Path | None, typer.Option(help="CRAFT-E bundle (default artifacts/kb/craft-e-default).")] = None,
    episodes: Annotated[int, typer.Option(min=1, help="Episodes per verb and setting.")] = 100,
    seed: Annotated[int, typer.Option(help="Seed of the episode sampler.")] = 0,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write results as JSON.")] = None,
    markdown: Annotated[Path | None, typer.Option(help="Write the Markdown table.")] = None,
    kb_dir: Annotated[Path | None, typer.Option(help="Folder of the baseline bundles (conceptnet/, direct-llm/).")] = None,
    temperature: Annotated[float | None, typer.Option(help="Softmax temperature of p(o|r) (default: calibrated).")] = None,
    aff_mode: Annotated[str, typer.Option(help="expected | argmax.")] = "expected",
    energy_form: Annotated[str | None, typer.Option(help="sum-tanh | normalized-product | specificity | required-veto | specificity-veto (default: each bundle's).")] = None,
    no_cache: Annotated[bool, typer.Option(help="Do not read or write the on-disk image-embedding cache.")] = False,
    threads: Annotated[int | None, typer.Option(min=1, help="Torch threads for the image encoder.")] = None,
    classes: Annotated[Path | None, typer.Option(help="Only draw episodes from these classes (file, one per line); "
                                                       "they are also the p(o|r) vocabulary.")] = None,
) -> None:
    """Nguyen et al.'s ImageNet functional-grounding protocol: every method on the same episodes."""
    from craft_e.paths import KB_DIR
    from craft_e.runtime.encoders.conse import ENCODER_CACHE_DIR
    from craft_e.runtime.evaluation.imagenet import LabelsError, default_methods, evaluate_imagenet
    from craft_e.runtime.grounding import DEFAULT_TEMPERATURE

    if aff_mode not in ("expected", "argmax"):
        fail(f"--aff-mode {aff_mode!r}: use expected or argmax")
    from craft_e.runtime.energies import ENERGY_FORMS

    if energy_form is not None and energy_form not in ENERGY_FORMS:
        fail(f"--energy-form {energy_form!r}: use one of {', '.join(ENERGY_FORMS)}")
    pool = None
    if classes is not None:
        try:
            from craft_e.runtime.evaluation.common import read_name_list

            pool = read_name_list(classes)
        except OSError as exc:
            fail(f"{classes}: cannot read the classes file ({exc})")
    try:
        report = evaluate_imagenet(
            labels, methods=default_methods(kb, kb_dir or KB_DIR), episodes=episodes, seed=seed, pool=pool,
            cache_dir=None if no_cache else ENCODER_CACHE_DIR,
            temperature=DEFAULT_TEMPERATURE if temperature is None else temperature,
            aff_mode=aff_mode,  # type: ignore[arg-type]
            energy_form=energy_form,
            threads=threads,
        )
    except (LabelsError, FileNotFoundError) as exc:
        fail(str(exc))
    from craft_e.runtime.evaluation.common import emit_report

    emit_report(report.to_markdown(), report.to_dict(), json_out, markdown,
                lambda msg: err.print(msg, highlight=False, markup=False))


def register_command_modules(modules: list[str] | None = None) -> list[str]:
    """Import each command module and call its ``register(app)``; returns those registered."""
    done: list[str] = []
    for name in COMMAND_MODULES if modules is None else modules:
        module = importlib.import_module(name)
        register = getattr(module, "register", None)
        if callable(register):
            register(app)
            done.append(name)
    return done


os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
REGISTERED_MODULES = register_command_modules()
