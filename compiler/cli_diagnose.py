"""``craftc diagnose BUNDLE``: discrimination diagnostics of any bundle, in one or every E_aff form.

The same numbers as ``report.json``'s ``diagnostics`` (``craft_e.runtime.kb.diagnostics``), but
computed from the bundle's graph, so they work on bundles built before the report carried them
and for E_aff forms other than the one the bundle was built with.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer


def register(app: typer.Typer) -> None:
    @app.command()
    def diagnose(
        bundle: Annotated[Path, typer.Argument(help="Bundle folder.")],
        energy_form: Annotated[
            list[str] | None,
            typer.Option(
                "--energy-form",
                help="E_aff form(s) to diagnose (repeatable; 'all' = every form; default: the "
                "bundle's own).",
            ),
        ] = None,
        format: Annotated[str, typer.Option("--format", help="md | json")] = "md",
    ) -> None:
        """Affordant and saturated shares, hub objects, dead properties, per-verb margins."""
        from ..runtime.cli.common import fail
        from ..runtime.grounding.energies import ENERGY_FORMS, check_energy_form
        from ..runtime.grounding.grounder import affordance_energy_in_form
        from ..runtime.kb.bundle import BundleError, load_bundle
        from ..runtime.kb.diagnostics import (
            bundle_diagnostics,
            dead_property_notes,
            markdown_summary,
        )

        if format not in ("md", "json"):
            fail(f"unknown format {format!r}; use md or json")
        try:
            kb = load_bundle(bundle, check_encoder=False)
            forms = [kb.manifest.energy.form] if not energy_form else (
                list(ENERGY_FORMS) if "all" in energy_form
                else [check_energy_form(f) for f in energy_form]
            )
        except (BundleError, ValueError) as exc:
            fail(str(exc))
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
