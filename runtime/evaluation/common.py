"""Shared pieces of the evaluation harnesses: ranking metrics, image-embedding cache, result tables.

Every harness reports methods side by side in one table. A method that cannot run (its bundle
is missing, say) is reported as *skipped with the reason*, never silently left out, so a table
with a missing row cannot be mistaken for a complete one.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ...files import sha256_file
from ...paths import artifacts_hint

FloatArray = npt.NDArray[np.float32]
BoolArray = npt.NDArray[np.bool_]


# ---------------------------------------------------------------------------------------------
# metrics over episodes: ``energy`` [E, K] (lower = better), ``relevant`` [E, K] bool


def rank_order(energy: npt.NDArray[Any]) -> npt.NDArray[np.intp]:
    """Candidate indices best first, ``[E, K]``; ties keep candidate order (stable)."""
    return np.argsort(energy, axis=1, kind="stable")


def topk_accuracy(energy: npt.NDArray[Any], relevant: BoolArray, k: int) -> FloatArray:
    """``[E]`` 1.0 where a relevant candidate is among the ``k`` lowest energies."""
    order = rank_order(energy)[:, :k]  # [E, k]
    hit: FloatArray = np.asarray(np.take_along_axis(relevant, order, axis=1).any(axis=1), dtype=np.float32)
    return hit


def reciprocal_rank(energy: npt.NDArray[Any], relevant: BoolArray) -> FloatArray:
    """``[E]`` 1 / rank of the first relevant candidate (0 if none)."""
    rel_sorted = np.take_along_axis(relevant, rank_order(energy), axis=1)  # [E, K]
    first = np.argmax(rel_sorted, axis=1)  # [E]
    has = rel_sorted.any(axis=1)
    return np.where(has, 1.0 / (first + 1.0), 0.0).astype(np.float32)


def ndcg(energy: npt.NDArray[Any], relevant: BoolArray) -> FloatArray:
    """``[E]`` nDCG with binary relevance over the full ranking of the K candidates."""
    k = relevant.shape[1]
    discount = 1.0 / np.log2(np.arange(2, k + 2))  # [K]
    rel_sorted = np.take_along_axis(relevant, rank_order(energy), axis=1).astype(np.float64)
    dcg = rel_sorted @ discount  # [E]
    n_rel = relevant.sum(axis=1)  # [E]
    ideal = np.cumsum(discount)[np.maximum(n_rel - 1, 0)]  # [E]
    return np.where(n_rel > 0, dcg / ideal, 0.0).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# image embeddings, computed once per image and encoder


class ImageEmbeddingCache:
    """Embeddings per (encoder id, image file sha256): in memory, optionally on disk.

    On disk it is one safetensors file per encoder under ``folder`` (tensor name = image sha256),
    so re-running an evaluation costs no forward pass and nothing is unpickled.
    """

    def __init__(self, encoder_id: str, folder: Path | None) -> None:
        self.encoder_id = encoder_id
        self.path = None if folder is None else folder / f"images.{_safe(encoder_id)}.safetensors"
        self._mem: dict[str, FloatArray] = {}
        self.hits = 0
        self.computed = 0
        if self.path is not None and self.path.is_file():
            from safetensors import safe_open
            from safetensors.numpy import load_file

            with safe_open(str(self.path), framework="numpy") as handle:
                meta = handle.metadata() or {}
            if meta.get("encoder") == encoder_id:
                self._mem.update({k: np.asarray(v, np.float32) for k, v in load_file(str(self.path)).items()})

    def embed_files(
        self, paths: Sequence[Path], embed: Callable[[list[Path]], FloatArray]
    ) -> FloatArray:
        """``[N, d]`` embeddings of ``paths``; ``embed`` is called once for the missing ones."""
        keys = [sha256_file(p) for p in paths]
        unique = list(dict.fromkeys(keys))
        todo = [k for k in unique if k not in self._mem]
        if todo:
            first_path = {k: p for k, p in zip(keys, paths, strict=True)}
            vectors = embed([first_path[k] for k in todo])  # [M, d]
            for k, vec in zip(todo, vectors, strict=True):
                self._mem[k] = np.asarray(vec, dtype=np.float32)
            self.computed += len(todo)
            self._save()
        self.hits += len(unique) - len(todo)
        return np.stack([self._mem[k] for k in keys]).astype(np.float32)

    def _save(self) -> None:
        if self.path is None:
            return
        from safetensors.numpy import save_file

        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".tmp")
        save_file(dict(sorted(self._mem.items())), str(tmp), metadata={"encoder": self.encoder_id})
        tmp.replace(self.path)


def _safe(text: str) -> str:
    keep = "".join(c if c.isalnum() or c in "-." else "_" for c in text)
    return f"{keep[:80]}-{hashlib.sha256(text.encode()).hexdigest()[:10]}"


# ---------------------------------------------------------------------------------------------
# results


@dataclass
class MethodResult:
    """One row of a results table: metric name -> value in [0, 1], plus per-verb details."""

    name: str
    description: str
    metrics: dict[str, float]
    per_verb: dict[str, dict[str, float]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class SkippedMethod:
    name: str
    reason: str


def markdown_table(results: Sequence[MethodResult], skipped: Sequence[SkippedMethod],
                   columns: Sequence[tuple[str, str]]) -> str:
    """Methods x metrics in percent (as the paper reports them), then the skipped methods."""
    head = "| Method | " + " | ".join(label for _, label in columns) + " |"
    rule = "|---|" + "---:|" * len(columns)
    rows = [head, rule]
    for r in results:
        cells = [f"{100 * r.metrics[key]:.2f}" if key in r.metrics else "–" for key, _ in columns]
        rows.append(f"| {r.name} | " + " | ".join(cells) + " |")
    for s in skipped:
        rows.append(f"| {s.name} | " + " | ".join("skipped" for _ in columns) + " |")
    out = "\n".join(rows) + "\n"
    if skipped:
        out += "\n" + "\n".join(f"- **{s.name}** skipped: {s.reason}" for s in skipped) + "\n"
    notes = [(r.name, n) for r in results for n in r.notes]
    if notes:
        out += "\n" + "\n".join(f"- {name}: {n}" for name, n in notes) + "\n"
    return out


def write_json(path: Path, data: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n", encoding="utf-8")


def read_name_list(path: Path) -> list[str]:
    """Names from a text file, one per line; blank lines and ``#`` comment lines are skipped,
    and a gloss after a tab (``name<TAB>gloss``, as in the compiler's vocabularies) is dropped.

    Raises ``OSError`` (the caller names the option the file came from)."""
    return [
        ln.split("\t", 1)[0].strip()
        for ln in path.read_text(encoding="utf-8").splitlines()
        if ln.split("\t", 1)[0].strip() and not ln.startswith("#")
    ]


def read_artifact_names(path: Path, what: str) -> list[str]:
    """:func:`read_name_list` of a file the artifacts folder ships (a vocabulary), or a
    ``FileNotFoundError`` that names it and, when it was sought under the default folder, why
    it may not be there (``paths.artifacts_hint``)."""
    try:
        return read_name_list(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: {what} is missing{artifacts_hint(path)}") from None


#: The vocabulary whose glosses every evaluated method reads ``p(o | r)``'s names in
#: (``grounding/senses.py``): the objects file the default KBs are built from
SENSES_FILE = "default_objects.txt"


def read_senses(path: Path) -> dict[str, str]:
    """``name -> gloss`` from a vocabulary file's ``name<TAB>gloss`` lines (names without a gloss,
    blank and ``#`` lines are skipped); names normalized as the grounder's vocabulary is.

    Raises ``OSError`` (the caller names the file)."""
    from ...schemas.names import normalize_name

    senses: dict[str, str] = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        name, _, gloss = line.partition("\t")
        if line.startswith("#") or not name.strip() or not gloss.strip():
            continue
        try:
            key = normalize_name(name)
        except ValueError:
            key = name.strip().lower()
        senses[key] = gloss.strip()
    return senses


def vocabulary_senses() -> dict[str, str]:
    """The glosses of the shipped vocabulary (``SENSES_FILE``), which every method of an
    evaluation reads its names in, so that perception is the same for all of them (as in the
    paper's comparison); a missing file is a ``FileNotFoundError`` naming it."""
    from ...paths import VOCAB_DIR

    path = VOCAB_DIR / SENSES_FILE
    try:
        return read_senses(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: the vocabulary's glosses are missing{artifacts_hint(path)}; restore it, "
                                "or pass --sense-weight 0 to read the names alone") from None


def emit_report(
    table: str,
    data: dict[str, Any],
    json_out: Path | None,
    markdown: Path | None,
    log: Callable[[str], None],
) -> None:
    """What every ``craft eval`` command does with its result: the Markdown table on stdout,
    and optionally the JSON and the table written to files (``log`` says where)."""
    import sys

    sys.stdout.write(table)
    writes: list[tuple[Path | None, Callable[[Path], None]]] = [
        (json_out, lambda p: write_json(p, data)), (markdown, lambda p: _write_markdown(p, table))]
    for path, write in writes:
        if path is None:
            continue
        try:
            write(path)
        except OSError as exc:  # checked up front for what can be; a mount, a race, a full disk cannot
            raise ReportWriteError(
                f"{path}: cannot write it ({exc.strerror or exc}); the table above is the whole result — "
                "give another path to keep it as a file") from None
        log(f"wrote {path}")


class ReportWriteError(ValueError):
    """An evaluation's output file could not be written; the message names it (the CLI's exit 2)."""


def _write_markdown(path: Path, table: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(table, encoding="utf-8")


def verb_object_lists(
    path: Path, raw: object, error: type[Exception], why_objects: str
) -> list[tuple[str, str, list[str]]]:
    """``(key, verb, objects)`` of a ``{"verb": ["object", ...]}`` labels document (keys starting
    with ``_`` are metadata, skipped): the key as written, its normalized verb, its object names.

    Shared by ``craft eval imagenet`` and ``craft eval kb``, so both refuse what they would
    misread (``error``, naming ``path``): a document that is no object, a blank verb, two keys
    naming one verb (``"carry"`` and ``"CARRY"``: the second list silently replaced the first), a
    value that is no list of names, and a verb with no objects (``why_objects`` says what that
    would break in the caller's protocol)."""
    from ..grounding.grounder import normalize_verb_name

    if not isinstance(raw, dict):
        raise error(f'{path}: expected an object {{"verb": ["object", ...]}}')
    out: list[tuple[str, str, list[str]]] = []
    spelled: dict[str, str] = {}  # normalized verb -> the key that named it first
    for key, objects in raw.items():
        if str(key).startswith("_"):
            continue
        verb = normalize_verb_name(key)
        if not verb:
            raise error(f"{path}: the verb name {key!r} is blank; name the action, e.g. \"cut\"")
        if verb in spelled:
            raise error(f"{path}: {spelled[verb]!r} and {key!r} name the same verb {verb!r}; "
                        "merge their objects under one key")
        spelled[verb] = key
        if not isinstance(objects, list) or not all(isinstance(o, str) for o in objects):
            raise error(f"{path}: {key!r}: expected a list of object names")
        if not objects:
            raise error(f"{path}: {key!r} lists no objects; {why_objects} (or drop the verb)")
        out.append((str(key), verb, objects))
    return out

