"""The methods every benchmark compares, defined once: their specs (a bundle and the energy
weights it is scored with), loading their bundles, and one ``Grounder`` per method built from the
run's :class:`GroundingSettings` plus what the protocol fixes (vocabulary, alpha).

A method that cannot run (its bundle is missing, unverifiable or in another embedding space) is
skipped with the reason, never silently dropped.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ...paths import KB_DIR, artifacts_hint
from ..grounding.settings import DEFAULT_BETA, DEFAULT_GAMMA, AffNorm, GroundingSettings
from .common import SkippedMethod, vocabulary_senses

if TYPE_CHECKING:
    from ..grounding.grounder import Grounder
    from ..kb.bundle import Bundle

#: The paper's four rows of the testbed tables.
SIM_METHODS = ("CRAFT-E", "CRAFT", "direct-LLM", "alignment-only")


@dataclass(frozen=True)
class MethodSpec:
    """A row of the table: a bundle and the energy weights it is scored with."""

    name: str
    description: str
    bundle: Path
    beta: float = DEFAULT_BETA
    gamma: float = DEFAULT_GAMMA
    #: E_aff scaling of this row (``GroundingSettings.aff_norm``); None: the run's setting
    aff_norm: AffNorm | None = None


def energy_weights(beta: float | None = None, gamma: float | None = None) -> tuple[float, float]:
    """``(beta, gamma)``, each ``None`` replaced by its default (``docs/energy_weights.md``): the
    one place a command's unset weight options become numbers."""
    return (DEFAULT_BETA if beta is None else beta, DEFAULT_GAMMA if gamma is None else gamma)


def default_methods(kb: Path | None = None, kb_dir: Path = KB_DIR, *,
                    beta: float | None = None, gamma: float | None = None) -> list[MethodSpec]:
    """CRAFT-E, CRAFT (ConceptNet KB), direct-LLM, and the two single-term ablations, at the
    weights ``beta``/``gamma`` (``None``: the defaults); each ablation keeps its one term's."""
    b, g = energy_weights(beta, gamma)
    craft_e = kb or kb_dir / "craft-e-default"
    return [
        MethodSpec("CRAFT-E", "LLM property KB + visual alignment", craft_e, beta=b, gamma=g),
        MethodSpec("CRAFT", "ConceptNet-derived KB + visual alignment", kb_dir / "conceptnet", beta=b, gamma=g),
        MethodSpec("direct-LLM", "verb -> objects ranked directly by the LLM (+ alignment)", kb_dir / "direct-llm",
                   beta=b, gamma=g),
        MethodSpec("alignment-only", "CRAFT-E with gamma only (no KB)", craft_e, beta=0.0, gamma=g),
        MethodSpec("affordance-only", "CRAFT-E with beta only (no alignment)", craft_e, beta=b, gamma=0.0),
    ]


def select_methods(
    names: Sequence[str] | None = None, kb: Path | None = None, kb_dir: Path = KB_DIR, *,
    beta: float | None = None, gamma: float | None = None,
) -> list[MethodSpec]:
    """The named methods of :func:`default_methods` (default: the paper's four rows)."""
    specs = {m.name: m for m in default_methods(kb, kb_dir, beta=beta, gamma=gamma)}
    wanted = list(names) if names else list(SIM_METHODS)
    unknown = [n for n in wanted if n not in specs]
    if unknown:
        raise ValueError(f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(specs)}")
    return [specs[n] for n in dict.fromkeys(wanted)]


class NoMethodToRunError(ValueError):
    """Every method an evaluation was asked for was skipped: its table would hold no number, so
    the command fails (exit 2) with each method's reason instead of spending its episodes and
    writing a table of skips."""


def load_methods(
    specs: Sequence[MethodSpec], text_space: str | None = None
) -> tuple[list[tuple[MethodSpec, Bundle]], list[SkippedMethod]]:
    """Load each method's bundle once; a method whose bundle is missing, unverifiable or (with
    ``text_space``) in another embedding space is skipped with the reason. Raises
    :class:`NoMethodToRunError` when every method is skipped."""
    from ..kb.bundle import BundleError, load_bundle

    loaded: dict[Path, Bundle | str] = {}
    runnable: list[tuple[MethodSpec, Bundle]] = []
    skipped: list[SkippedMethod] = []
    for spec in specs:
        if spec.bundle not in loaded:
            try:
                loaded[spec.bundle] = load_bundle(spec.bundle, check_encoder=False)
            except BundleError as exc:
                loaded[spec.bundle] = f"bundle unavailable: {exc}"
        bundle = loaded[spec.bundle]
        if isinstance(bundle, str):
            skipped.append(SkippedMethod(spec.name, bundle))
        elif text_space is not None and bundle.manifest.text_encoder.id != text_space:
            skipped.append(SkippedMethod(spec.name, f"{spec.bundle}: text encoder "
                                         f"{bundle.manifest.text_encoder.id}, the image encoder embeds "
                                         f"into {text_space}"))
        else:
            runnable.append((spec, bundle))
    if specs and not runnable:
        raise NoMethodToRunError(nothing_runs([s.bundle for s in specs], skipped))
    return runnable, skipped


def nothing_runs(bundles: Sequence[Path], skipped: Sequence[SkippedMethod]) -> str:
    """One line for :class:`NoMethodToRunError`: methods sharing a bundle's reason are named
    together, and the artifacts folder's hint, which each missing bundle's reason carries, is
    said once at the end."""
    hints = dict.fromkeys(h for h in (artifacts_hint(b) for b in bundles if not b.exists()) if h)
    by_reason: dict[str, list[str]] = {}
    for s in skipped:
        reason = s.reason
        for hint in hints:
            reason = reason.replace(hint, "")
        by_reason.setdefault(reason, []).append(s.name)
    return "no method can run: " + "; ".join(f"{', '.join(n)}: {r}" for r, n in by_reason.items()) + "".join(hints)


def method_settings(spec: MethodSpec, settings: GroundingSettings, vocabulary: Sequence[str],
                    alpha: float | None = None) -> GroundingSettings:
    """The run's settings with the method's weights, the protocol's vocabulary (open
    vocabulary on: benchmark verbs may be missing from a KB) and, where the protocol fixes it,
    alpha (no grasps on ImageNet photos)."""
    update: dict[str, object] = {"beta": spec.beta, "gamma": spec.gamma,
                                 "vocabulary": tuple(vocabulary), "open_vocab": True}
    if alpha is not None:
        update["alpha"] = alpha
    if spec.aff_norm is not None:
        update["aff_norm"] = spec.aff_norm
    return settings.model_copy(update=update)


def build_grounders(
    runnable: Sequence[tuple[MethodSpec, Bundle]],
    settings: GroundingSettings,
    vocabulary: Sequence[str],
    *,
    alpha: float | None = None,
    senses: Mapping[str, str] | None = None,
) -> dict[str, Grounder]:
    """One ``Grounder`` per method (see :func:`method_settings`), every one reading the names of
    ``p(o | r)`` in the same senses (``senses``; default: the shipped vocabulary's glosses,
    ``common.vocabulary_senses``), whatever its bundle records: the methods differ in knowledge,
    not in perception."""
    from ..grounding.grounder import Grounder

    if senses is None and settings.sense_weight > 0:
        senses = vocabulary_senses()
    return {spec.name: Grounder(bundle, method_settings(spec, settings, vocabulary, alpha), senses=senses)
            for spec, bundle in runnable}
