"""``craftc diagnose BUNDLE``: discrimination diagnostics of any bundle, in one or every E_aff form.

The same numbers as ``report.json``'s ``diagnostics`` (``craft_e.runtime.kb.diagnostics``), but
computed from the bundle's graph, so they work on bundles built before the report carried them
and for E_aff forms other than the one the bundle was built with.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from ..runtime.cli.common import fail
from .cli_options import TrustedKeyOpt, trusted_keys

if TYPE_CHECKING:
    from ..runtime.grounding.energies import EnergyForm


def chosen_forms(values: list[str] | None) -> list[EnergyForm] | None:
    """``--energy-form`` values as the forms to diagnose (None: the bundle's own), checked before
    the bundle loads: every value must be a form or ``all`` (an unknown one beside ``all`` was
    ignored), else exit 2 naming each unknown value and the valid ones."""
    from ..runtime.grounding.energies import ENERGY_FORMS, check_energy_form

    if not values:
        return None
    unknown = [v for v in values if v != "all" and v not in ENERGY_FORMS]
    if unknown:
        fail(f"--energy-form {', '.join(map(repr, unknown))}: unknown E_aff form{'s' if len(unknown) > 1 else ''}; "
             f"use one of {', '.join(ENERGY_FORMS)}, or all (every form); repeat the option for several")
    return list(ENERGY_FORMS) if "all" in values else [check_energy_form(v) for v in dict.fromkeys(values)]


def register(app: typer.Typer) -> None:
    @app.command()
    def diagnose(
        bundle: Annotated[
            Path, typer.Argument(help="Bundle folder, or a signed .craft file (with --trusted-key).")
        ],
        energy_form: Annotated[
            list[str] | None,
            typer.Option(
                "--energy-form",
                help="E_aff form(s) to diagnose (repeatable; 'all' = every form; default: the "
                "bundle's own).",
            ),
        ] = None,
        format: Annotated[str, typer.Option("--format", help="md | json")] = "md",
        trusted_key: TrustedKeyOpt = None,
    ) -> None:
        """Affordant and saturated shares, hub objects, dead properties, per-verb margins."""
        from ..runtime.grounding.grounder import affordance_energy_in_form
        from ..runtime.kb.bundle import BundleError, load_bundle
        from ..runtime.kb.diagnostics import (
            bundle_diagnostics,
            dead_property_notes,
            markdown_summary,
        )

        if format not in ("md", "json"):
            fail(f"unknown format {format!r}; use md or json")
        given = chosen_forms(energy_form)  # before the bundle loads
        keys = trusted_keys(trusted_key)
        try:
            kb = load_bundle(bundle, check_encoder=False, trusted_keys=keys)
        except BundleError as exc:
            fail(str(exc))
        forms = given or [kb.manifest.energy.form]
        columns: dict[str, dict[str, Any]] = {
            form: bundle_diagnostics(kb, affordance_energy_in_form(kb, form)) for form in forms
        }
        if format == "json":
            data = {"kb_name": kb.manifest.kb_name, "content_sha256": kb.manifest.content_sha256,
                    "forms": columns}
            sys.stdout.write(json.dumps(data, indent=1, sort_keys=True) + "\n")
            return
        sys.stdout.write(f"## Discrimination diagnostics of `{kb.manifest.kb_name}` "
                         f"{kb.manifest.kb_version}\n\n" + markdown_summary(columns))
        dead = sorted({p for c in columns.values() for p in c["properties_reaching_no_object"]})
        if dead:  # the same for every form: whether an edge reaches tau does not depend on it
            sys.stdout.write("\nProperties reaching no object:\n" + "\n".join(dead_property_notes(kb, dead)) + "\n")
