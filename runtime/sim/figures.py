"""Pictures of a testbed episode: the paper's qualitative figure and an animated GIF.

The figure has the paper's four panels — the input image, the grasp predictions, the ROIs (green)
and the final grounding (blue) with its explanation path — so a person can see at which stage an
episode went right or wrong. The GIF is rendered by a second, low-resolution camera that sees the
arm, the table and the drop zone; frames are taken every N simulation steps (a step-count clock,
so the same episode gives the same GIF). Matplotlib uses the Agg backend (no display needed).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from ..grasp.geometry import CameraIntrinsics, Grasp2D
from .camera import Camera, render

if TYPE_CHECKING:
    from .pipeline import EpisodeResult

UInt8Image = npt.NDArray[np.uint8]


def overview_camera(width: int = 320, height: int = 240) -> Camera:
    """An oblique view of the arm, the workspace and the drop zone (for the GIF only)."""
    return Camera(intrinsics=CameraIntrinsics.realsense_d435(width, height),
                  eye=(1.05, 0.55, 0.75), target=(0.22, -0.12, 0.05), up=(0.0, 0.0, 1.0))


@dataclass
class FrameRecorder:
    """A ``SimEnv.step_hook`` that renders a frame every ``every`` steps while ``active``."""

    client: int
    every: int = 24
    camera: Camera = field(default_factory=overview_camera)
    active: bool = False
    frames: list[UInt8Image] = field(default_factory=list)

    def snapshot(self) -> None:
        self.frames.append(render(self.client, self.camera).rgb)

    def __call__(self, step: int) -> None:
        if self.active and step % self.every == 0:
            self.snapshot()

    def save(self, path: Path, fps: float = 12.0) -> Path:
        """Write the frames as an endlessly looping GIF (imageio, Pillow plugin)."""
        import imageio.v3 as iio

        if not self.frames:
            raise ValueError("no frames were recorded")
        path.parent.mkdir(parents=True, exist_ok=True)
        iio.imwrite(path, np.stack(self.frames), extension=".gif", duration=1000.0 / fps, loop=0)
        return path


def _rect_polygon(rect: Grasp2D) -> npt.NDArray[np.float64]:
    return rect.corners()


def explanation_lines(result: EpisodeResult, method: str, max_paths: int = 4) -> list[str]:
    """The chosen ROI's energies and its strongest verb -> property -> object paths."""
    outcome = result.outcomes[method]
    chosen = outcome.grounding.chosen
    if chosen is None:
        return ["no ROI could be chosen (none has a usable grasp)"]
    top = chosen.hypotheses[0] if chosen.hypotheses else None
    lines = [f"chosen roi{chosen.index}: most likely '{top.name}' (p={top.probability:.2f})" if top else
             f"chosen roi{chosen.index}",
             f"E={chosen.total:.2f}  E_grasp={chosen.e_grasp:.2f}  E_aff={chosen.e_aff:.2f}  "
             f"E_align={chosen.e_align:.2f}"]
    shown = chosen.paths[0].obj if chosen.paths else None
    if top is not None and shown is not None and shown != top.name:  # the first hypothesis with a path
        p_shown = next((h.probability for h in chosen.hypotheses if h.name == shown), 0.0)
        lines.append(f"E_aff's path: '{shown}' (p={p_shown:.2f}; none for '{top.name}')")
    for path in sorted(chosen.paths, key=lambda q: -(q.w_vp + q.w_po))[:max_paths]:
        records = ",".join(k[:8] for k in path.provenance)
        lines.append(f"{path.verb} -({path.w_vp:.2f})-> {path.prop} -({path.w_po:.2f})-> {path.obj}  [{records}]")
    if not chosen.paths:
        lines.append("no verb -> property -> object path in the KB")
    verdict = "SUCCESS" if outcome.success else f"failed: {outcome.failure.value}"
    lines.append(f"outcome: {verdict}")
    return lines


def plot_episode(result: EpisodeResult, method: str, out: Path, *, title: str | None = None,
                 gripper: str | None = None) -> Path:
    """The four-panel figure of one method's episode, written to ``out`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import patches

    per = result.perception
    rgb = per.obs.rgb
    outcome = result.outcomes[method]
    fig = plt.figure(figsize=(20, 6.8))
    grid = fig.add_gridspec(2, 4, height_ratios=[4.0, 1.3])
    axes = [fig.add_subplot(grid[0, i]) for i in range(4)]
    for ax in axes:
        ax.imshow(rgb)
        ax.set_axis_off()
    axes[0].set_title("input", fontsize=11)

    cmap = matplotlib.colormaps["viridis"]
    for roi in per.rois:
        usable = {id(c) for c in roi.usable}
        for cand in roi.candidates:
            poly = _rect_polygon(cand.rect)
            axes[1].add_patch(patches.Polygon(poly, closed=True, fill=False, edgecolor=cmap(cand.quality),
                                              linewidth=2.5 if id(cand) in usable else 1.0))
    axes[1].set_title(f"grasp predictions ({result.spec.verb}; thick = usable)", fontsize=11)

    for i, roi in enumerate(per.rois):
        x, y, w, h = roi.roi.box_xywh
        axes[2].add_patch(patches.Rectangle((x, y), w, h, fill=False, edgecolor="lime", linewidth=2))
        axes[2].text(x + 2, y - 3, f"roi{i}", color="black", fontsize=8, va="bottom",
                     bbox={"facecolor": "lime", "alpha": 0.8, "pad": 1, "edgecolor": "none"})
    axes[2].set_title(f"ROIs ({len(per.rois)})", fontsize=11)

    ax = axes[3]
    chosen = outcome.grounding.chosen
    if per.target_box is not None:
        tx, ty, tw, th = per.target_box
        ax.add_patch(patches.Rectangle((tx, ty), tw, th, fill=False, edgecolor="white", linestyle="--",
                                       linewidth=1.2))
    if chosen is not None:
        cx, cy, cw, ch = chosen.roi.box_xywh
        ax.add_patch(patches.Rectangle((cx, cy), cw, ch, fill=False, edgecolor="royalblue", linewidth=3))
        if outcome.grasp is not None:
            ax.add_patch(patches.Polygon(_rect_polygon(outcome.grasp.rect), closed=True, fill=False,
                                         edgecolor="cyan", linewidth=2.5))
    ax.set_title(f"grounding: '{result.spec.verb}' ({method}; dashed = target)", fontsize=11)
    text = fig.add_subplot(grid[1, :])
    text.set_axis_off()
    text.text(0.0, 1.0, "\n".join(explanation_lines(result, method)), transform=text.transAxes,
              fontsize=9, va="top", ha="left", family="monospace")
    ok, sentence = verdict(result, method)
    fig.suptitle((title or f"{result.spec.verb}: target {result.spec.target} among "
                  f"{', '.join(result.spec.distractors)}" + (f" (gripper {gripper})" if gripper else ""))
                 + "\n" + sentence, fontsize=12, color="darkgreen" if ok else "firebrick")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


_FAILURE_SENTENCES = {
    "no_target_roi": "perception found no region for the {target}",
    "no_grasp": "the {target}'s region had no usable grasp, so it could not be chosen",
    "ik_failure": "the arm could not reach the grasp on the {target}",
    "missed": "the arm went for the {target} and missed it (the fingers closed on nothing)",
    "lift_failed": "the arm grasped the {target} but lost it while lifting",
    "lifted_other_body": "the arm went for the {target} but lifted another object",
    "slip_during_transport": "the arm lifted the {target} but dropped it on the way",
    "outside_drop_zone": "the arm carried the {target} but it came to rest outside the drop zone",
}


DESCENT_GAP_SHOWN = 0.01  # m: a hand stopped higher than this above its grasp is worth saying


def descent_sentence(gap: float, touching: tuple[str, ...]) -> str:
    """Where the hand stopped on its way down, and on what: why a miss was a miss."""
    where = (f"the hand stopped {100 * gap:.1f} cm above its grasp" if gap > DESCENT_GAP_SHOWN
             else "the hand reached its grasp")
    names = ", ".join(t.replace("_", " ") for t in touching)
    return f"end of the descent: {where}" + (f", touching the {names}" if names else "")


def choice_error_sentence(error: str | None, verb: str, target: str, true_class_roi: int | None) -> str:
    """Why a wrong choice was wrong (a ``choice_errors.ChoiceError``, a str), from re-grounding the episode
    with every region named by the simulator's ground truth: a diagnostic, not robot knowledge."""
    target = target.replace("_", " ")
    named = "with every object named right (the simulator's ground truth; the robot does not have it)"
    if error == "perception":
        return f"why: {named} grounding picks the {target}, so the {target} was not recognised"
    if error == "knowledge":
        return f"why: {named} the KB still prefers another object for '{verb}', or finds none here that affords it"
    if error == "energies":
        other = f"roi{true_class_roi}" if true_class_roi is not None else "another region"
        return (f"why: {named} the KB ranks the {target} first, but the grasp and alignment energies "
                f"put {other} ahead")
    return ""


def verdict(result: EpisodeResult, method: str) -> tuple[bool, str]:
    """(success, one plain sentence saying what happened), for the terminal and the figure.

    Says outright when the episode failed and at which stage, so a demo is never mistaken for
    a success.
    """
    outcome = result.outcomes[method]
    target = result.spec.target.replace("_", " ")
    if outcome.success:
        return True, f"SUCCESS: picked the {target} and put it in the drop zone."
    failure = outcome.failure.value
    if failure == "wrong_object":
        chosen = result.body_assets.get(outcome.chosen_body) if outcome.chosen_body is not None else None
        what = chosen.replace("_", " ") if chosen else f"roi{outcome.chosen_roi}"
        return False, (f"FAILED: '{result.spec.verb}' chose the {what}, not the {target}; "
                       "a wrong choice counts as a failure, so nothing was picked.")
    sentence = _FAILURE_SENTENCES.get(failure, failure).format(target=target)
    return False, f"FAILED: {sentence}."


def describe(result: EpisodeResult, method: str, *, gripper: str | None = None) -> str:
    """The terminal explanation: the grounding's ranking with energies and paths, the outcome,
    and a final verdict line that says plainly whether the episode succeeded."""
    outcome = result.outcomes[method]
    lines = [outcome.grounding.render()]
    per = result.perception
    if outcome.looked:  # the active look ran: the ranking above is the one with both views
        looked = ", ".join(f"roi{i}" for i in outcome.looked)
        lines.append(f"active look: {looked} seen again, closer, by the look camera; the ranking above mixes both views")
    lines.append(f"3D (viable grasp on the target): {per.three_d}"
                 + (f" ({per.three_d_detail})" if per.three_d_detail else ""))
    lines.append(f"Detect (chosen ROI is the target, IoU {outcome.chosen_iou:.2f}): {outcome.detect}")
    pick = outcome.pick
    if outcome.relocation:  # the relocation policy ran and the approach was blocked
        lines.append(f"before the pick: {outcome.relocation}")
    lines.append(f"outcome: {outcome.failure.value}"
                 + (f" ({pick.detail})" if pick is not None and pick.detail else "")
                 + (f", {pick.steps} simulation steps" if pick is not None else "")
                 + (f", wrist look moved the grasp {pick.wrist_shift * 1000:.1f} mm"
                    if pick is not None and pick.wrist_frames else "")
                 + (f", gripper {gripper}" if gripper else ""))
    if pick is not None and pick.descent_gap is not None and (
            pick.descent_gap > DESCENT_GAP_SHOWN or pick.touching):
        lines.append(descent_sentence(pick.descent_gap, pick.touching))
    why = choice_error_sentence(outcome.choice_error, result.spec.verb, result.spec.target, outcome.true_class_roi)
    if why:
        lines.append(why)
    lines.append(verdict(result, method)[1])
    if outcome.retries:  # a retry policy ran after an empty hand (craft sim demo --retries)
        for k, a in enumerate(outcome.retries, 1):
            lines.append(f"retry {k}: chose roi{a.chosen_roi}" if a.chosen_roi is not None else f"retry {k}: no choice")
            lines[-1] += (f" (the target), outcome {a.failure}" if a.detect else f" (not the target), {a.failure}") + (
                f" ({a.pick_detail})" if a.pick_detail else "")
        final = "SUCCESS" if outcome.retries[-1].failure == "success" else "FAILED"
        lines.append(f"with {len(outcome.retries)} retr{'y' if len(outcome.retries) == 1 else 'ies'}: {final} "
                     "(the single-attempt verdict above is what the benchmarks count)")
    return "\n".join(lines)
