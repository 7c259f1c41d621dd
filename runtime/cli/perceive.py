"""``craft perceive``: one RGB-D frame to the object and grasp for a verb, as the robot perceives.

Thin: the files are read and checked here, then ``runtime/frame.py`` runs the testbed robot's
own perception (segmentation, one grasp-network pass, the crops' embeddings, the size and cavity
cues, the finger checks) and grounding on the frame. ``craft ground`` is the other way in: the
caller's own boxes, no depth cues.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from .common import (
    EnergyFormOpt,
    checked_output_file,
    checked_plot_file,
    fail,
    grounding_settings,
    note,
    out,
    read_some_names,
)
from .episodes import GripperOpt

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from ..grasp.geometry import CameraIntrinsics
    from ..perception.workspace import Workspace

#: what a ``--camera`` file holds (the pose is optional)
CAMERA_KEYS = ("fx", "fy", "cx", "cy")


def with_option(message: str) -> str:
    """A ``frame`` message as the command's user reads it: its hint names the option."""
    return message.replace("a depth scale of 0.001", "--depth-scale 0.001")


def read_colour(path: Path) -> npt.NDArray[np.uint8]:
    """The colour image as H x W x 3 uint8, or exit 2 naming the file: one beyond
    ``frame.MAX_FRAME_PIXELS`` (judged from its header, before decoding), or a 16-bit or float
    single-channel image, which converting to RGB clips to white (a depth PNG given as
    ``--rgb`` was perceived into a different grasp, silently)."""
    import numpy as np
    from PIL import Image, UnidentifiedImageError

    from ..frame import MAX_FRAME_PIXELS

    if path.is_dir() or not path.is_file():
        fail(f"{path}: {'is a folder; give an image file' if path.is_dir() else 'image not found'} (png/jpg)")
    try:
        with Image.open(path) as img:
            if img.width * img.height > MAX_FRAME_PIXELS:
                fail(f"{path}: the image is {img.width}x{img.height} pixels; at most {MAX_FRAME_PIXELS} are perceived "
                     "(downscale both images, and the camera's fx, fy, cx, cy with them)")
            if img.mode.startswith("I") or img.mode == "F":
                fail(f"{path}: a single-channel {img.mode} image, not 8-bit colour (is it the depth image?); give "
                     "the colour image (8-bit RGB png/jpg) as --rgb")
            return np.asarray(img.convert("RGB"), dtype=np.uint8)
    except Image.DecompressionBombError as exc:
        fail(f"{path}: too large to decode ({str(exc).rstrip('.')}); downscale it")
    except (OSError, UnidentifiedImageError) as exc:
        fail(f"{path}: not a readable image ({exc})")


def read_depth(path: Path, scale: float | None) -> npt.NDArray[np.float32]:
    """A depth image in metres from ``.npy`` (H x W numbers) or a 16-bit ``.png``
    (``frame.decode_depth``); integer depth (a RealSense's raw millimetres) needs ``scale``,
    metres per unit. Every problem exits 2 naming the file."""
    from ..frame import MAX_FRAME_PIXELS, FrameError, decode_depth

    if path.is_dir():
        fail(f"{path}: is a folder; give a depth image (.npy, or a 16-bit .png)")
    if not path.is_file():
        fail(f"{path}: depth image not found")
    try:
        return decode_depth(path.read_bytes(), scale, MAX_FRAME_PIXELS)
    except OSError as exc:
        fail(f"{path}: not readable ({exc})")
    except FrameError as exc:
        fail(f"{path}: {with_option(str(exc))}")


def read_mask(path: Path, width: int, height: int) -> npt.NDArray[np.bool_]:
    """The pixels to perceive from a ``--mask`` image of the frame's size (non-zero: perceive,
    zero: ignore), or exit 2 naming the file."""
    import numpy as np
    from PIL import Image, UnidentifiedImageError

    from ..perception.workspace import mask_from_image

    if path.is_dir() or not path.is_file():
        fail(f"{path}: {'is a folder; give a mask image file' if path.is_dir() else 'mask image not found'} (png)")
    try:
        with Image.open(path) as img:
            if img.format == "JPEG":
                fail(f"{path}: a JPEG mask; save it as PNG (JPEG's compression leaves non-zero pixels beside the "
                     "mask's edges, which would be perceived)")
            if (img.width, img.height) != (width, height):
                fail(f"{path}: the mask is {img.width}x{img.height} pixels, the frame {width}x{height}: give a mask "
                     "of the frame's size (non-zero: perceive, zero: ignore)")
            # a palette's indices and an alpha channel are not what the mask shows: read its colours
            image = np.asarray(img if img.mode in ("1", "L", "I", "I;16", "F", "RGB") else img.convert("RGB"))
    except Image.DecompressionBombError as exc:
        fail(f"{path}: too large to decode ({str(exc).rstrip('.')})")
    except (OSError, ValueError, UnidentifiedImageError) as exc:
        fail(f"{path}: not a readable image ({exc})")
    try:
        return mask_from_image(image)
    except ValueError as exc:
        fail(f"{path}: {exc}")


def parse_workspace(text: str | None) -> Workspace | None:
    """``--workspace``'s box, or exit 2 saying what is wrong with it."""
    if text is None:
        return None
    from ..perception.workspace import Workspace

    try:
        return Workspace.parse(text)
    except ValueError as exc:
        fail(f"--workspace {exc}")


def read_camera(path: Path | None, width: int, height: int) -> tuple[CameraIntrinsics, list[list[float]] | None]:
    """(the intrinsics, the optional ``cam_to_world``) from a ``--camera`` JSON file, or a
    RealSense-D435-like model at the image's size when none is given (with a note)."""
    from ..grasp.geometry import CameraIntrinsics

    if path is None:
        note(f"no --camera: assuming RealSense-D435-like intrinsics at {width}x{height} (fx = fy = "
             f"{615.0 * width / 640.0:g}); sizes are only as right as that guess")
        return CameraIntrinsics.realsense_d435(width, height), None
    from ...files import read_json

    try:
        data = read_json(path, f"camera file (JSON: {', '.join(CAMERA_KEYS)}, optional cam_to_world)",
                         unique_keys=True)
    except ValueError as exc:
        fail(str(exc))
    if not isinstance(data, dict):
        fail(f"{path}: the camera file must be a JSON object with {', '.join(CAMERA_KEYS)}")
    missing = [k for k in CAMERA_KEYS if k not in data]
    if missing:
        fail(f"{path}: the camera file lacks {', '.join(missing)} (pixels, the colour image's pinhole model)")
    values: dict[str, float] = {}
    for k in CAMERA_KEYS:
        v = data[k]
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            fail(f"{path}: {k} must be a finite number, got {v!r}")
        values[k] = float(v)
    if values["fx"] <= 0 or values["fy"] <= 0:
        fail(f"{path}: fx and fy must be positive (pixels), got {values['fx']:g}, {values['fy']:g}")
    for k in ("width", "height"):
        if k in data and (isinstance(data[k], bool) or not isinstance(data[k], int | float)):
            fail(f"{path}: {k} must be a number of pixels, got {data[k]!r}")
        if k in data and data[k] != (width if k == "width" else height):
            fail(f"{path}: {k} {data[k]!r} is not the image's {width if k == 'width' else height}")
    pose = data.get("cam_to_world")
    if pose is not None and not (isinstance(pose, list) and len(pose) == 4
                                 and all(isinstance(row, list) and len(row) == 4 for row in pose)
                                 and all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                                         for row in pose for v in row)):
        fail(f"{path}: cam_to_world must be a 4 x 4 list of finite numbers (camera frame -> world, z up), "
             "or left out to measure heights from the table plane")
    intrinsics = CameraIntrinsics(width, height, values["fx"], values["fy"], values["cx"], values["cy"])
    return intrinsics, pose


def check_unique_names(path: Path, names: list[str]) -> None:
    """Exit 2 naming the file when it lists an object twice, as the grounder would read the names
    (``Grounder._object_name``: normalised, so ``Knife`` and ``knife`` are one); the grounder's own
    refusal came after the bundle loaded, naming neither the file nor the fix."""
    from ...schemas.names import normalize_name

    def key(raw: str) -> str:
        try:
            return normalize_name(raw)
        except ValueError:
            return raw.strip().lower()

    keys = [key(n) for n in names]
    twice = sorted({k for k in keys if keys.count(k) > 1})
    if twice:
        fail(f"--vocab {path}: lists {', '.join(twice)} more than once; keep one line for each object")


def perceive(
    kb: Annotated[Path, typer.Option(help="Bundle folder (or signed .craft file with --trusted-key).")],
    verb: Annotated[str, typer.Option(help="The action, e.g. cut.")],
    rgb: Annotated[Path, typer.Option(help="Colour image (png/jpg), registered to the depth image.")],
    depth: Annotated[Path, typer.Option(help="Depth image: .npy of metres, or a 16-bit .png with --depth-scale.")],
    camera: Annotated[Path | None, typer.Option(help="JSON with fx, fy, cx, cy (pixels) and optionally cam_to_world "
                                                     "(4 x 4, z up); default: a RealSense-D435-like model, "
                                                     "heights from the table plane.")] = None,
    depth_scale: Annotated[float | None, typer.Option(help="Metres per depth unit (0.001 for millimetres); "
                                                           "default: 1 for float depth.")] = None,
    vocab: Annotated[Path | None, typer.Option(help="The objects the robot may meet, one per line (default: the "
                                                    "KB's); the size cue needs a typical size for each, e.g. "
                                                    "artifacts/vocab/sim_objects.txt.")] = None,
    grasp: Annotated[str, typer.Option(help="Grasp network: grconvnet | ggcnn | ggcnn2.")] = "grconvnet",
    gripper: GripperOpt = "panda",
    energy_form: EnergyFormOpt = None,
    open_vocab: Annotated[bool, typer.Option(help="Accept verbs the KB lacks and free requests (\"dig a hole\"): "
                                                  "mapped to properties of similar verbs and properties, or "
                                                  "abstained on.")] = False,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the grounding, the regions' measurements "
                                                                 "and the grasp as JSON.",
                                                  callback=checked_output_file)] = None,
    plot: Annotated[Path | None, typer.Option(help="Write a figure (ROIs by energy + reasoning path).",
                                              callback=checked_plot_file)] = None,
    trusted_key: Annotated[list[Path] | None, typer.Option("--trusted-key", help="Signer key for a .craft package.")] = None,
    threads: Annotated[int, typer.Option(min=1, help="Torch threads of the two networks.")] = 1,
    workspace: Annotated[str | None, typer.Option(help="x_min,x_max,y_min,y_max[,z_max] (metres, in the --camera "
                                                       "file's cam_to_world frame): perceive only what stands inside "
                                                       "this box of the table, below z_max if given (the arm's "
                                                       "links), e.g. 0.14,0.61,-0.30,0.30,0.30.")] = None,
    mask: Annotated[Path | None, typer.Option(help="An image of the frame's size: non-zero pixels are perceived, "
                                                   "zero ones ignored (the robot's own body, the floor).")] = None,
) -> None:
    """Perceive one RGB-D frame as the robot does and choose the object and grasp for a verb."""
    from ...schemas.names import MAX_NAME_CHARS, shown
    from ..frame import MAX_DEPTH_SCALE, FrameError, FramePerceiver, frame_keep, frame_observation
    from ..grasp.predict import BACKENDS
    from ..kb.bundle import BundleError, load_bundle
    from ..sim.pipeline import NETWORK_SOURCES

    if depth_scale is not None and not (math.isfinite(depth_scale) and 0 < depth_scale <= MAX_DEPTH_SCALE):
        fail(f"--depth-scale {depth_scale:g}: metres per depth unit must be a positive number up to "
             f"{MAX_DEPTH_SCALE:g}, e.g. 0.001 for mm")
    if len(verb) > MAX_NAME_CHARS:
        fail(f"--verb {shown(verb)} is longer than {MAX_NAME_CHARS} characters")
    if not verb.strip():
        fail("--verb is blank; name the action, e.g. --verb cut")
    if grasp not in NETWORK_SOURCES or grasp not in BACKENDS:
        fail(f"--grasp {grasp!r}: choose one of {', '.join(s for s in NETWORK_SOURCES if s in BACKENDS)}")
    box = parse_workspace(workspace)
    vocabulary = read_some_names(vocab, "vocabulary", "--vocab") if vocab is not None else None
    if vocab is not None and vocabulary is not None:
        check_unique_names(vocab, vocabulary)
    settings = grounding_settings(energy_form=energy_form, vocabulary=vocabulary, open_vocab=open_vocab)
    from ..sim.episode import sim_configs

    try:
        sim_configs(gripper, wrist_look=False)  # an unknown hand is named before anything loads
    except ValueError as exc:
        fail(str(exc))
    colour = read_colour(rgb)
    depth_m = read_depth(depth, depth_scale)
    if depth_m.shape != colour.shape[:2]:
        fail(f"{depth}: depth is {depth_m.shape[1]}x{depth_m.shape[0]} pixels, {rgb} is "
             f"{colour.shape[1]}x{colour.shape[0]}: give both from one registered frame")
    intrinsics, pose = read_camera(camera, colour.shape[1], colour.shape[0])
    keep = read_mask(mask, colour.shape[1], colour.shape[0]) if mask is not None else None
    if box is not None and pose is None:
        fail(f"--workspace {workspace} is a box in the world frame of the camera's pose: give a --camera file with "
             "cam_to_world, or limit the frame with --mask instead")
    try:  # the frame's own checks (units, camera model, pose, a table), before anything loads
        observed, _, from_table = frame_observation(colour, depth_m, intrinsics, pose)
        frame_keep(observed, from_table, keep, box)
    except FrameError as exc:
        source = {"rgb": rgb, "camera": camera, "cam_to_world": camera, "mask": mask,
                  "workspace": f"--workspace {workspace}"}.get(exc.part, depth)
        fail(f"{source if source is not None else 'the default camera model'}: {with_option(str(exc))}")
    try:
        bundle = load_bundle(kb, trusted_keys=[str(k) for k in trusted_key] if trusted_key else None)
    except BundleError as exc:
        fail(str(exc))
    try:
        perceiver = FramePerceiver(bundle, gripper=gripper, grasp=grasp, threads=threads, settings=settings,
                                   workspace=box)
        found = perceiver.ground(verb, colour, depth_m, intrinsics, pose, mask=keep)
    except (FrameError, ValueError) as exc:  # UnknownVerbError and a cue's refusal included
        fail(str(exc))
    grounder = perceiver.grounder
    result = found.grounding
    result.notes.append("no robot model here: the grasp is checked against the open hand and the hand's "
                        "approach against the depth frame, but the arm is not planned (no IK, no check of its "
                        "links); the testbed's `craft sim demo` does both")
    if found.pose_from_table:
        result.notes.append("no camera pose: heights are measured from the table plane fitted in this frame")
    if box is not None or keep is not None:
        limits = " and ".join(x for x in (f"the workspace ({workspace})" if box is not None else "",
                                          f"the mask ({mask})" if keep is not None else "") if x)
        result.notes.append(f"regions only within {limits}; the hand's approach is still checked against the "
                            "whole frame")
    if not grounder.size_cue_active:
        result.notes.append("the size cue is off: some vocabulary objects have no typical size in the bundle "
                            "(--vocab with names that all have one turns it on)")
    out.print(result.render(), highlight=False, markup=False, soft_wrap=True)
    summary = found.grasp_dict()
    if found.relocation:
        out.print(f"before the pick: {found.relocation}", highlight=False, markup=False, soft_wrap=True)
    if summary is not None:
        out.print(f"grasp: centre ({summary['center_px'][0]:g}, {summary['center_px'][1]:g}) px, opening "
                  f"{100 * summary['opening_m']:.1f} cm, yaw {summary['yaw_deg']:g} deg, at "
                  f"({', '.join(f'{v:.3f}' for v in summary['position_m'])}) m"
                  f"{' (the antipodal fallback)' if summary['fallback'] else ''}",
                  highlight=False, markup=False, soft_wrap=True)
    if json_out is not None:
        data = {"rgb": str(rgb), "depth": str(depth), "image_encoder": perceiver.encoder.id, **result.to_dict(),
                **found.frame_dict(), "workspace": None if box is None else box.bounds(),
                "mask": None if mask is None else str(mask)}
        from ...files import atomic_write_bytes

        atomic_write_bytes(json_out, (json.dumps(data, indent=1) + "\n").encode())
        note(f"wrote {json_out}")
    if plot is not None:
        from ..grounding.plotting import plot_grounding

        plot_grounding(colour, result, plot, grasp=found.grasp)
        note(f"wrote {plot}")
