"""``craft eval compare``: did a change help, episode by episode?

Two runs of one benchmark (before and after a change: a KB version, a pick setting, a cue), or
two methods of one run, compared on the episodes they share. Each side's rate comes with its
Wilson 95 % interval, and the comparison with the episodes it gained and lost and McNemar's exact
test on those.

Why paired. The two sides see the same scenes, so the scene-to-scene spread that makes a 105-
episode rate uncertain by about ±9 points (the interval of each rate alone) cancels: what is left
is whether the gained episodes outnumber the lost ones by more than a coin flip per changed
episode would. A change that moves 3 episodes up and none down is p = 0.25, not a finding; the
session notes' "+2, no losses" counts, computed by hand from two JSON files until this command,
now come from one command anyone can re-run.

Reads the JSON that ``craft eval sim``, ``craft eval pickability`` and ``craft eval static`` write
(``--json``): every episode's record, per method. Pairs are episodes with the same id and, where
the records carry it, the same scene seed; runs of different ``--seed`` or labels share no scene
and are refused rather than compared.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, get_args

Metric = Literal["success", "detect"]
METRICS: tuple[Metric, ...] = get_args(Metric)
#: what ``success`` is called in each benchmark's own tables
SUCCESS_NAMES = {"sim": "Grasp Rate", "pickability": "picked", "static": "accuracy"}
DEFAULT_STATIC_VIEW = "clean:grconvnet/predicted"  # the static protocol's full pipeline, no noise
CONFIDENCE = 0.95
#: changed episodes listed per comparison in the Markdown (the JSON lists every one)
LISTED = 12
#: ``--fail-on-loss``: a side that lost more episodes than it gained, with McNemar p under this
LOSS_ALPHA = 0.05


class CompareError(ValueError):
    """A run that cannot be read or compared; the message names the file, the record and the fix."""


@dataclass(frozen=True)
class EpisodeOutcome:
    """One method on one episode: what ``--metric`` reads, and the outcome class for the lists."""

    success: bool
    detect: bool
    outcome: str  # the failure class ("success", "missed", ...), or "success"/"wrong" where none

    def value(self, metric: Metric) -> bool:
        return self.success if metric == "success" else self.detect


@dataclass(frozen=True)
class Run:
    """One benchmark JSON, as the comparison reads it."""

    path: Path
    kind: str  # "sim" | "pickability" | "static"
    config: Mapping[str, Any]
    methods: tuple[str, ...]  # in the file's order
    outcomes: Mapping[str, Mapping[str, EpisodeOutcome]]  # episode id -> method -> outcome
    scene_seeds: Mapping[str, int | None]  # episode id -> its scene seed, where recorded
    view: str | None = None  # static only: "LEVEL:GRASP/ROIS"


def _kind(benchmark: object, path: Path) -> str:
    text = benchmark if isinstance(benchmark, str) else ""
    for kind in ("sim", "pickability", "static"):
        if text.startswith(kind + " ("):
            return kind
    raise CompareError(
        f"{path}: not a results file of craft eval sim, pickability or static (its \"benchmark\" is "
        f"{benchmark!r}); give the file their --json option wrote")


def _flag(record: Mapping[str, Any], key: str, where: str) -> bool:
    value = record.get(key)
    if not isinstance(value, bool):
        raise CompareError(f"{where}: \"{key}\" is {value!r}, not true or false; was the file edited? "
                           "Re-run the command that wrote it")
    return value


def _outcome(record: object, where: str) -> EpisodeOutcome:
    if not isinstance(record, Mapping):
        raise CompareError(f"{where}: not an object; re-run the command that wrote the file")
    success = _flag(record, "success", where)
    failure = record.get("failure")
    outcome = failure if isinstance(failure, str) else ("success" if success else "wrong")
    return EpisodeOutcome(success, _flag(record, "detect", where), outcome)


def _method_records(episode: Mapping[str, Any], kind: str, view: str, where: str) -> Mapping[str, Any]:
    """The episode's per-method records (for static: those of ``view``)."""
    if kind != "static":
        methods = episode.get("methods")
    else:
        level, _, setting = view.partition(":")
        levels = episode.get("levels")
        if not isinstance(levels, Mapping) or level not in levels:
            raise CompareError(f"{where}: no noise level {level!r} (it has {sorted(levels or {})}); "
                               "choose one with --static-view LEVEL:GRASP/ROIS")
        settings = levels[level]
        if not isinstance(settings, Mapping) or setting not in settings:
            raise CompareError(f"{where}: no grasp/ROI setting {setting!r} at level {level!r} "
                               f"(it has {sorted(settings or {})}); choose one with --static-view LEVEL:GRASP/ROIS")
        methods = settings[setting].get("methods") if isinstance(settings[setting], Mapping) else None
    if not isinstance(methods, Mapping):
        raise CompareError(f"{where}: no per-method records; re-run the command that wrote the file")
    return methods


def load_run(path: Path, static_view: str = DEFAULT_STATIC_VIEW) -> Run:
    """Read a ``craft eval sim|pickability|static --json`` file.

    Raises CompareError naming the file (and the episode) for anything it cannot pair."""
    from ...files import read_json

    data = read_json(path, "results file", CompareError)
    if not isinstance(data, Mapping):
        raise CompareError(f"{path}: not a results file (its top level is not an object)")
    kind = _kind(data.get("benchmark"), path)
    level, _, setting = static_view.partition(":")
    if kind == "static" and not (level and setting.count("/") == 1 and all(setting.split("/"))):
        raise CompareError(f"--static-view {static_view!r}: write LEVEL:GRASP/ROIS, e.g. {DEFAULT_STATIC_VIEW}")
    episodes = data.get("episodes")
    if not isinstance(episodes, list) or not episodes:
        raise CompareError(f"{path}: no \"episodes\" list, or an empty one; write the file with --json")
    outcomes: dict[str, dict[str, EpisodeOutcome]] = {}
    seeds: dict[str, int | None] = {}
    methods: dict[str, None] = {}
    for n, episode in enumerate(episodes):
        where = f"{path}, episode {n}"
        if not isinstance(episode, Mapping) or not isinstance(episode.get("id"), str):
            raise CompareError(f"{where}: no \"id\"; re-run the command that wrote the file")
        eid = episode["id"]
        where = f"{path}, episode {eid}"
        if eid in outcomes:
            raise CompareError(f"{where}: the id appears twice; a file made by joining runs cannot be paired")
        records = _method_records(episode, kind, static_view, where)
        outcomes[eid] = {str(m): _outcome(r, f"{where}, method {m}") for m, r in records.items()}
        methods.update(dict.fromkeys(outcomes[eid]))
        seed = episode.get("scene_seed")
        seeds[eid] = seed if isinstance(seed, int) else None
    config = data.get("config")
    return Run(path, kind, config if isinstance(config, Mapping) else {}, tuple(methods), outcomes, seeds,
               static_view if kind == "static" else None)


def wilson_interval(successes: int, trials: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The Wilson score interval of a rate (scipy's): unlike the normal approximation, it stays
    inside [0, 1] and is not of zero width at 0 or n successes."""
    from scipy.stats import binomtest

    if trials == 0:
        return (0.0, 1.0)
    ci = binomtest(successes, trials).proportion_ci(confidence_level=confidence, method="wilson")
    return (float(ci.low), float(ci.high))


def mcnemar_exact(gained: int, lost: int) -> float:
    """Two-sided p of McNemar's exact test: under "the change does nothing", each changed
    episode is a gain or a loss with probability 1/2 (1.0 when nothing changed)."""
    from scipy.stats import binomtest

    changed = gained + lost
    return 1.0 if changed == 0 else float(binomtest(gained, changed, 0.5).pvalue)


@dataclass(frozen=True)
class Change:
    """One episode that one side got right and the other did not."""

    id: str
    before: str  # outcome class on the base side
    after: str


@dataclass(frozen=True)
class Row:
    """One comparison: ``base`` against ``new`` on their paired episodes."""

    label: str
    base_method: str
    new_method: str
    episodes: int
    base_hits: int
    new_hits: int
    gained: tuple[Change, ...]
    lost: tuple[Change, ...]

    @property
    def p_value(self) -> float:
        return mcnemar_exact(len(self.gained), len(self.lost))

    @property
    def significant_loss(self) -> bool:
        return len(self.lost) > len(self.gained) and self.p_value < LOSS_ALPHA

    def to_dict(self) -> dict[str, Any]:
        n = self.episodes
        return {
            "label": self.label, "base_method": self.base_method, "new_method": self.new_method,
            "episodes": n, "base_hits": self.base_hits, "new_hits": self.new_hits,
            "base_rate": round(self.base_hits / n, 6), "new_rate": round(self.new_hits / n, 6),
            "base_ci95": [round(x, 6) for x in wilson_interval(self.base_hits, n)],
            "new_ci95": [round(x, 6) for x in wilson_interval(self.new_hits, n)],
            "change_points": round(100 * (self.new_hits - self.base_hits) / n, 4),
            "gained": [vars(c) for c in self.gained], "lost": [vars(c) for c in self.lost],
            "mcnemar_p": round(self.p_value, 6),
        }


def _row(label: str, base: Run, base_method: str, new: Run, new_method: str, ids: Sequence[str],
         metric: Metric) -> Row:
    gained: list[Change] = []
    lost: list[Change] = []
    base_hits = new_hits = 0
    for eid in ids:
        a, b = base.outcomes[eid][base_method], new.outcomes[eid][new_method]
        base_hits += a.value(metric)
        new_hits += b.value(metric)
        if a.value(metric) != b.value(metric):
            (gained if b.value(metric) else lost).append(Change(eid, a.outcome, b.outcome))
    return Row(label, base_method, new_method, len(ids), base_hits, new_hits, tuple(gained), tuple(lost))


def _paired_ids(base: Run, new: Run) -> tuple[list[str], list[str], list[str]]:
    """Ids in both runs (in the base run's order), then those only in the base, only in the new."""
    if base.kind != new.kind:
        raise CompareError(f"{base.path} is a {base.kind} run and {new.path} a {new.kind} run; "
                           "compare two runs of the same benchmark")
    if base.view != new.view:
        raise CompareError(f"the static views differ ({base.view} against {new.view})")
    both = [eid for eid in base.outcomes if eid in new.outcomes]
    for eid in both:
        a, b = base.scene_seeds[eid], new.scene_seeds[eid]
        if a is not None and b is not None and a != b:
            raise CompareError(
                f"episode {eid}: its scene in {base.path} (scene seed {a}) is not the one in {new.path} "
                f"(scene seed {b}): the runs were made with different --seed, layouts or labels and share "
                "no scene to pair; compare runs of the same --seed and labels")
    if not both:
        raise CompareError(f"{base.path} and {new.path} share no episode id; were they run on the same labels?")
    return (both, [e for e in base.outcomes if e not in new.outcomes],
            [e for e in new.outcomes if e not in base.outcomes])


def _check_methods(run: Run, names: Sequence[str], ids: Sequence[str]) -> None:
    for name in names:
        if name not in run.methods:
            raise CompareError(f"{run.path}: no method {name!r}; it has {', '.join(run.methods)}")
        missing = [eid for eid in ids if name not in run.outcomes[eid]]
        if missing:
            raise CompareError(f"{run.path}, episode {missing[0]}: no record of method {name!r} "
                               f"({len(missing)} such episodes); re-run the command that wrote the file")


def _differing_config(base: Run, new: Run) -> list[str]:
    keys = sorted(set(base.config) | set(new.config))
    return [k for k in keys if base.config.get(k) != new.config.get(k)]


@dataclass
class Comparison:
    """What ``craft eval compare`` prints and writes."""

    base: Run
    new: Run | None  # None: two methods of one run
    metric: Metric
    rows: list[Row]
    unpaired: tuple[int, int] = (0, 0)  # episodes only in the base run, only in the new one
    config_differs: list[str] = field(default_factory=list)

    @property
    def metric_name(self) -> str:
        return SUCCESS_NAMES[self.base.kind] if self.metric == "success" else "Detect"

    def to_dict(self) -> dict[str, Any]:
        return {
            "benchmark": "paired comparison", "kind": self.base.kind, "metric": self.metric,
            "metric_name": self.metric_name, "base": str(self.base.path),
            "new": str(self.new.path) if self.new is not None else None, "static_view": self.base.view,
            "unpaired": {"base_only": self.unpaired[0], "new_only": self.unpaired[1]},
            "config_differs": self.config_differs, "confidence": CONFIDENCE,
            "rows": [r.to_dict() for r in self.rows],
        }

    def to_markdown(self) -> str:
        if self.new is None:
            title = f"two methods of `{self.base.path}`"
            left, right = "base method", "method"
        else:
            title = f"`{self.base.path}` → `{self.new.path}`"
            left, right = "before", "after"
        view = f" (static view {self.base.view})" if self.base.view else ""
        lines = [f"### Paired comparison: {title}, {self.metric_name}{view}\n",
                 f"| comparison | episodes | {left} % (95 % CI) | {right} % (95 % CI) | change (points) | "
                 "gained | lost | McNemar p |",
                 "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for r in self.rows:
            d = r.to_dict()
            lo_a, hi_a = d["base_ci95"]
            lo_b, hi_b = d["new_ci95"]
            lines.append(
                f"| {r.label} | {r.episodes} | {100 * d['base_rate']:.1f} ({100 * lo_a:.1f}–{100 * hi_a:.1f}) | "
                f"{100 * d['new_rate']:.1f} ({100 * lo_b:.1f}–{100 * hi_b:.1f}) | {d['change_points']:+.1f} | "
                f"{len(r.gained)} | {len(r.lost)} | {_p(r.p_value)} |")
        out = "\n".join(lines) + "\n\n"
        for r in self.rows:
            for word, changes in (("gained", r.gained), ("lost", r.lost)):
                if changes:
                    shown = ", ".join(f"`{c.id}` ({c.before} → {c.after})" for c in changes[:LISTED])
                    more = f" and {len(changes) - LISTED} more (the --json file lists every one)" \
                        if len(changes) > LISTED else ""
                    out += f"- {r.label}, {word} ({len(changes)}): {shown}{more}\n"
        notes = ["Episodes: those with the same id (and scene seed) on both sides. 95 % CI: the Wilson "
                 "score interval of each rate alone. McNemar p: the exact two-sided binomial test of "
                 "gained against lost episodes (under \"no effect\" each changed episode is a gain or a "
                 "loss with probability 1/2)."]
        if any(self.unpaired):
            notes.append(f"Not paired: {self.unpaired[0]} episodes only in the base run, "
                         f"{self.unpaired[1]} only in the new one.")
        if self.config_differs:
            notes.append("The runs' configs differ in: " + ", ".join(f"`{k}`" for k in self.config_differs) + ".")
        return out + "\n" + "\n".join(f"- {n}" for n in notes) + "\n"


def _p(p: float) -> str:
    return f"{p:.2g}" if p < 0.01 else f"{p:.2f}"


def compare_runs(base: Run, new: Run, metric: Metric = "success", methods: Sequence[str] = ()) -> Comparison:
    """Each method (default: every method both runs have, in the base run's order) before and after."""
    ids, base_only, new_only = _paired_ids(base, new)
    names = list(methods) or [m for m in base.methods if m in new.methods]
    if not names:
        raise CompareError(f"{base.path} ({', '.join(base.methods)}) and {new.path} ({', '.join(new.methods)}) "
                           "have no method in common; name them with --method")
    _check_methods(base, names, ids)
    _check_methods(new, names, ids)
    rows = [_row(m, base, m, new, m, ids, metric) for m in names]
    return Comparison(base, new, metric, rows, (len(base_only), len(new_only)), _differing_config(base, new))


def compare_methods(run: Run, against: str, metric: Metric = "success", methods: Sequence[str] = ()) -> Comparison:
    """Each method (default: every other one) of one run against the method ``against``."""
    ids = list(run.outcomes)
    names = list(methods) or [m for m in run.methods if m != against]
    if against in names:
        raise CompareError(f"--against {against} is also a --method; a method against itself changes nothing")
    if not names:
        raise CompareError(f"{run.path} has no method besides {against!r} to compare with it")
    _check_methods(run, [against, *names], ids)
    rows = [_row(f"{m} vs {against}", run, against, run, m, ids, metric) for m in names]
    return Comparison(run, None, metric, rows)
