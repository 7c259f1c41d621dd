"""The README's bundle table states what the shipped bundles' report.json files say.

A table of counts goes stale silently when a bundle is rebuilt with more objects; this reads
each row and compares it with the bundle it names.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

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
