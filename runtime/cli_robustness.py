"""``craft eval robustness imagenet``: the ImageNet protocol under perceptual noise.

Thin command over ``runtime/evaluation/robustness.py``; prints the Markdown table, optionally
writes JSON, Markdown and a plot. Exit codes as for ``craft eval imagenet``: 0 ok, 2 bad input
(labels, levels, classes file, missing data).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, NoReturn

import typer
from rich.console import Console
from rich.markup import escape

_err = Console(stderr=True)
EXIT_BAD_INPUT = 2

robustness_app = typer.Typer(help="Robustness of the method to perceptual noise.", no_args_is_help=True)


def _fail(message: str, code: int = EXIT_BAD_INPUT) -> NoReturn:
    _err.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


@robustness_app.command("imagenet")
def robustness_imagenet(
    labels: Annotated[Path, typer.Option(help='Labels JSON {"verb": ["object", ...]}.')],
    kb: Annotated[Path | None, typer.Option(help="CRAFT-E bundle (default artifacts/kb/craft-e-default).")] = None,
    kb_dir: Annotated[Path | None, typer.Option(help="Folder of the baseline bundles (conceptnet/, direct-llm/).")] = None,
    levels: Annotated[list[str] | None, typer.Option(
        "--levels", help="KIND=L1,L2,... (repeatable; kinds: gaussian sigma, blur radius px, crop fraction cut "
                         "away). Default: gaussian=0,8,16,32,64 blur=0,1,2,4,8 crop=0,0.25,0.5,0.75.")] = None,
    episodes: Annotated[int, typer.Option(min=1, help="Episodes per verb and setting.")] = 100,
    seed: Annotated[int, typer.Option(help="Seed of the episode sampler.")] = 0,
    noise_seed: Annotated[int, typer.Option(help="First seed of the perturbations.")] = 0,
    noise_seeds: Annotated[int, typer.Option(min=1, help="Noise draws per level (seeds noise-seed, +1, ...), averaged.")] = 1,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write results as JSON.")] = None,
    plot: Annotated[Path | None, typer.Option(help="Write Top-1/MRR vs noise level (PNG).")] = None,
    markdown: Annotated[Path | None, typer.Option(help="Write the Markdown tables.")] = None,
    classes: Annotated[Path | None, typer.Option(help="Only draw episodes from these classes (one per line).")] = None,
    no_cache: Annotated[bool, typer.Option(help="Do not read or write the on-disk image-embedding cache.")] = False,
    threads: Annotated[int | None, typer.Option(min=1, help="Torch threads for the image encoder.")] = None,
    temperature: Annotated[float | None, typer.Option(help="Softmax temperature of p(o|r) (default: calibrated).")] = None,
    aff_mode: Annotated[str, typer.Option(help="expected | argmax.")] = "expected",
    energy_form: Annotated[str | None, typer.Option(help="sum-tanh | normalized-product | specificity | required-veto | specificity-veto (default: each bundle's).")] = None,
) -> None:
    """Top-1 / MRR of every method as Gaussian noise, blur and ROI crop jitter grow."""
    from craft_e.paths import KB_DIR
    from craft_e.runtime.encoders.conse import ENCODER_CACHE_DIR
    from craft_e.runtime.evaluation.common import emit_report, read_name_list
    from craft_e.runtime.evaluation.imagenet import LabelsError, default_methods
    from craft_e.runtime.evaluation.robustness import (
        DEFAULT_LEVELS,
        evaluate_robustness,
        parse_levels,
    )
    from craft_e.runtime.grounding import DEFAULT_TEMPERATURE

    if aff_mode not in ("expected", "argmax"):
        _fail(f"--aff-mode {aff_mode!r}: use expected or argmax")
    from craft_e.runtime.energies import ENERGY_FORMS

    if energy_form is not None and energy_form not in ENERGY_FORMS:
        _fail(f"--energy-form {energy_form!r}: use one of {', '.join(ENERGY_FORMS)}")
    if temperature is not None and temperature <= 0:
        _fail(f"--temperature {temperature}: must be > 0")
    try:
        chosen = parse_levels(levels) if levels else DEFAULT_LEVELS
    except ValueError as exc:
        _fail(str(exc))
    pool = None
    if classes is not None:
        try:
            pool = read_name_list(classes)
        except OSError as exc:
            _fail(f"{classes}: cannot read the classes file ({exc})")
    try:
        report = evaluate_robustness(labels, levels=chosen, methods=default_methods(kb, kb_dir or KB_DIR),
                                     episodes=episodes, seed=seed, noise_seeds=range(noise_seed, noise_seed + noise_seeds), pool=pool,
                                     cache_dir=None if no_cache else ENCODER_CACHE_DIR, threads=threads,
                                     temperature=DEFAULT_TEMPERATURE if temperature is None else temperature,
                                     aff_mode=aff_mode,  # type: ignore[arg-type]
                                     energy_form=energy_form)
    except (LabelsError, FileNotFoundError, ValueError) as exc:
        _fail(str(exc))
    emit_report(report.to_markdown(), report.to_dict(), json_out, markdown,
                lambda msg: _err.print(msg, highlight=False, markup=False))
    if plot is not None:
        report.plot(plot)
        _err.print(f"wrote {plot}", highlight=False, markup=False)


def register(app: typer.Typer) -> None:
    """Add ``robustness`` to ``craft eval`` (pass ``eval_app``).

    Given the top-level ``craft`` app instead (the ``COMMAND_MODULES`` convention of
    ``runtime/cli.py``), it attaches under that app's ``eval`` group, so the command is always
    ``craft eval robustness imagenet``.
    """
    from craft_e.runtime import cli

    target = cli.eval_app if app is cli.app else app
    target.add_typer(robustness_app, name="robustness")
