"""The example KB-review workflow builds the KB that ships, as ``scripts/build_kbs`` builds it.

Why: ``examples/ci/kb-diff.yml`` is what a team copies to review knowledge changes. It once built
the default KB without stage 2b and the object pass's reuse (``--property-pass --object-pass
reuse``) over the benchmark's objects, so its first step stopped at exit 3 ("no record for
object_properties@v2 ...") on the shipped cache. ``tests/test_shipped_bundles.py`` rebuilds the
shipped bundles with build_kbs's settings; this test keeps the workflow's build line the same.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: options that say where a build reads or writes, not what it builds
WHERE = {"--out", "--cache", "--name", "--provider"}


def _options(args: list[str]) -> dict[str, str]:
    """``--flag value`` / ``--switch`` pairs of a craftc build line, minus ``WHERE`` and ``--quiet``."""
    out: dict[str, str] = {}
    i = 0
    while i < len(args):
        flag = args[i]
        value = args[i + 1] if i + 1 < len(args) and not args[i + 1].startswith("--") else ""
        if flag not in WHERE and flag != "--quiet":
            out[flag] = value
        i += 2 if value else 1
    return out


def _workflow_build() -> dict[str, str]:
    text = (ROOT / "examples" / "ci" / "kb-diff.yml").read_text(encoding="utf-8")
    env = dict(re.findall(r"^  ([A-Z_]+): (.+)$", text.split("\njobs:")[0], flags=re.M))
    step = re.search(r"^ +craftc build (.*?)--quiet", text, flags=re.S | re.M)
    assert step is not None, "no craftc build step in the workflow"
    line = step.group(1).replace("\\\n", " ")
    for name, value in env.items():
        line = line.replace(f'"${name}"', value.strip('"')).replace(f"${name}", value.strip('"'))
    return _options(shlex.split(line))


def _shipped_build() -> dict[str, str]:
    text = (ROOT / "scripts" / "build_kbs").read_text(encoding="utf-8")
    variables = dict(re.findall(r'^([A-Z])="?([^"\n]*)"?$', text, flags=re.M))
    line = next(row for row in text.splitlines() if "--name craft-e-default" in row)
    line = line.split("$C build", 1)[1].replace('"$@"', "")
    for _ in range(2):  # $D holds $V
        for name, value in variables.items():
            line = line.replace(f'"${name}/', f'"{value}/').replace(f"${name}", value)
    return _options(shlex.split(line))


def test_the_workflow_builds_the_shipped_default_kb() -> None:
    shipped = _shipped_build()
    assert shipped["--verbs"] == "artifacts/vocab/union_verbs.txt" and "--property-pass" in shipped
    assert _workflow_build() == shipped
