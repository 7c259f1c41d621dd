"""``craft eval kb``: E_aff alone with perfect recognition, every bundle x E_aff form, dev labels."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .common import checked_markdown_file, checked_output_file


def eval_kb(
    kb: Annotated[list[Path] | None, typer.Option(
        help="Bundle(s) to score (repeatable; default: craft-e-default, direct-llm, conceptnet).")] = None,
    labels: Annotated[list[str] | None, typer.Option(
        help="zhu | sim-dev | sim-val | labels .json {verb: [objects]} | verb,object .csv over sim assets "
             "(repeatable; default: zhu and sim-dev).")] = None,
    energy_form: Annotated[list[str] | None, typer.Option(
        "--energy-form", help="E_aff form(s) (repeatable; default: every form).")] = None,
    objects: Annotated[Path | None, typer.Option(
        help="Candidate objects of a .json labels file without an \"_objects\" list "
             "(default: the ImageNet vocabulary).")] = None,
    episodes: Annotated[int, typer.Option(min=1, help="5-candidate episodes per verb.")] = 100,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the episodes and the verb folds.")] = 0,
    folds: Annotated[int, typer.Option(min=2, help="Leave-verbs-out folds.")] = 5,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write results as JSON.", callback=checked_output_file)] = None,
    markdown: Annotated[Path | None, typer.Option(help="Write the Markdown tables.", callback=checked_markdown_file)] = None,
) -> None:
    """Knowledge alone: AP, AUC and 5-candidate top-1 of E_aff per verb, chance and oracle rows,
    and leave-verbs-out choice of the E_aff form."""
    from ..evaluation.kb_eval import DEFAULT_KBS, KBLabelsError, evaluate_kbs
    from ..evaluation.methods import NoMethodToRunError
    from ..grounding.energies import ENERGY_FORMS, check_energy_form
    from ..kb.bundle import BundleError
    from .common import check_named_bundles, emit, err, fail, read_some_names

    check_named_bundles(kb)
    try:
        forms = [check_energy_form(f) for f in energy_form] if energy_form else list(ENERGY_FORMS)
    except ValueError as exc:
        fail(f"--energy-form: {exc}")
    candidates = read_some_names(objects, "objects file", "--objects") if objects is not None else None
    try:
        report = evaluate_kbs(kb or DEFAULT_KBS, labels or ["zhu", "sim-dev"], forms=forms,
                              episodes_per_verb=episodes, seed=seed, folds=folds, objects=candidates)
    except (KBLabelsError, FileNotFoundError, NoMethodToRunError, BundleError) as exc:
        fail(str(exc))
    emit(report.to_markdown(), report.to_dict(), json_out, markdown,
                lambda msg: err.print(msg, highlight=False, markup=False))
