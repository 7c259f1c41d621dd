"""``craftc``: the knowledge compiler's command line. Commands are thin; work lives in modules.

Exit codes: 0 ok; 1 a check failed (validate, diff --fail-on, cache verify); 2 bad input or
usage (files, vocabularies, overrides, unknown provider); 3 a source could not answer (missing
record in replay, live provider failed after retries).
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path
from typing import Annotated, Literal

import typer
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
)

from ..paths import CACHE_DIR, KB_DIR, VOCAB_DIR, artifacts_hint
from ..runtime.cli.common import EXIT_BAD_INPUT, EXIT_CHECK_FAILED, err, fail, make_console
from ..signals import exit_through_python_on_sigterm
from .cli_diagnose import register as register_diagnose
from .cli_options import TrustedKeyOpt, trusted_keys
from .cli_pack import register as register_pack
from .prompts import DEFAULT_PROMPT_VERSION, PROMPT_VERSIONS

app = typer.Typer(
    help="CRAFT-E knowledge compiler: verbs -> properties -> objects, offline and verifiable.",
    no_args_is_help=True,
    add_completion=False,
)
cache_app = typer.Typer(help="Inspect the record cache.", no_args_is_help=True)
curate_app = typer.Typer(
    help="Store hand-written answers to the project's prompts (provider 'curated').",
    no_args_is_help=True,
)
app.add_typer(cache_app, name="cache")
app.add_typer(curate_app, name="curate")
stdout = make_console()

EXIT_SOURCE_FAILED = 3
PROVIDERS = ("replay", "openai", "gemini", "openai-batch", "gemini-batch")


PromptsOpt = Annotated[
    str,
    typer.Option(
        "--prompts",
        help="Prompt version: v2 (discriminating, defined properties; glossed objects) | v1.",
    ),
]


def _prompt_version(version: str) -> Literal["v1", "v2"]:
    if version == "v1":
        return "v1"
    if version == "v2":
        return "v2"
    fail(f"unknown prompt version {version!r}; choose one of {', '.join(PROMPT_VERSIONS)}")


def _cache_problem(cache: Path, *, must_exist: bool) -> str | None:
    """What is wrong with a ``--cache`` (or ``CRAFT_CACHE``) path, or None: a path that is a file
    is never a record cache (reading records below it raised NotADirectoryError, and the cache
    commands called it "no such folder"); one that does not exist is a typo where ``must_exist``
    (``cache verify`` on it would pass a CI gate having checked nothing)."""
    if cache.exists() and not cache.is_dir():
        return (f"{cache}: is a file, not a record cache folder; give the cache's folder (e.g. "
                "artifacts/cache), from --cache or CRAFT_CACHE")
    if must_exist and not cache.is_dir():
        return f"{cache}: no such record cache folder; check the path (or CRAFT_CACHE)"
    return None


# typer passes a callback's value to its last plain parameter: each callback takes only ``cache``
def _cache_folder(cache: Path) -> Path:
    """typer callback of --cache where the cache may be made: refused when it is a file."""
    problem = _cache_problem(cache, must_exist=False)
    if problem is not None:
        raise typer.BadParameter(problem)
    return cache


def _existing_cache(cache: Path) -> Path:
    """typer callback of the cache commands' --cache: an existing folder (see _cache_problem)."""
    problem = _cache_problem(cache, must_exist=True)
    if problem is not None:
        raise typer.BadParameter(problem)
    return cache


CacheOpt = Annotated[
    Path, typer.Option(help="Record cache root (artifacts/cache).", envvar="CRAFT_CACHE",
                       callback=_cache_folder)
]
ExistingCacheOpt = Annotated[
    Path, typer.Option(help="Record cache root (artifacts/cache); must exist.", envvar="CRAFT_CACHE",
                       callback=_existing_cache)
]


def _given_path(text: str) -> Path:
    """A path option's parser: an empty value is refused, not read as the working directory (an
    ``--out "$UNSET"`` would otherwise name wherever the command ran)."""
    if not text.strip():
        raise typer.BadParameter("empty path; give a folder path (nothing was written)")
    return Path(text)


@app.command()
def build(
    verbs: Annotated[Path, typer.Option(help="Verbs file: one verb per line.")],
    objects: Annotated[
        Path, typer.Option(help="Objects file (default: artifacts/vocab/union_objects.txt, the "
                           "benchmarks' union; the shipped craft-e-default uses default_objects.txt, "
                           "see scripts/build_kbs).")
    ] = VOCAB_DIR / "union_objects.txt",
    provider: Annotated[
        str,
        typer.Option(
            help="replay (cache only) | openai | gemini (cache-first, then live) | openai-batch "
            "| gemini-batch (the misses of each stage as one batch job; same records)."
        ),
    ] = "replay",
    model: Annotated[
        str | None, typer.Option(help="Model id (default: craft-e-curators for replay).")
    ] = None,
    record_provider: Annotated[
        str, typer.Option(help="With replay: whose records to replay (curated, openai, ...).")
    ] = "curated",
    base_url: Annotated[
        str | None, typer.Option(help="Live provider base URL (OpenAI-compatible or Gemini).")
    ] = None,
    mode: Annotated[
        str,
        typer.Option(
            help="llm (two-stage property KB) | conceptnet (CRAFT baseline) | direct (direct-LLM "
            "baseline) | llm+direct (property KB plus the direct answer as one labelled path)."
        ),
    ] = "llm",
    conceptnet: Annotated[
        str,
        typer.Option(help="With --mode conceptnet: omcs (offline default) | csv:<dump.csv[.gz]> | api[:<base_url>]."),
    ] = "omcs",
    overrides: Annotated[
        Path | None, typer.Option(help="TOML file of edits compiled with provenance 'override'.")
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(parser=_given_path,
                     help="Output bundle folder (default artifacts/kb/<name>, which is never "
                     "replaced without --force); never inside another bundle."),
    ] = None,
    name: Annotated[
        str, typer.Option(help="KB name (lowercase, digits, . _ -).")
    ] = "craft-e-default",
    kb_version: Annotated[
        str, typer.Option("--kb-version", help="Semantic version written to the manifest.")
    ] = "1.0.0",
    tau: Annotated[
        float | None,
        typer.Option(help="w_po threshold for an edge to count (default 0.5; 0 for direct)."),
    ] = None,
    energy_form: Annotated[
        str, typer.Option(
            help="sum-tanh (paper, default) | normalized-product | specificity | required-veto "
            "| specificity-veto (runtime/grounding/energies.py)."
        )
    ] = "sum-tanh",
    cache: CacheOpt = CACHE_DIR,
    quiet: Annotated[bool, typer.Option(help="No progress bars.")] = False,
    force: Annotated[
        bool,
        typer.Option(
            help="Replace an existing bundle of another kb name at --out, or any bundle at the default "
            "output (never anything that is not a bundle)."
        ),
    ] = False,
    prompts: PromptsOpt = DEFAULT_PROMPT_VERSION,
    property_pass: Annotated[
        bool,
        typer.Option(
            help="Stage 2b: also read per-property answers over all objects (w_po = the larger)."
        ),
    ] = False,
    object_pass: Annotated[
        str,
        typer.Option(
            help="Stage 2 per object: ask (a prompt per object with unjudged properties) | reuse "
            "(recorded answers only; the rest is judged by stage 2b, needs --property-pass)."
        ),
    ] = "ask",
    concurrency: Annotated[
        int, typer.Option(min=1, help="Live requests in flight at once (openai, gemini).")
    ] = 4,
    timeout: Annotated[
        float | None,
        typer.Option(min=0.1, help="Seconds one live HTTP request may take (default: 120 read)."),
    ] = None,
    batch_wait: Annotated[
        float | None,
        typer.Option(
            help="Batch providers: stop waiting after this many seconds (exit 3; the batch "
            "keeps running and the same command resumes it; 0: poll once). Default: wait until "
            "it ends."
        ),
    ] = None,
) -> None:
    """Compile a KB bundle from verbs (and objects), replaying recorded answers by default."""
    from pydantic import ValidationError

    from .build import PHASE, BuildConfig
    from .build import build as run_build
    from .cache import CacheError, cache_in_use
    from .emit import BundleWriteError
    from .sources.llm import SourceError
    from .vocab import VocabError

    if provider not in PROVIDERS:
        fail(f"unknown provider {provider!r}; choose one of {', '.join(PROVIDERS)}")
    if not record_provider.strip():  # replay would look for records of provider '' and miss
        fail("--record-provider is empty; name whose records to replay, e.g. curated or openai")
    if batch_wait is not None and not (math.isfinite(batch_wait) and batch_wait >= 0):
        # NaN would compare false and wait forever; a negative bound gives up at the first poll
        fail(f"--batch-wait {batch_wait}: give a finite number of seconds >= 0 (0 polls the batch "
             "once; leave the option out to wait until the batch ends)")
    if mode not in ("llm", "conceptnet", "direct", "llm+direct"):
        fail(f"unknown mode {mode!r}; choose llm, conceptnet, direct or llm+direct")
    if object_pass not in ("ask", "reuse"):
        fail(f"unknown --object-pass {object_pass!r}; choose ask or reuse")
    if object_pass == "reuse" and not property_pass:
        fail("--object-pass reuse leaves unrecorded pairs to stage 2b: add --property-pass")
    transport = None
    batch_backend = None
    if provider.endswith("-batch"):
        from .sources.batch import make_batch_backend

        try:
            batch_backend = make_batch_backend(provider, model, base_url, timeout_s=timeout)
        except ValueError as exc:
            fail(str(exc))
        identity, model_id = batch_backend.provider, batch_backend.model
    elif provider != "replay":
        from .sources.transports import make_transport

        try:
            transport = make_transport(provider, model=model, base_url=base_url, timeout_s=timeout)
        except ValueError as exc:
            fail(str(exc))
        identity, model_id = transport.provider, transport.model
    else:
        identity, model_id = record_provider, model or "craft-e-curators"
    try:
        config = BuildConfig(
            verbs_file=verbs,
            objects_file=objects,
            out=out or KB_DIR / name,
            name=name,
            kb_version=kb_version,
            mode=mode,
            provider=identity,
            model=model_id,
            cache_root=cache,
            overrides_file=overrides,
            conceptnet=conceptnet,
            tau=(0.0 if mode == "direct" else 0.5) if tau is None else tau,
            energy_form=energy_form,
            force=force,
            prompt_version=_prompt_version(prompts),
            property_pass=property_pass,
            object_pass="reuse" if object_pass == "reuse" else "ask",
            concurrency=concurrency,
        )
    except ValidationError as exc:
        first = exc.errors()[0]
        option = "--" + str(first["loc"][0]).replace("_", "-")
        hints = {"--name": " (lowercase letters, digits, '.', '_' and '-', e.g. my-kb)",
                 "--kb-version": " (MAJOR.MINOR.PATCH, e.g. 1.0.0)", "--tau": " (a number in [0, 1])"}
        fail(f"bad option {option} {first.get('input')!r}: {first['msg']}{hints.get(option, '')}; "
             "nothing was built")
    if provider == "replay" and not cache.is_dir():
        # A replay build reads every answer from the cache: a mistyped --cache / CRAFT_CACHE would
        # otherwise surface as "no record for ..." about the first verb, naming a record path.
        fail(f"{cache}: no such record cache folder (from --cache or CRAFT_CACHE); a replay build "
             f"reads every answer from it (the shipped one is artifacts/cache){artifacts_hint(cache)}; "
             "nothing was built")
    if out is None and (config.out / "manifest.json").is_file() and not force:
        fail(f"{config.out}: a bundle already exists at the default output (artifacts/kb/{name}); "
             "pass --out DIR for a new bundle, or --force to replace it (nothing was written)")
    if quiet:  # the text encoder's weight-loading bar (transformers) reads this when it loads
        os.environ["HF_HUB_DISABLE_PROGRESS_BARS"] = "1"
    try:
        with _progress(quiet) as bar:
            tasks: dict[str, TaskID] = {}

            phases: list[TaskID] = []
            counted: dict[str, int] = {}

            def finish_phase() -> None:
                """Complete the current phase and its counted stages (their totals are now known)."""
                if phases:
                    bar.update(phases[-1], completed=1)
                for stage, task_id in tasks.items():
                    bar.update(task_id, total=counted[stage], completed=counted[stage])

            def tick(stage: str, n: int) -> None:
                if stage.startswith(PHASE):  # a new build phase: the last one is done
                    finish_phase()
                    phases.append(bar.add_task(stage.removeprefix(PHASE), total=1))
                    return
                if stage not in tasks:
                    tasks[stage] = bar.add_task(f"  {stage}", total=None)
                counted[stage] = counted.get(stage, 0) + n
                bar.advance(tasks[stage], n)

            batch = None
            if batch_backend is not None:
                from .cache import RecordCache
                from .sources.batch import BatchLLMSource

                batch = BatchLLMSource(
                    cache=RecordCache(config.cache_root),
                    provider=identity,
                    model=model_id,
                    backend=batch_backend,
                    max_wait_s=batch_wait,
                    log=lambda text: err.print(escape(text), highlight=False),
                )
            with cache_in_use(config.cache_root):  # cache clean waits (refuses) meanwhile
                result = run_build(config, transport=transport, progress=tick, batch=batch)
            finish_phase()
    except VocabError as exc:
        fail(str(exc))
    except SourceError as exc:
        fail(str(exc), EXIT_SOURCE_FAILED)
    except ValueError as exc:  # overrides and other input errors name their file and line
        fail(str(exc))
    except CacheError as exc:  # a damaged record or embedding is a bad input file
        fail(f"{exc} (`craftc cache verify` lists every damaged file)")
    except BundleWriteError as exc:  # read-only or full --out, a concurrent build replacing --out
        where = f" {exc.filename}" if exc.filename else ""
        fail(
            f"cannot write the bundle --out {config.out}:{where} {exc.strerror or exc}; "
            "check that the folder is writable and has free space (a build racing another "
            "build to the same --out: retry); nothing half-written was left at --out"
        )
    except OSError as exc:  # not the output (that is BundleWriteError): the cache or an input
        where = f" {exc.filename}" if exc.filename else ""
        failed = Path(os.fsdecode(exc.filename)).absolute() if exc.filename else None
        if failed is not None and Path(cache).absolute() in failed.parents:
            fail(f"cannot read{where} from the record cache ({exc.strerror or exc}): it changed while "
                 "the build read it (a `craftc cache clean --yes` at the same time?); run the build "
                 "again; nothing was written to --out")
        fail(f"cannot read{where or ' an input'} ({exc.strerror or exc}); check the build's input "
             "files and options; nothing was written to --out")
    for note in result.notes:
        err.print(f"[yellow]note:[/] {escape(note)}", highlight=False)
    m = result.manifest
    stdout.print(
        f"built [bold]{escape(m.kb_name)}[/] {m.kb_version} -> {escape(str(result.out))}\n"
        f"  content sha256 {m.content_sha256}\n"
        f"  {len(m.verbs)} verbs, {len(m.properties)} properties, {len(m.objects)} objects; "
        f"embeddings {result.embedding_hits} cached / {result.embedding_misses} computed; "
        f"{result.duration_s:.2f} s",
        highlight=False,
    )


def _progress(quiet: bool) -> Progress:
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=err,
        disable=quiet or not err.is_terminal,
    )


@app.command()
def validate(
    bundle: Annotated[
        Path, typer.Argument(help="Bundle folder, or a signed .craft file (with --trusted-key).")
    ],
    trusted_key: TrustedKeyOpt = None,
) -> None:
    """Verify a bundle: schema, per-file sha256, content hash, internal consistency, E_aff and graph.ttl = its graph's."""
    from ..runtime.kb.bundle import BundleError
    from .bundle_checks import load_and_check

    keys = trusted_keys(trusted_key)
    try:  # then E_aff and graph.ttl recomputed from graph.json: what loading skips
        kb = load_and_check(bundle, keys)
    except BundleError as exc:
        fail(str(exc), EXIT_CHECK_FAILED)
    stdout.print(
        f"ok: {kb.manifest.kb_name} {kb.manifest.kb_version} content sha256 {kb.manifest.content_sha256}",
        highlight=False,
    )


@app.command()
def diff(
    old: Annotated[Path, typer.Argument(help="Old bundle.")],
    new: Annotated[Path, typer.Argument(help="New bundle.")],
    format: Annotated[str, typer.Option("--format", help="md | json")] = "md",
    top_k: Annotated[int, typer.Option(help="Objects per verb in the behavioural diff.")] = 5,
    threshold: Annotated[float, typer.Option(help="Report weight changes larger than this.")] = 0.1,
    fail_on: Annotated[
        list[str] | None,
        typer.Option(
            "--fail-on",
            help="Gate: top1-changed | verb-removed | any-change | edges-removed>N | "
            "weight-changes>N (repeatable).",
        ),
    ] = None,
    trusted_key: TrustedKeyOpt = None,
) -> None:
    """Structural and behavioural differences between two bundles (Markdown for a PR)."""
    from ..runtime.kb.bundle import BundleError, load_bundle
    from .diff import (
        DiffError,
        diff_bundles,
        gate_failures,
        parse_rules,
        render_markdown,
    )

    if format not in ("md", "json"):
        fail(f"unknown format {format!r}; use md or json")
    try:
        parse_rules(fail_on or [])  # a typo in a gate fails before any output, not after
        keys = trusted_keys(trusted_key)
        a = load_bundle(old, check_encoder=False, trusted_keys=keys)
        b = load_bundle(new, check_encoder=False, trusted_keys=keys)
        result = diff_bundles(a, b, top_k=top_k, threshold=threshold)
        failures = gate_failures(result, fail_on or [])
    except (BundleError, DiffError) as exc:
        fail(str(exc), EXIT_BAD_INPUT)
    if format == "json":
        stdout.print_json(json.dumps(result))
    else:
        sys.stdout.write(render_markdown(result))
    for failure in failures:
        err.print(f"[bold red]gate failed:[/] {escape(failure)}", highlight=False)
    if failures:
        raise typer.Exit(EXIT_CHECK_FAILED)


@app.command()
def explain(
    bundle: Annotated[
        Path, typer.Argument(help="Bundle folder, or a signed .craft file (with --trusted-key).")
    ],
    verb: Annotated[str, typer.Argument(help="Verb, e.g. cut.")],
    obj: Annotated[str, typer.Argument(metavar="OBJECT", help="Object, e.g. knife.")],
    trusted_key: TrustedKeyOpt = None,
) -> None:
    """Print the verb -> property -> object paths behind E_aff(verb, object)."""
    from ..runtime.grounding.explain import UnknownNameError, explain_pair
    from ..runtime.kb.bundle import BundleError, load_bundle

    keys = trusted_keys(trusted_key)
    try:
        kb = load_bundle(bundle, check_encoder=False, trusted_keys=keys)
        text = explain_pair(kb, verb, obj).render()
    except (BundleError, UnknownNameError) as exc:
        fail(str(exc))
    sys.stdout.write(text + "\n")


@app.command()
def review(
    ctx: typer.Context,
    bundle: Annotated[
        Path, typer.Argument(help="Bundle folder, or a signed .craft file (with --trusted-key).")
    ],
    sample: Annotated[
        int, typer.Option(min=1, help="How many random verb -> property -> object paths.")
    ] = 20,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    trusted_key: TrustedKeyOpt = None,
) -> None:
    """Print random verb -> property -> object paths with weights, for a human read."""
    import random

    from ..runtime.cli.common import note
    from ..runtime.kb.bundle import BundleError, load_bundle

    keys = trusted_keys(trusted_key)
    try:
        kb = load_bundle(bundle, check_encoder=False, trusted_keys=keys)
    except BundleError as exc:
        fail(str(exc))
    paths = kb.paths()
    # a --sample typed beyond the paths: said (as --jobs beyond the CPUs), then done with what
    # there is; the default 20 on a small bundle is no request to be told about
    # (by name: typer's Context is its own vendored click's, whose enum is not click's)
    source = ctx.get_parameter_source("sample")
    if source is not None and source.name == "COMMANDLINE" and sample > len(paths):
        note(f"--sample {sample}: the bundle has {len(paths)} verb -> property -> object paths; "
             f"printing all {len(paths)}")
    rng = random.Random(seed)
    for p in rng.sample(paths, min(sample, len(paths))):
        sys.stdout.write(f"{p.verb} -({p.w_vp:.2f})-> {p.prop} -({p.w_po:.2f})-> {p.obj}\n")


@app.command()
def schema(
    write: Annotated[bool, typer.Option(help="Regenerate schemas/v1/json/*.schema.json.")] = False,
) -> None:
    """Print (or regenerate) the JSON Schemas of every v1 artifact."""
    from ..schemas.generate import SCHEMA_DIR, generate_all, write_all

    if write:
        for path in write_all():
            stdout.print(f"wrote {escape(str(path))}", highlight=False)
        return
    sys.stdout.write(
        json.dumps({k: v for k, v in generate_all().items()}, indent=2, sort_keys=True) + "\n"
    )
    err.print(f"(committed copies live in {escape(str(SCHEMA_DIR))})", highlight=False)


@cache_app.command("verify")
def cache_verify(cache: ExistingCacheOpt = CACHE_DIR) -> None:
    """Re-hash every record; report corrupt and orphaned files (exit 1 if any)."""
    from .cache import CacheError, RecordCache

    try:
        report = RecordCache(cache).verify()
    except (CacheError, OSError) as exc:
        fail(str(exc), EXIT_CHECK_FAILED)
    for _path, why in report.corrupt:
        err.print(f"[red]corrupt:[/] {escape(why)}", highlight=False)
    for path in report.orphaned:
        err.print(f"[yellow]orphaned:[/] {escape(str(path))}", highlight=False)
    for path in report.unindexed:
        err.print(
            f"[red]unindexed:[/] {escape(str(path))} (not in SHA256SUMS; check it, then run "
            "`craftc cache index`)",
            highlight=False,
        )
    if report.embeddings_unindexed:
        err.print(
            f"[yellow]note:[/] {len(report.embeddings_unindexed)} cached embeddings are not in "
            "their INDEX.tsv (an older cache); builds re-embed them instead of trusting them",
            highlight=False,
        )
    unindexed = f", {len(report.unindexed)} unindexed" if report.unindexed else ""
    stdout.print(
        f"checked {report.checked} records: {len(report.corrupt)} corrupt, "
        f"{len(report.orphaned)} orphaned{unindexed}; {report.embeddings_checked} embeddings",
        highlight=False,
    )
    if not report.ok:
        raise typer.Exit(EXIT_CHECK_FAILED)


@cache_app.command("index")
def cache_index(cache: ExistingCacheOpt = CACHE_DIR) -> None:
    """Add records missing from each source's SHA256SUMS (never changes an existing entry)."""
    from .cache import CacheError, RecordCache

    store = RecordCache(cache)
    bad = 0
    try:
        for source in store.sources():
            added, pruned, mismatched = store.build_index(source)
            for path, why in mismatched:
                err.print(f"[red]not indexed:[/] {escape(str(path))}: {escape(why)}", highlight=False)
            bad += len(mismatched)
            stdout.print(
                f"{source}: {len(added)} added, {len(pruned)} entries of deleted files dropped, "
                f"{len(mismatched)} left out",
                highlight=False,
            )
    except (CacheError, OSError) as exc:
        fail(str(exc), EXIT_BAD_INPUT)
    if bad:
        raise typer.Exit(EXIT_CHECK_FAILED)


@cache_app.command("stats")
def cache_stats(
    cache: ExistingCacheOpt = CACHE_DIR,
    table: Annotated[
        bool, typer.Option(help="A table per source/provider/model/prompt version instead of JSON.")
    ] = False,
) -> None:
    """Records and bytes per source, provider, model and prompt version."""
    from .cache import RecordCache

    store = RecordCache(cache)
    if not table:
        stdout.print_json(json.dumps(store.stats()))
        return
    from rich.table import Table

    view = Table("source", "provider", "model", "prompt", "version", "records", "bytes")
    for row in store.stats_rows():
        view.add_row(*(escape(x) for x in (row.source, row.provider, row.model, row.prompt,
                                           row.version)), str(row.records), f"{row.bytes:,}")
    stdout.print(view)


@cache_app.command("clean")
def cache_clean(
    ctx: typer.Context,
    cache: ExistingCacheOpt = CACHE_DIR,
    verbs: Annotated[
        Path | None, typer.Option(help="Also keep what a replay build of these verbs reads.")
    ] = None,
    objects: Annotated[Path, typer.Option(help="Objects file of that build.")] = VOCAB_DIR
    / "union_objects.txt",
    mode: Annotated[
        list[str] | None,
        typer.Option(help="Modes of that build: llm | direct | llm+direct (repeatable; default llm)."),
    ] = None,
    prompts: PromptsOpt = DEFAULT_PROMPT_VERSION,
    property_pass: Annotated[bool, typer.Option(help="That build reads stage 2b too.")] = False,
    record_provider: Annotated[str, typer.Option(help="Whose records that build replays.")] = "curated",
    model: Annotated[str, typer.Option(help="Model id of those records.")] = "craft-e-curators",
    bundles: Annotated[
        list[Path] | None,
        typer.Option(
            help="Bundle folders (or folders of bundles) whose records are kept "
            "(repeatable; default: every shipped bundle, artifacts/kb)."
        ),
    ] = None,
    yes: Annotated[bool, typer.Option("--yes", help="Delete (default: a dry run).")] = False,
) -> None:
    """Drop llm records no build references (a dry run unless --yes).

    Kept: every record a bundle's graph.json provenance or its object_sizes.json /
    object_colours.json names (and records of the same provider, model, prompt and subject);
    a --bundles path that does not exist is an error; and with --verbs every record a replay build of
    those inputs reads. SHA256SUMS stays consistent.
    """
    from .cache import CacheBusyError, CacheError, RecordCache, cache_for_cleaning
    from .cache_clean import (
        ReferencesError,
        build_references,
        bundle_references,
        check_modes,
        plan_clean,
        with_siblings,
    )
    from .sources.llm import LLM_SOURCE, SourceError
    from .vocab import VocabError

    # every option before the lock and the plan, with or without --verbs (which alone reads them)
    try:
        check_modes(mode or [])
    except ReferencesError as exc:
        fail(str(exc))
    version = _prompt_version(prompts)
    if yes:  # plan and delete while no build or curate record runs on this cache (held to the end)
        try:
            ctx.with_resource(cache_for_cleaning(cache))
        except CacheBusyError as exc:
            fail(str(exc))
        except OSError as exc:
            fail(f"{cache}: cannot lock the cache for cleaning ({exc.strerror}); nothing deleted")
    store = RecordCache(cache)
    try:
        keys, graphs = bundle_references(bundles, strict=True) if bundles else bundle_references(
            [KB_DIR], strict=False)
        referenced = with_siblings(store, keys)
        if verbs is not None:
            referenced |= build_references(
                store, verbs, objects, mode or ["llm"], provider=record_provider, model=model,
                prompt_version=version, property_pass=property_pass,
            )
        elif not graphs:
            fail("no bundle found to keep records for (--bundles) and no build given (--verbs); "
                 "refusing to call every record unreferenced")
        plan = plan_clean(store, referenced, graphs)
    except (ReferencesError, VocabError) as exc:
        fail(str(exc))
    except SourceError as exc:
        fail(f"{exc} (the build's references are unknown; nothing deleted)", EXIT_SOURCE_FAILED)
    except (CacheError, OSError) as exc:
        fail(str(exc))
    if yes and plan.drop:
        try:
            store.remove(LLM_SOURCE, [path.stem for path, _ in plan.drop])
        except (CacheError, OSError) as exc:
            fail(str(exc), EXIT_CHECK_FAILED)
    for path, label in plan.drop:
        err.print(f"{'deleted' if yes else 'would delete'}: {escape(path.name)}  {escape(label)}",
                  highlight=False)
    verb = "deleted" if yes else "would delete"
    stdout.print(
        f"{len(plan.graphs)} bundles read; {plan.kept} records referenced; {verb} "
        f"{len(plan.drop)} ({plan.drop_bytes:,} bytes)"
        + ("" if yes or not plan.drop else "; run again with --yes to delete them"),
        highlight=False,
    )


@curate_app.command("record")
def curate_record(
    prompt: Annotated[
        str,
        typer.Option(
            help="verb_properties | object_properties | property_objects | verb_objects | object_size | "
            "object_colour | object_lookalike"
        ),
    ],
    answers: Annotated[Path, typer.Option(help="JSONL file: one answer payload per line.")],
    verbs: Annotated[
        Path, typer.Option(help="Verbs file (defines the property set for objects).")
    ] = VOCAB_DIR / "union_verbs.txt",
    objects: Annotated[Path, typer.Option(help="Objects file.")] = VOCAB_DIR / "union_objects.txt",
    cache: CacheOpt = CACHE_DIR,
    prompts: PromptsOpt = DEFAULT_PROMPT_VERSION,
) -> None:
    """Store written answers as provider-'curated' records of their rendered prompts.

    Every answer is validated before any is stored (a bad line stores nothing). A prompt that
    already has a different stored answer is an error: stored answers are never rewritten.
    """
    from .cache import RecordCache, cache_in_use
    from .curate import PROMPT_IDS, CurationError, read_answers, record_answers
    from .sources.llm import LLMSource, SourceError
    from .vocab import VocabError, read_vocabulary

    try:
        # the prompt and the answers file first: a refused run must not create --cache or its lock
        if prompt not in PROMPT_IDS:
            raise CurationError(f"unknown prompt {prompt!r}; choose one of {', '.join(PROMPT_IDS)}")
        read_answers(answers)
        vv = read_vocabulary(verbs, kind="verbs")
        ov = read_vocabulary(objects, kind="objects")
        with cache_in_use(cache):
            result = record_answers(
                LLMSource(RecordCache(cache)),
                prompt,
                answers,
                vv.names,
                ov.names,
                version=_prompt_version(prompts),
                glosses=ov.glosses,
                verb_glosses=vv.glosses,
            )
    except (CurationError, VocabError) as exc:
        fail(str(exc))
    except SourceError as exc:
        fail(str(exc), EXIT_SOURCE_FAILED)
    for line in result.skipped:
        err.print(f"[yellow]skipped:[/] {escape(line)}", highlight=False)
    stdout.print(
        f"stored {result.stored} records, {result.unchanged} unchanged, {len(result.skipped)} skipped"
    )
    if result.not_stored:  # a script must notice: these answers are not in the cache
        err.print(f"{result.not_stored} answer(s) of {answers} were not stored: their subject is in neither "
                  "--verbs nor --objects; pass the files that name them and run again (stored answers stay "
                  "as they are)", highlight=False, markup=False)
        raise typer.Exit(EXIT_CHECK_FAILED)


@curate_app.command("pending")
def curate_pending(
    verbs: Annotated[Path, typer.Option(help="Verbs file.")] = VOCAB_DIR / "union_verbs.txt",
    objects: Annotated[Path, typer.Option(help="Objects file.")] = VOCAB_DIR / "union_objects.txt",
    cache: CacheOpt = CACHE_DIR,
    prompts: PromptsOpt = DEFAULT_PROMPT_VERSION,
    prompt: Annotated[
        str,
        typer.Option(
            help="object_properties (stage 2) | property_objects (stage 2b) | verb_objects "
            "(direct) | verb_properties (stage 1) | object_size (typical sizes, for perception) | "
            "object_colour (typical colours, for perception) | object_lookalike (the ImageNet classes "
            "photos of an object get, for perception)."
        ),
    ] = "object_properties",
) -> None:
    """List prompts with no answer yet (subject, gloss or definition, named set, rendered
    prompt), as JSON."""
    from .cache import RecordCache
    from .curate import (
        pending_colour_requests,
        pending_direct_requests,
        pending_lookalike_requests,
        pending_object_requests,
        pending_property_requests,
        pending_size_requests,
        pending_verb_requests,
    )
    from .sources.llm import LLMSource, SourceError
    from .vocab import VocabError, read_vocabulary

    try:
        vv = read_vocabulary(verbs, kind="verbs")
        ov = read_vocabulary(objects, kind="objects")
        listers = {
            "object_properties": pending_object_requests,
            "property_objects": pending_property_requests,
            "verb_objects": pending_direct_requests,
            "verb_properties": pending_verb_requests,
            "object_size": pending_size_requests,
            "object_colour": pending_colour_requests,
            "object_lookalike": pending_lookalike_requests,
        }
        if prompt not in listers:
            fail(f"unknown prompt {prompt!r}; choose one of {', '.join(listers)}")
        lister = listers[prompt]
        pending = lister(
            LLMSource(RecordCache(cache)),
            vv.names,
            ov.names,
            version=_prompt_version(prompts),
            glosses=ov.glosses,
            verb_glosses=vv.glosses,
        )
    except VocabError as exc:
        fail(str(exc))
    except SourceError as exc:
        fail(str(exc), EXIT_SOURCE_FAILED)
    sys.stdout.write(json.dumps(pending, indent=1) + "\n")


# Commands that live in their own modules (packing/signing, diagnostics); they import nothing
# from this module.
register_pack(app)
register_diagnose(app)


def main() -> None:  # pragma: no cover - console entry
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    exit_through_python_on_sigterm()
    app()
