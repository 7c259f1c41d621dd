"""``craft eval open-world``: leave-objects-out and leave-verbs-out on dev labels (issue 11)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ...paths import KB_DIR
from .common import checked_markdown_file, checked_output_file


def eval_open_world(
    kb: Annotated[Path, typer.Option(help="Bundle to evaluate.")] = KB_DIR / "craft-e-default",
    labels: Annotated[list[str] | None, typer.Option(
        help="zhu | sim-dev | sim-val | labels .json | verb,object .csv (repeatable; default: zhu and sim-dev).")] = None,
    energy_form: Annotated[str | None, typer.Option(help="E_aff form (default: the bundle's).")] = None,
    episodes: Annotated[int, typer.Option(min=1, help="5-candidate episodes per verb.")] = 100,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the episodes.")] = 0,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write results as JSON.", callback=checked_output_file)] = None,
    markdown: Annotated[Path | None, typer.Option(help="Write the Markdown tables.", callback=checked_markdown_file)] = None,
) -> None:
    """Objects and verbs the KB has never seen: remove them, infer them, compare AP with the
    in-KB result; abstention rate and precision; the thresholds' dev grid."""
    from ..evaluation.kb_eval import KBLabelsError
    from ..evaluation.open_world_eval import evaluate_open_world
    from ..grounding.energies import check_energy_form
    from ..kb.bundle import BundleError
    from .common import emit, err, fail

    try:
        form = check_energy_form(energy_form) if energy_form else None
        report = evaluate_open_world(kb, labels or ["zhu", "sim-dev"], form=form,
                                     episodes_per_verb=episodes, seed=seed)
    except (KBLabelsError, FileNotFoundError, BundleError, ValueError) as exc:
        fail(str(exc))
    emit(report.to_markdown(), report.to_dict(), json_out, markdown,
                lambda msg: err.print(msg, highlight=False, markup=False))
