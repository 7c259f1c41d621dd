"""Why grounding chose a wrong region: perception, knowledge, or the balance of the energies.

A diagnostic of the evaluation, never part of a choice: it re-grounds an episode with every
region named by the simulator's ground truth, which a robot does not have. Why a module of its
own: it is the one place a grounder runs on ground-truth classes, so it is easy to see that no
choice of the robot goes through it; the episode (``pipeline.run_episode``) only records its
verdict.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from ..grounding.grounder import Grounder
from .perceive import ScenePerception


class ChoiceError(StrEnum):
    """Why grounding chose a wrong region (``wrong_object`` episodes only).

    The episode is re-grounded with ``p(o | r)`` set to each ROI's true class (one-hot on the
    plain name of the body its mask covers most; ROIs over no body keep their perceived ``p``),
    everything else unchanged: a wrong choice that this fixes is a *perception* error (the
    object was not recognised). One it does not fix is a *knowledge* error when, with every
    object named right, the KB's E_aff ranks another usable ROI strictly ahead of the target (or
    finds nothing in the scene affordant), and an *energies* error when the KB ranks the target
    first (ties included) but its grasp and alignment energies move another ROI ahead: the
    knowledge was right, the balance of the paper's three energies was not.
    """

    PERCEPTION = "perception"
    KNOWLEDGE = "knowledge"
    ENERGIES = "energies"


def true_class_probabilities(
    grounder: Grounder, perceived: npt.NDArray[np.float32], perception: ScenePerception,
    body_names: Mapping[int, str],
) -> npt.NDArray[np.float32]:
    """``p(o | r)`` ``[N, O]`` with each ROI's row one-hot on its true class (see
    ``ChoiceError``); rows of ROIs over no scene body, or whose name is not in the grounder's
    vocabulary, stay as perceived."""
    from ...schemas.names import normalize_name

    index = {name: j for j, name in enumerate(grounder.vocabulary)}
    p_true = np.array(perceived, dtype=np.float32, copy=True)
    for n, r in enumerate(perception.rois):
        name = body_names.get(r.body) if r.body is not None else None
        if name is None:
            continue
        try:
            j = index.get(name, index.get(normalize_name(name), -1))
        except ValueError:
            j = -1
        if j >= 0:
            p_true[n] = 0.0
            p_true[n, j] = 1.0
    return p_true


@dataclass(frozen=True)
class TrueClassGrounding:
    """The episode re-grounded with ``p(o | r)`` set to the true classes (``ChoiceError``)."""

    roi: int | None  # the ROI chosen; None if no ROI is usable
    # the usable ROIs whose E_aff alone is the lowest (ties: all); empty when that lowest is 0
    kb_best: tuple[int, ...] = ()


#: E_aff values this close count as a tie (float32 sums of the same weights in another order)
E_AFF_TIE = 1e-6


def true_class_grounding(
    grounder: Grounder, verb: str, perception: ScenePerception, body_names: Mapping[int, str]
) -> TrueClassGrounding:
    """What ``grounder`` chooses when ``p(o | r)`` is the true class, and which ROIs its E_aff
    alone ranks first.

    Follows ``Grounder.ground``: ROIs without a grasp scoring above 0 are excluded, each ROI's
    best grasp gives ``E_grasp``, the lowest total energy wins (stable ties).
    """
    usable = [i for i, r in enumerate(perception.rois)
              if r.usable and max(c.quality for c in r.usable) > 0.0]
    if not usable:
        return TrueClassGrounding(None)
    emb = np.stack([perception.rois[i].embedding for i in usable])  # [N, d]
    gmax = np.array([max(c.quality for c in perception.rois[i].usable) for i in usable], np.float32)
    perceived = grounder.energies(verb, emb, gmax).p_obj  # [N, O]
    subset = ScenePerception(perception.obs, tuple(perception.rois[i] for i in usable),
                             perception.target_body, perception.target_box, None, False, "", perception.raised)
    p_true = true_class_probabilities(grounder, perceived, subset, body_names)
    terms = grounder.energies(verb, emb, gmax, p_obj=p_true)
    e_aff = np.asarray(terms.e_aff, dtype=np.float64)
    low = float(e_aff.min())
    # a KB that finds nothing in the scene affordant (every E_aff 0) ranks no ROI first
    best = tuple(usable[k] for k in np.flatnonzero(e_aff <= low + E_AFF_TIE).tolist()) if low < -E_AFF_TIE else ()
    return TrueClassGrounding(usable[int(np.argsort(terms.total, kind="stable")[0])], best)


def true_class_choice(
    grounder: Grounder, verb: str, perception: ScenePerception, body_names: Mapping[int, str]
) -> int | None:
    """The ROI ``grounder`` chooses when ``p(o | r)`` is the true class; None if none is usable."""
    return true_class_grounding(grounder, verb, perception, body_names).roi


def choice_error(perception: ScenePerception, true_class: TrueClassGrounding, detect_iou: float) -> ChoiceError:
    """Why a ``wrong_object`` choice was wrong (see ``ChoiceError``)."""
    def is_target(i: int) -> bool:
        return perception.target_box is not None and perception.rois[i].target_iou >= detect_iou

    if true_class.roi is not None and is_target(true_class.roi):
        return ChoiceError.PERCEPTION
    return ChoiceError.ENERGIES if any(is_target(i) for i in true_class.kb_best) else ChoiceError.KNOWLEDGE
