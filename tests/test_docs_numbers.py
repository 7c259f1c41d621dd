"""The README's bundle table states what the shipped bundles' report.json files say.

A table of counts goes stale silently when a bundle is rebuilt with more objects; this reads
each row and compares it with the bundle it names.
"""

from __future__ import annotations

import importlib.util
import json
import re
from decimal import ROUND_HALF_UP, Decimal
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


CURRENT = re.compile(r"^\| sim-(dev|val), \d+ episodes(, new layouts)? \| `craft eval sim [^`]*--markdown (?P<md>\S+)` \|"
                     r"(?P<cells>( [\d.]+ / [\d.]+ \|){4})$")
RESULT_ROW = re.compile(r"^\| (?P<method>[A-Za-z-]+) \| [\d.]+ \| (?P<detect>[\d.]+) \| (?P<gr>[\d.]+) \|$")


def test_readme_current_testbed_numbers_are_the_committed_tables() -> None:
    """The README's "testbed's current numbers" table (Detect / Grasp Rate per method, rounded to
    0.1) states what the results file its command writes holds: re-running a table and forgetting
    the README would otherwise leave a newcomer reading stale numbers."""
    rows = [m for line in (REPO_ROOT / "README.md").read_text(encoding="utf-8").splitlines()
            if (m := CURRENT.match(line))]
    assert len(rows) == 4  # seed 0 and new layouts (--seed 1), sim-dev and sim-val
    def tenth(text: str) -> Decimal:  # 64.55 reads 64.6, as a person rounds the table's digits
        return Decimal(text).quantize(Decimal("0.1"), rounding=ROUND_HALF_UP)

    for m in rows:
        results = {r["method"]: (tenth(r["detect"]), tenth(r["gr"]))
                   for line in (REPO_ROOT / m["md"]).read_text(encoding="utf-8").splitlines()
                   if (r := RESULT_ROW.match(line))}
        stated = [tuple(Decimal(x) for x in cell.split(" / ")) for cell in m["cells"].strip(" |").split(" | ")]
        for method, pair in zip(("CRAFT-E", "direct-LLM", "CRAFT", "alignment-only"), stated, strict=True):
            assert pair == results[method], (m["md"], method, pair, results[method])
