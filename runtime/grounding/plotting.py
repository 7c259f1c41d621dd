"""Figures for people: a grounding drawn over its image, with the reasoning path beside it.

Matplotlib with the Agg backend (no display on robots or CI). The left panel colours every ROI by
its total energy (low = green), draws the chosen ROI thick and its chosen grasp, and marks
excluded ROIs dashed grey; the right panel draws the explanation as a small layered graph
verb -> properties -> object, edge labels w_vp and w_po.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from .grounder import Grounding


def _grasp_segment(grasp: Any) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """Endpoints of a planar grasp's closing axis, if the grasp object describes one (a checked
    candidate, ``sim.candidates.GraspCandidate``, through its image rectangle ``rect``)."""
    grasp = getattr(grasp, "rect", grasp)
    center = getattr(grasp, "center_xy", None)
    angle = getattr(grasp, "angle_rad", None)
    width = getattr(grasp, "width_px", None)
    if center is None or angle is None or width is None:
        return None
    dx, dy = np.cos(angle) * width / 2.0, -np.sin(angle) * width / 2.0
    return (center[0] - dx, center[1] - dy), (center[0] + dx, center[1] + dy)


def plot_grounding(image: npt.NDArray[np.uint8], grounding: Grounding, out: Path, *, max_paths: int = 6,
                   title: str | None = None, grasp: Any = None) -> Path:
    """Write the figure to ``out`` (PNG, or any format matplotlib infers from the suffix).
    ``grasp``: the grasp to draw on the chosen region, when not the grounding's own (a relocated
    one, ``frame.choose``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import cm, colors, patches, ticker

    fig, (ax_img, ax_path) = plt.subplots(1, 2, figsize=(12, 5.5), gridspec_kw={"width_ratios": [1.3, 1]})
    ax_img.imshow(image)
    ax_img.set_axis_off()
    totals = [r.total for r in grounding.ranked]
    lo, hi = min(totals, default=0.0), max(totals, default=1.0)
    if hi - lo < 0.05:  # one ROI or near-ties: a readable scale around them, not a 1e-9 range
        lo, hi = (lo + hi) / 2 - 0.25, (lo + hi) / 2 + 0.25
    norm = colors.Normalize(vmin=lo, vmax=hi)
    cmap = matplotlib.colormaps["RdYlGn_r"]
    chosen = grounding.chosen
    for rank, r in enumerate(grounding.ranked, start=1):
        x, y, w, h = r.roi.box_xywh
        best = chosen is not None and r.index == chosen.index
        ax_img.add_patch(patches.Rectangle((x, y), w, h, fill=False, edgecolor=cmap(norm(r.total)),
                                           linewidth=4 if best else 2))
        top = r.hypotheses[0].name if r.hypotheses else "?"
        ax_img.text(x + 2, y + 2, f"#{rank} {r.roi.label or top}  E={r.total:.2f}", va="top", fontsize=8,
                    color="white", bbox={"facecolor": cmap(norm(r.total)), "alpha": 0.8, "pad": 1.5,
                                         "edgecolor": "black" if best else "none"})
        if best:
            seg = _grasp_segment(grasp if grasp is not None else r.grasp)
            if seg is not None:
                ax_img.plot([seg[0][0], seg[1][0]], [seg[0][1], seg[1][1]], color="cyan", linewidth=3)
    for e in grounding.excluded:
        x, y, w, h = e.roi.box_xywh
        ax_img.add_patch(patches.Rectangle((x, y), w, h, fill=False, edgecolor="grey", linestyle="--", linewidth=1.5))
        ax_img.text(x + 2, y + h - 2, f"excluded: {e.reason.split(':')[0]}", fontsize=7, color="grey")
    cbar = fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax_img, fraction=0.035, pad=0.01,
                        label="total energy (lower = better)")
    formatter = cbar.ax.yaxis.get_major_formatter()
    if isinstance(formatter, ticker.ScalarFormatter):
        formatter.set_useOffset(False)  # energies are small numbers; an offset label confuses
    ax_img.set_title(title or f"'{grounding.verb}' — {grounding.kb}", fontsize=10)
    _draw_path(ax_path, grounding, max_paths)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _draw_path(ax: Any, grounding: Grounding, max_paths: int) -> None:
    """verb (left) -> properties (middle) -> object (right), edge labels w_vp / w_po."""
    ax.set_axis_off()
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    best = grounding.chosen
    if best is None:
        ax.text(0.5, 0.5, "no ROI could be chosen", ha="center")
        return
    top = best.hypotheses[0].name if best.hypotheses else "?"
    # the paths end at the most likely hypothesis that has one (``Grounding.render`` says the same):
    # the object box names that one, not the top hypothesis, so the drawn weights are its own
    obj = best.paths[0].obj if best.paths else top
    rank = next((i for i, h in enumerate(best.hypotheses) if h.name == obj), 0)
    p_obj = best.hypotheses[rank].probability if best.hypotheses else 0.0
    who = f"{obj}, p={p_obj:.2f}" + ("" if obj == top else f"; most likely {top}, which has no path")
    paths = sorted(best.paths, key=lambda p: -(p.w_vp + p.w_po))[:max_paths]
    ax.set_title(f"why ROI {best.index} ({who}):\n"
                 f"E_aff={best.e_aff:.2f} E_align={best.e_align:.2f} E_grasp={best.e_grasp:.2f}", fontsize=9)
    box = {"boxstyle": "round", "facecolor": "#eef", "edgecolor": "#88a"}
    verb_label = grounding.verb + (" (open vocab)" if grounding.open_vocab_used else "")
    ax.text(0.08, 0.5, verb_label, ha="center", va="center", fontsize=10, bbox=box)
    ax.text(0.92, 0.5, obj, ha="center", va="center", fontsize=10, bbox={**box, "facecolor": "#efe"})
    if not paths:
        ax.annotate("", xy=(0.85, 0.5), xytext=(0.15, 0.5), arrowprops={"arrowstyle": "->", "color": "grey", "ls": "--"})
        ax.text(0.5, 0.55, "no property path in the KB", ha="center", fontsize=9, color="grey")
        return
    ys = np.linspace(0.9, 0.1, len(paths)) if len(paths) > 1 else np.array([0.5])
    for p, y in zip(paths, ys, strict=True):
        ax.annotate("", xy=(0.36, y), xytext=(0.15, 0.5), arrowprops={"arrowstyle": "->", "lw": 0.5 + 2 * p.w_vp})
        ax.annotate("", xy=(0.84, 0.5), xytext=(0.64, y), arrowprops={"arrowstyle": "->", "lw": 0.5 + 2 * p.w_po})
        ax.text(0.5, y, p.prop, ha="center", va="center", fontsize=9, bbox={**box, "facecolor": "#ffe"})
        label = {"fontsize": 7, "ha": "center", "va": "center", "bbox": {"facecolor": "white", "edgecolor": "none", "pad": 0.5}}
        ax.text(0.15 + 0.7 * 0.21, 0.5 + 0.7 * (y - 0.5), f"{p.w_vp:.2f}", **label)  # on the verb -> prop arrow
        ax.text(0.64 + 0.3 * 0.20, y + 0.3 * (0.5 - y), f"{p.w_po:.2f}", **label)  # on the prop -> object arrow
