"""The README's bundle table states what the shipped bundles' report.json files say.

A table of counts goes stale silently when a bundle is rebuilt with more objects; this reads
each row and compares it with the bundle it names.
"""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import pytest

from craft_e.paths import KB_DIR

REPO_ROOT = Path(__file__).resolve().parents[1]

ROW = re.compile(r"^\| `(?P<kb>[a-z0-9-]+)` \|[^|]*\| (?P<form>[a-z-]+) \| (?P<verbs>[\d,]+) \| "
                 r"(?P<props>[\d,]+)[^|]*\| (?P<objects>[\d,]+) \| (?P<edges>[\d,]+) \|$")


def _int(text: str) -> int:
    return int(text.replace(",", ""))


def test_readme_bundle_table_matches_the_reports() -> None:
    rows = [m for line in (REPO_ROOT / "README.md").read_text(encoding="utf-8").splitlines()
            if (m := ROW.match(line))]
    assert {m["kb"] for m in rows} >= {"craft-e-default", "craft-e-properties", "craft-e-v1", "direct-llm",
                                       "conceptnet", "local-llm"}
    for m in rows:
        folder = KB_DIR / m["kb"]
        manifest = json.loads((folder / "manifest.json").read_text(encoding="utf-8"))
        counts = json.loads((folder / "report.json").read_text(encoding="utf-8"))["counts"]
        stated = (_int(m["verbs"]), _int(m["props"]), _int(m["objects"]), _int(m["edges"]))
        actual = (len(manifest["verbs"]), len(manifest["properties"]), len(manifest["objects"]),
                  counts["property_object_edges"])
        assert stated == actual, (m["kb"], stated, actual)


def test_serving_doc_example_is_the_example_scripts_answer(capsys: pytest.CaptureFixture[str]) -> None:
    """docs/serving.md shows the answer of examples/serving/ground_request.py, rounded."""
    spec = importlib.util.spec_from_file_location("ground_request", REPO_ROOT / "examples/serving/ground_request.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main()
    answer = json.loads(capsys.readouterr().out)
    doc = (REPO_ROOT / "docs/serving.md").read_text(encoding="utf-8")
    best = answer["ranked"][0]
    assert answer["chosen"] == 0 and answer["kb_content_sha256"][:8] in doc
    for key in ("e_grasp", "e_aff", "e_align", "total"):
        assert f'"{key}": {best[key]:.3f}' in doc, key
    assert f'"p": {best["hypotheses"][0]["p"]:.3f}' in doc
    assert f'"property": "{best["paths"][1]["property"]}"' in doc or f'"property": "{best["paths"][0]["property"]}"' in doc
