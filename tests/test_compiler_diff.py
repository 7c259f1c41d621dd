"""``craftc diff``: fixture pairs (bundle A, bundle B -> ``diff/*.expected.json``), gates, Markdown.

The behavioural diff is what a KB reviewer relies on to notice that an edit changed which object
the robot hands over, so these tests pin it on real (fixture) bundles: a revised "scoop" answer
must show up as a top-1 change spoon -> cup, and a vocabulary change as added/removed names.
"""

from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import FIXTURES, FixtureKB, build_config

from craft_e.compiler.build import build
from craft_e.compiler.diff import (
    VALID_RULES,
    DiffError,
    diff_bundles,
    gate_failures,
    parse_rules,
    render_markdown,
    top_objects,
)
from craft_e.runtime.kb.bundle import Bundle, load_bundle

EXPECTED = FIXTURES / "diff"
ALL_RULES = ["top1-changed", "verb-removed", "any-change", "edges-removed>0", "weight-changes>0"]


def _load(kb: FixtureKB) -> Bundle:
    return load_bundle(kb.bundle, check_encoder=False)


def _comparable(result: dict[str, Any]) -> dict[str, Any]:
    """The diff without the two bundles' identity (paths and hashes vary between machines)."""
    return {k: v for k, v in result.items() if k not in ("a", "b", "identical")}


@pytest.fixture(scope="module")
def base(kb_a: FixtureKB) -> Bundle:
    return _load(kb_a)


@pytest.mark.parametrize("case", ["scoop_v2", "b2"])
def test_diff_fixture_pairs(
    case: str, base: Bundle, kb_scoop_v2: FixtureKB, kb_b2: FixtureKB
) -> None:
    other = {"scoop_v2": kb_scoop_v2, "b2": kb_b2}[case]
    result = diff_bundles(base, _load(other))
    expected = json.loads((EXPECTED / f"{case}.expected.json").read_text("utf-8"))
    assert _comparable(result) == expected
    assert json.loads(json.dumps(result)) == result, "the result is plain JSON"


def test_identical_bundles_have_no_differences(base: Bundle, kb_a: FixtureKB) -> None:
    result = diff_bundles(base, _load(kb_a))
    assert result["identical"]
    assert all(v == 0 for k, v in result["summary"].items() if k != "verbs_compared")
    assert result["summary"]["verbs_compared"] == 3
    assert not any(r["order_changed"] or r["top1_changed"] for r in result["behaviour"])
    assert gate_failures(result, ALL_RULES) == []
    markdown = render_markdown(result)
    assert "**No changes**" in markdown
    assert base.manifest.content_sha256[:16] in markdown


def test_revised_answer_flips_top1(base: Bundle, kb_scoop_v2: FixtureKB) -> None:
    result = diff_bundles(base, _load(kb_scoop_v2))
    rows = {r["verb"]: r for r in result["behaviour"]}
    assert (rows["scoop"]["top1_a"], rows["scoop"]["top1_b"]) == ("spoon", "cup")
    assert rows["scoop"]["top1_changed"] and not rows["scoop"]["entered"]
    assert not rows["cut"]["order_changed"] and not rows["pour"]["order_changed"]
    assert [r["object"] for r in rows["scoop"]["b"]] == ["cup", "bowl", "spoon", "knife"]
    assert result["a"]["content_sha256"] != result["b"]["content_sha256"]
    # 0.2 -> 0.1 is a change of exactly the threshold, which is not "over" it
    changed = {(w["verb"], w["property"]): w["delta"] for w in result["weight_changes"]}
    assert changed == {
        ("scoop", "shallow bowl shape"): -0.7,
        ("scoop", "holds liquid"): 0.4,
        ("scoop", "rounded"): -0.3,
    }


def test_threshold_and_top_k(base: Bundle, kb_scoop_v2: FixtureKB) -> None:
    b = _load(kb_scoop_v2)
    assert len(diff_bundles(base, b, threshold=0.0)["weight_changes"]) == 4
    assert len(diff_bundles(base, b, threshold=0.5)["weight_changes"]) == 1
    one = diff_bundles(base, b, top_k=1)
    assert all(len(r["a"]) <= 1 and len(r["b"]) <= 1 for r in one["behaviour"])
    with pytest.raises(DiffError, match="top_k"):
        diff_bundles(base, b, top_k=0)
    with pytest.raises(DiffError, match="threshold"):
        diff_bundles(base, b, threshold=-1)


def test_structural_change(base: Bundle, kb_b2: FixtureKB) -> None:
    result = diff_bundles(base, _load(kb_b2))
    assert result["verbs"] == {"added": [], "removed": ["pour"]}
    assert result["objects"] == {"added": ["ladle"], "removed": ["cup"]}
    assert result["properties"]["removed"] == ["has a spout", "open top", "waterproof"]
    assert [r["verb"] for r in result["behaviour"]] == ["cut", "scoop"], "only verbs in both"
    scoop = next(r for r in result["behaviour"] if r["verb"] == "scoop")
    assert scoop["entered"] == ["ladle"] and scoop["left"] == ["cup"]
    failures = gate_failures(result, ["verb-removed", "edges-removed>15", "edges-removed>16"])
    assert failures == [
        "verb-removed: 1 verb(s) removed: pour",
        "edges-removed>15: 16 edges removed (allowed at most 15)",
    ]


def test_settings_change_is_reported(base: Bundle, kb_a: FixtureKB, tmp_path: Path) -> None:
    config = build_config(kb_a.cache, tmp_path / "np").model_copy(
        update={"energy_form": "normalized-product"}
    )
    build(config)
    result = diff_bundles(base, load_bundle(tmp_path / "np", check_encoder=False))
    assert result["settings_changed"] == [
        {"setting": "energy_form", "a": "sum-tanh", "b": "normalized-product"}
    ]
    assert result["edges"]["verb_property"] == {"added": [], "removed": []}
    assert "setting `energy_form` changed" in render_markdown(result)


def test_top_objects_ranks_reachable_objects_and_breaks_ties_by_name(base: Bundle) -> None:
    assert [r["object"] for r in top_objects(base, "cut", 5)] == ["knife", "spoon", "cup"]
    energy = base.energy.copy()
    row = base.verb_index["scoop"]
    energy[row] = np.float32(-0.5)  # every object ties
    energy[row, base.object_index["cup"]] = np.float32(1.0)  # "never pick"
    tied = dataclasses.replace(base, energy=energy)
    assert [r["object"] for r in top_objects(tied, "scoop", 5)] == ["bowl", "knife", "spoon"]
    assert [r["object"] for r in top_objects(tied, "scoop", 2)] == ["bowl", "knife"]


def test_gate_rules() -> None:
    assert parse_rules(
        ["top1-changed,verb-removed", " weight-changes > 2 ", "EDGES-REMOVED>0"]
    ) == ["top1-changed", "verb-removed", "weight-changes>2", "edges-removed>0"]
    with pytest.raises(DiffError) as info:
        parse_rules(["top1_changed"])
    assert "'top1_changed'" in str(info.value)
    for rule in VALID_RULES:
        assert rule in str(info.value)
    with pytest.raises(DiffError, match=r"needs a bound, e\.g\. edges-removed>0"):
        parse_rules(["edges-removed"])
    with pytest.raises(DiffError):
        parse_rules(["verbs-added>1"])
    assert issubclass(DiffError, ValueError)


def test_gates_on_a_changed_kb(base: Bundle, kb_scoop_v2: FixtureKB) -> None:
    result = diff_bundles(base, _load(kb_scoop_v2))
    failures = gate_failures(result, ALL_RULES)
    assert [f.split(":")[0] for f in failures] == [
        "top1-changed",
        "any-change",
        "edges-removed>0",
        "weight-changes>0",
    ]
    assert "scoop (spoon -> cup)" in failures[0]
    assert gate_failures(result, ["weight-changes>3", "edges-removed>2", "verb-removed"]) == []
    assert gate_failures(result, []) == []


def test_markdown_for_a_pull_request(
    base: Bundle, kb_scoop_v2: FixtureKB, kb_b2: FixtureKB
) -> None:
    md = render_markdown(diff_bundles(base, _load(kb_scoop_v2)))
    assert md.startswith("## KB diff: `fixture-kb` 1.0.0 → `fixture-kb` 1.0.0\n")
    assert "**1** of 3 verbs changed their top-1 object" in md
    assert "| `scoop` ⚠️ | `spoon` | `cup` | — | — |" in md
    assert "| `scoop` → `shallow bowl shape` | 0.8 | 0.1 | -0.7 |" in md
    assert "- Properties removed (1): `long`" in md
    assert md.endswith("\n") and not md.endswith("\n\n")
    # short tables stay open, long ones fold into <details>
    assert "edges added or removed</summary>" not in md
    long_md = render_markdown(diff_bundles(base, _load(kb_b2)))
    assert "<details><summary>22 edges added or removed</summary>" in long_md
    assert long_md.count("<details>") == long_md.count("</details>")


def test_markdown_escapes_table_cells(base: Bundle, kb_scoop_v2: FixtureKB) -> None:
    result = copy.deepcopy(diff_bundles(base, _load(kb_scoop_v2)))
    result["weight_changes"][0]["property"] = "a|b"
    assert "`a\\|b`" in render_markdown(result)


def test_markdown_stays_under_the_pr_comment_limit(base: Bundle, kb_b2: FixtureKB) -> None:
    """A whole-KB rewrite removes thousands of edges; tables are cut, JSON keeps everything."""
    result = copy.deepcopy(diff_bundles(base, _load(kb_b2)))
    many = [{"verb": f"verb {i:04d}", "property": "sharp", "weight": 0.5} for i in range(5000)]
    result["edges"] = {
        "verb_property": {"added": [], "removed": many},
        "property_object": {"added": [], "removed": []},
    }
    result["verbs"]["removed"] = [f"verb {i:04d}" for i in range(5000)]
    markdown = render_markdown(result)
    assert len(markdown) < 65_536
    assert "… and 4900 more rows (see `craftc diff --format json`)" in markdown
    assert "… and 4900 more" in markdown.split("- <details><summary>Verbs removed (5000)")[1]


def test_typical_size_changes_are_reported(base: Bundle) -> None:
    from craft_e.runtime.kb.sizes import TypicalSize

    old = dataclasses.replace(base, sizes={"knife": TypicalSize((0.26, 0.03, 0.02), "medium"),
                                           "spoon": TypicalSize((0.18, 0.04, 0.02), "low")})
    new = dataclasses.replace(base, sizes={"knife": TypicalSize((0.30, 0.03, 0.02), "medium"),
                                           "bowl": TypicalSize((0.16, 0.16, 0.07), "medium")},
                              manifest=base.manifest.model_copy(update={"content_sha256": "f" * 64}))
    result = diff_bundles(old, new)
    assert result["sizes"] == {
        "added": ["bowl"], "removed": ["spoon"],
        "changed": [{"object": "knife", "a": {"dimensions_cm": [26.0, 3.0, 2.0], "variability": "medium"},
                     "b": {"dimensions_cm": [30.0, 3.0, 2.0], "variability": "medium"}}],
    }
    assert (result["summary"]["sizes_added"], result["summary"]["sizes_removed"],
            result["summary"]["sizes_changed"]) == (1, 1, 1)
    markdown = render_markdown(result)
    assert "| typical sizes (size cue) | 1 | 1 |" in markdown
    assert "| `knife` | 26 x 3 x 2 cm, medium | 30 x 3 x 2 cm, medium |" in markdown


def test_typical_colour_changes_are_reported(base: Bundle) -> None:
    from craft_e.runtime.kb.colours import TypicalColours

    old = dataclasses.replace(base, colours={"knife": TypicalColours((("grey", 0.7),), "medium"),
                                             "spoon": TypicalColours((("grey", 0.9),), "low")})
    new = dataclasses.replace(base, colours={"knife": TypicalColours((("black", 0.3), ("grey", 0.6)), "medium"),
                                             "bowl": TypicalColours((("white", 0.9),), "high")},
                              manifest=base.manifest.model_copy(update={"content_sha256": "f" * 64}))
    result = diff_bundles(old, new)
    assert result["colours"] == {
        "added": ["bowl"], "removed": ["spoon"],
        "changed": [{"object": "knife", "a": {"colours": {"grey": 0.7}, "variability": "medium"},
                     "b": {"colours": {"black": 0.3, "grey": 0.6}, "variability": "medium"}}],
    }
    assert (result["summary"]["colours_added"], result["summary"]["colours_removed"],
            result["summary"]["colours_changed"]) == (1, 1, 1)
    markdown = render_markdown(result)
    assert "| typical colours (colour cue) | 1 | 1 |" in markdown
    assert "| `knife` | grey 0.7; medium | black 0.3, grey 0.6; medium |" in markdown
