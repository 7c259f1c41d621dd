"""Development check on the Zhu et al. (2014) affordance matrix: does E_aff rank the right objects?

For each of the 15 affordances (as verbs) the 62 objects are ranked by E_aff(verb, object) from a
bundle, and the ranking is scored by average precision against the matrix's 0/1 labels. AP is
computed over distinct score thresholds (as scikit-learn does), so tied energies — e.g. objects
no path reaches — are not ordered by an arbitrary tie-break in anyone's favour.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ...schemas.names import normalize_name
from ..grounding.energies import EnergyForm
from ..grounding.grounder import affordance_energy_in_form
from ..kb.bundle import Bundle

#: Column name in the CSV -> the verb used in our vocabularies.
ZHU_AFFORDANCES = {
    "Grasp": "grasp", "Lift": "lift", "Throw": "throw", "Push": "push", "Fix": "fix",
    "Ride": "ride", "Play": "play", "Watch": "watch", "SitOn": "sit on", "Feed": "feed",
    "Row": "row", "PourFrom": "pour from", "LookThrough": "look through",
    "WriteWith": "write with", "TypeOn": "type on",
}  # fmt: skip


@dataclass(frozen=True)
class ZhuMatrix:
    objects: list[str]
    labels: dict[str, npt.NDArray[np.bool_]]  # verb -> [n_objects]


class ZhuMatrixError(ValueError):
    """The Zhu CSV is unreadable or malformed; the message names the file, line and fix."""


def read_zhu_matrix(path: Path) -> ZhuMatrix:
    """Read the CSV (first column a WordNet synset like ``axe.n.01``; one 0/1 column per
    affordance of ``ZHU_AFFORDANCES``); ``ZhuMatrixError`` names what is wrong."""
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            rows = list(csv.reader(handle))
    except UnicodeDecodeError as exc:
        raise ZhuMatrixError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise ZhuMatrixError(f"{path}: cannot read the Zhu matrix ({exc.strerror or exc})") from None
    if not rows:
        raise ZhuMatrixError(f"{path}: empty; expected a header row with the columns "
                             f"{', '.join(ZHU_AFFORDANCES)}")
    header = rows[0]
    missing = [col for col in ZHU_AFFORDANCES if col not in header]
    if missing:
        raise ZhuMatrixError(f"{path}:1: the header lacks the column(s) {', '.join(missing)}")
    columns = {col: header.index(col) for col in ZHU_AFFORDANCES}
    objects: list[str] = []
    body: list[list[str]] = []
    seen: dict[str, int] = {}
    for lineno, row in enumerate(rows[1:], start=2):
        if not row or not row[0]:
            continue
        if len(row) != len(header):
            raise ZhuMatrixError(f"{path}:{lineno}: {len(row)} cells, the header has {len(header)}")
        bad = [f"{col}={row[i]!r}" for col, i in columns.items() if row[i] not in ("0", "1")]
        if bad:
            raise ZhuMatrixError(f"{path}:{lineno}: affordance cells must be 0 or 1, got {', '.join(bad[:3])}")
        name = normalize_name(row[0].split(".")[0])
        if name in seen:
            raise ZhuMatrixError(f"{path}:{lineno}: object {name!r} again (first on line {seen[name]})")
        seen[name] = lineno
        objects.append(name)
        body.append(row)
    if not body:
        raise ZhuMatrixError(f"{path}: no object rows after the header")
    labels = {verb: np.array([row[columns[col]] == "1" for row in body], dtype=bool)
              for col, verb in ZHU_AFFORDANCES.items()}
    return ZhuMatrix(objects, labels)


def average_precision(scores: npt.NDArray[np.float64], positives: npt.NDArray[np.bool_]) -> float:
    """AP = sum_k (R_k - R_{k-1}) P_k over distinct score thresholds, descending."""
    n_pos = int(positives.sum())
    if n_pos == 0:
        return float("nan")
    order = np.argsort(-scores, kind="stable")
    s, y = scores[order], positives[order].astype(np.float64)
    distinct = np.r_[np.nonzero(np.diff(s))[0], len(s) - 1]  # last index of each tie group
    tp = np.cumsum(y)[distinct]
    fp = (distinct + 1) - tp
    precision = tp / (tp + fp)
    recall = tp / n_pos
    recall_prev = np.r_[0.0, recall[:-1]]
    return float(np.sum((recall - recall_prev) * precision))


def evaluate_bundle(
    bundle: Bundle, matrix: ZhuMatrix, form: EnergyForm | None = None
) -> dict[str, float]:
    """AP per affordance for ranking the matrix's objects by -E_aff (missing -> energy 0)."""
    table = affordance_energy_in_form(bundle, form or bundle.manifest.energy.form)  # [V, O]
    result: dict[str, float] = {}
    obj_cols = [bundle.object_index.get(o) for o in matrix.objects]
    for verb, positives in matrix.labels.items():
        row = bundle.verb_index.get(verb)
        energy = np.zeros(len(matrix.objects), dtype=np.float64)
        if row is not None:
            for i, col in enumerate(obj_cols):
                if col is not None:
                    energy[i] = float(table[row, col])
        result[verb] = average_precision(-energy, positives)
    return result


def chance_ap(matrix: ZhuMatrix) -> dict[str, float]:
    """AP of a ranking with every object tied: the positive rate."""
    return {v: float(p.mean()) for v, p in matrix.labels.items()}


def markdown_table(columns: dict[str, dict[str, float]]) -> str:
    """Affordance rows x method columns, with a mean row."""
    names = list(columns)
    verbs = list(ZHU_AFFORDANCES.values())
    lines = ["| affordance | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for verb in verbs:
        lines.append(f"| {verb} | " + " | ".join(f"{columns[n][verb]:.3f}" for n in names) + " |")
    means = [float(np.nanmean([columns[n][v] for v in verbs])) for n in names]
    lines.append("| **mean AP** | " + " | ".join(f"**{m:.3f}**" for m in means) + " |")
    return "\n".join(lines) + "\n"
