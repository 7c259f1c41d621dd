"""The runtime must not pull in the compiler, httpx or rdflib (robots ship without them)."""

from __future__ import annotations

import json
import subprocess
import sys

RUNTIME_MODULES = [
    "craft_e.runtime.bundle",
    "craft_e.runtime.energies",
    "craft_e.runtime.grounding",
    "craft_e.runtime.explain",
    "craft_e.runtime.plotting",
    "craft_e.runtime.encoders",
    "craft_e.runtime.encoders.text",
    "craft_e.runtime.encoders.image",
    "craft_e.runtime.encoders.efficientnet",
    "craft_e.runtime.encoders.conse",
    "craft_e.runtime.encoders.clip",
    "craft_e.runtime.evaluation.common",
    "craft_e.runtime.evaluation.imagenet",
    "craft_e.runtime.cli",
]
FORBIDDEN = ("craft_e.compiler", "httpx", "rdflib")


def test_runtime_imports_no_compiler_httpx_rdflib() -> None:
    code = (
        "import importlib, json, sys\n"
        f"for name in {RUNTIME_MODULES!r}:\n"
        "    importlib.import_module(name)\n"
        f"bad = sorted(m for m in sys.modules if m.split('.')[0] in {FORBIDDEN!r} or m.startswith('craft_e.compiler'))\n"
        "print(json.dumps(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []
