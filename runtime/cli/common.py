"""What every ``craft`` command shares: the consoles, the exit codes, one ``fail``, the option
types used by more than one command, and the resolution of grounding options into
:class:`GroundingSettings`.

Exit codes (both CLIs): 0 ok; 1 a check failed (verification commands); 2 bad input or usage
(files, boxes, unknown verb, bundle refused).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
from rich.console import Console
from rich.markup import escape

from ...files import ancestor_problem, output_file_problem
from ..grounding.settings import GroundingSettings


def make_console(*, stderr: bool = False) -> Console:
    """A console that wraps lines only on a terminal: piped or logged, rich would wrap at 80
    columns and split hashes, paths and key ids across lines that scripts grep for."""
    console = Console(stderr=stderr)
    console.soft_wrap = not console.is_terminal
    return console


err = make_console(stderr=True)
out = make_console()
EXIT_CHECK_FAILED = 1
EXIT_BAD_INPUT = 2


def fail(message: str, code: int = EXIT_BAD_INPUT) -> NoReturn:
    """Print ``error: message`` on stderr and exit with ``code`` (default: bad input)."""
    err.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def emit(table: str, data: dict[str, Any], json_out: Path | None, markdown: Path | None,
         log: Callable[[str], None]) -> None:
    """``evaluation.common.emit_report``, with an output file that cannot be written (a
    read-only mount, a full disk) an exit-2 error naming it instead of a traceback."""
    from ..evaluation.common import ReportWriteError, emit_report

    try:
        emit_report(table, data, json_out, markdown, log)
    except ReportWriteError as exc:
        fail(str(exc))


def check_named_bundles(kbs: list[Path] | Path | None, kb_dir: Path | None = None) -> None:
    """Exit 2 before any work when a bundle the user named (``--kb``) does not load and verify,
    or a ``--kb-dir`` is not a folder. Bundles the defaults name may be missing (that method is
    skipped with the reason); one the user asked for must not turn into a skip and exit 0."""
    from ..kb.bundle import BundleError, load_bundle

    if kb_dir is not None and not kb_dir.is_dir():
        fail(f"--kb-dir {kb_dir}: no such folder of bundles")
    for path in [kbs] if isinstance(kbs, Path) else kbs or []:
        try:
            load_bundle(path, check_encoder=False)
        except BundleError as exc:
            fail(f"--kb {path}: {exc}")


def note(message: str) -> None:
    """A plain line on stderr ("wrote FILE"), never read as markup."""
    err.print(message, highlight=False, markup=False)


def grounding_settings(**options: Any) -> GroundingSettings:
    """The grounding options of a command, validated once (a bad value exits 2 naming it)."""
    try:
        return GroundingSettings.of(**options)
    except ValueError as exc:
        fail(str(exc))


def read_names(path: Path, what: str) -> list[str]:
    """A one-name-per-line file (vocabulary, classes), or exit 2 naming it."""
    from ..evaluation.common import read_name_list

    try:
        return read_name_list(path)
    except OSError as exc:
        fail(f"{path}: cannot read the {what} ({exc})")


def read_some_names(path: Path, what: str, option: str) -> list[str]:
    """:func:`read_names` of a file an option names (``--vocab``, ``--classes``) that must name
    at least one thing, or exit 2 naming the option and the file. Commands call it before any
    bundle or model loads: an empty file used to fail only after the KB (or ~40 s of image
    embedding) with "the object vocabulary is empty" and no file name; a folder or a non-UTF-8
    file is named too (``files.read_text_file``)."""
    from ...files import read_text_file

    try:
        read_text_file(path, what)
    except ValueError as exc:
        fail(f"{option} {exc}")
    names = read_names(path, what)
    if not names:
        fail(f"{option} {path}: the {what} names nothing (empty, or only blank and # lines); "
             "write one name per line")
    return names


def _checked_output(value: Path | None, example_suffix: str) -> Path | None:
    problem = None if value is None else output_file_problem(value, example_suffix)
    if problem is not None:
        raise typer.BadParameter(problem)
    return value


# typer passes a callback's value to its last plain parameter: each callback takes only ``value``
def checked_output_file(value: Path | None) -> Path | None:
    """typer callback of an output file option (see ``output_file_problem``)."""
    return _checked_output(value, ".json")


def checked_markdown_file(value: Path | None) -> Path | None:
    """typer callback of a ``--markdown`` option: as ``checked_output_file``, offering ``out.md``."""
    return _checked_output(value, ".md")


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the platform has one)."""
    affinity = getattr(os, "sched_getaffinity", None)
    return len(affinity(0)) if affinity is not None else os.cpu_count() or 1


def checked_jobs(value: int) -> int:
    """typer callback of ``--jobs``: at most one worker per usable CPU. Each worker holds its own
    image encoder, grasp network and simulator (~0.65 GB measured), so ``--jobs 64`` on a
    2-core, 24 GB machine would run out of memory, and workers beyond the CPUs only wait;
    results are byte-identical for any ``--jobs``, so fewer workers change nothing but time."""
    cpus = usable_cpus()
    if value > cpus:
        note(f"--jobs {value}: this machine gives the command {cpus} CPU{'s' if cpus > 1 else ''}; "
             f"running {cpus} worker{'s' if cpus > 1 else ''} (results are the same for any --jobs)")
        return cpus
    return value


def checked_weight(value: float | None) -> float | None:
    """typer callback of an energy weight: finite (``inf`` times an energy of 0 is NaN, which
    ranks every ROI as NaN; ``craft ground`` rejects it through ``GroundingSettings`` too)."""
    if value is not None and not math.isfinite(value):
        raise typer.BadParameter(f"{value} is not a finite number; give a weight >= 0, e.g. 1")
    return value


def checked_conse_temperature(value: float | None) -> float | None:
    """typer callback of ``--conse-temperature``: finite and > 0 (a softmax temperature)."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise typer.BadParameter(f"{value} is not a finite number > 0; give a temperature, e.g. 2 (1: ConSE's own)")
    return value


PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def checked_plot_file(value: Path | None) -> Path | None:
    """typer callback of a ``--plot`` option: a writable file with a format matplotlib writes."""
    _checked_output(value, ".png")
    if value is not None and value.suffix.lower() not in PLOT_SUFFIXES:
        raise typer.BadParameter(f"{value}: unknown figure format {value.suffix or '(none)'!r}; "
                                 f"end the name with one of {', '.join(PLOT_SUFFIXES)}")
    return value


def checked_output_folder(value: Path | None) -> Path | None:
    """typer callback of an output folder option: not an existing file, nor under one."""
    if value is None:
        return value
    problem = (f"{value} is a file; give a folder" if value.exists() and not value.is_dir()
               else ancestor_problem(value))
    if problem is not None:
        raise typer.BadParameter(problem)
    return value


_FORMS = "sum-tanh | normalized-product | specificity | required-veto | specificity-veto"

KbDirOpt = Annotated[Path | None, typer.Option(help="Folder of the baseline bundles (conceptnet/, direct-llm/).")]
JsonOpt = Annotated[Path | None, typer.Option("--json", help="Write results as JSON.", callback=checked_output_file)]
MarkdownOpt = Annotated[Path | None, typer.Option(help="Write the Markdown table.", callback=checked_markdown_file)]
SenseWeightOpt = Annotated[float | None, typer.Option(
    "--sense-weight", min=0.0, max=1.0,
    help="Read each name on both sides of p(o|r) with its gloss: the object names' text embeddings, and the "
         "ImageNet class names' ConSE embeds crops among, are the unit mean of the name's and the gloss's, the "
         "gloss weighing this much (grounding/senses.py, encoders/conse.py; in evaluations every method reads the "
         "shipped vocabulary's glosses). Default 0.5; 0 reads bare names and, with --conse-temperature 1, "
         "reproduces runs from before.",
    show_default=False)]
ConseTemperatureOpt = Annotated[float | None, typer.Option(
    "--conse-temperature", callback=checked_conse_temperature,
    help="Softmax temperature of the image classifier's probabilities that weigh ConSE's top-10 ImageNet class "
         "names (encoders/conse.py). Default 2; 1 is ConSE's own weighting and reproduces runs from before.",
    show_default=False)]
TemperatureOpt = Annotated[float | None, typer.Option(help="Softmax temperature of p(o|r) (default: 0.1, fixed a priori; grounding/settings.py).")]
AffModeOpt = Annotated[str, typer.Option(help="E_aff over object hypotheses: expected | argmax.")]
AffNormOpt = Annotated[str | None, typer.Option(help="E_aff scaling: none | verb-best (each verb's best KB object at -1; default: grounding/settings.py, docs/energy_weights.md).")]
BetaOpt = Annotated[float | None, typer.Option(min=0.0, callback=checked_weight, help="Weight of E_aff (default 8, on E_aff scaled per verb; the paper's is 1: docs/energy_weights.md).")]
GammaOpt = Annotated[float | None, typer.Option(min=0.0, callback=checked_weight, help="Weight of E_align (default 1, as the paper's: docs/energy_weights.md).")]
EnergyFormOpt = Annotated[str | None, typer.Option(help=f"E_aff form: {_FORMS} (default: each bundle's).")]
ThreadsOpt = Annotated[int | None, typer.Option(min=1, help="Torch threads for the image encoder.")]
NoCacheOpt = Annotated[bool, typer.Option("--no-cache", help="Do not read or write the on-disk image-embedding cache.")]
