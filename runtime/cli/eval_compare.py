"""``craft eval compare``: two runs (or two methods of one run), episode by episode, with the
gained and lost episodes and McNemar's exact test (``evaluation/compare.py``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, cast

import typer

from .common import EXIT_CHECK_FAILED, checked_markdown_file, checked_output_file, emit, fail, note


def eval_compare(
    base: Annotated[Path, typer.Argument(help="Results JSON of craft eval sim, pickability or static (--json): "
                                              "the run before the change.")],
    new: Annotated[Path | None, typer.Argument(help="The same benchmark's JSON after the change (same --seed "
                                                    "and labels); leave out with --against.")] = None,
    methods: Annotated[list[str] | None, typer.Option(
        "--method", help="A method to compare, e.g. CRAFT-E; repeatable; default: every method both runs have "
                         "(with --against: every other method).")] = None,
    against: Annotated[str | None, typer.Option(
        help="Compare the methods of one run (give one file) against this one, e.g. direct-LLM.")] = None,
    metric: Annotated[str, typer.Option(help="success (Grasp Rate; picked; accuracy) | detect.")] = "success",
    static_view: Annotated[str, typer.Option(
        help="For craft eval static files: LEVEL:GRASP/ROIS, e.g. clean:gt/gt.")] = "clean:grconvnet/predicted",
    fail_on_loss: Annotated[bool, typer.Option(
        "--fail-on-loss", help="Exit 1 when a comparison lost more episodes than it gained with McNemar p < 0.05 "
                               "(for a check in a pull request).")] = False,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the comparison as JSON.",
                                                  callback=checked_output_file)] = None,
    markdown: Annotated[Path | None, typer.Option(help="Write the Markdown table.",
                                                  callback=checked_markdown_file)] = None,
) -> None:
    """Did a change help? Paired episodes, each side's rate with its 95 % interval, what was gained and lost."""
    from ..evaluation.compare import (
        LOSS_ALPHA,
        METRICS,
        CompareError,
        compare_methods,
        compare_runs,
        load_run,
    )

    if metric not in METRICS:
        fail(f"--metric {metric!r}: choose one of {', '.join(METRICS)}")
    if new is None and against is None:
        fail("give a second results file to compare with, or --against METHOD to compare the methods of one run")
    if new is not None and against is not None:
        fail("--against compares two methods of one run: give one results file, or leave --against out")
    inputs = {p.resolve() for p in (base, new) if p is not None}
    for option, path in (("--json", json_out), ("--markdown", markdown)):
        if path is not None and path.resolve() in inputs:
            fail(f"{option} {path} is a results file being compared: writing the comparison there would "
                 "replace that run; give another path")
    try:
        base_run = load_run(base, static_view)
        if against is not None:
            comparison = compare_methods(base_run, against, metric, methods or ())
        else:
            comparison = compare_runs(base_run, load_run(cast(Path, new), static_view), metric, methods or ())
    except CompareError as exc:
        fail(str(exc))
    emit(comparison.to_markdown(), comparison.to_dict(), json_out, markdown, note)
    losers = [r.label for r in comparison.rows if r.significant_loss]
    if fail_on_loss and losers:
        note(f"lost more episodes than it gained (McNemar p < {LOSS_ALPHA}): {', '.join(losers)}")
        raise typer.Exit(EXIT_CHECK_FAILED)
