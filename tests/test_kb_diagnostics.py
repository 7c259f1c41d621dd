"""Discrimination diagnostics on a hand-made E_aff matrix; report.json, craftc diff and diagnose."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import FixtureKB
from typer.testing import CliRunner

from craft_e.compiler.cli import app
from craft_e.compiler.diff import diff_bundles, render_markdown
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.runtime.kb.diagnostics import discrimination_diagnostics, top_k_credit
from craft_e.schemas.v1.bundle import BundleReport, Diagnostics

OBJECTS = ["a", "b", "c", "d", "e", "f"]
ENERGY = np.array([
    [-1.0, -1.0, -1.0, -0.5, 0.0, 1.0],  # a, b, c saturated and tied; f "never pick"
    [-0.9, 0.0, -0.2, -0.995, 0.0, 0.0],
], dtype=np.float32)  # fmt: skip
W_VP = np.array([[0.9, 0.5, 0.0], [0.0, 0.4, 0.7]], dtype=np.float32)
W_PO = np.zeros((3, 6), dtype=np.float32)
W_PO[0, :3] = 0.9
W_PO[1, 3] = 0.6
W_PO[2, :] = 0.4  # below tau everywhere: p2 reaches no object


def diagnose() -> dict[str, object]:
    return discrimination_diagnostics(
        ENERGY, W_VP, W_PO, ["v0", "v1"], ["p0", "p1", "p2"], OBJECTS,
        tau=0.5, top_k=2, n_hubs=3, margin_rank=3,
    )  # fmt: skip


def test_top_k_credit_shares_ties() -> None:
    # v0: a, b, c tie for both top-2 places -> 2/3 each; d (4th) and the rest nothing
    np.testing.assert_allclose(top_k_credit(ENERGY[0], 2), [2 / 3, 2 / 3, 2 / 3, 0, 0, 0])
    # v1: d strictly first, a alone at the 2nd place
    np.testing.assert_allclose(top_k_credit(ENERGY[1], 2), [1, 0, 0, 1, 0, 0])
    # fewer reachable objects than k: each counts fully; nothing reachable: nothing counts
    np.testing.assert_allclose(top_k_credit(np.array([-0.1, 0.0, 1.0]), 2), [1, 0, 0])
    assert not top_k_credit(np.zeros(4), 2).any()


def test_hand_values() -> None:
    d = diagnose()
    assert d["affordant_share"] == pytest.approx(7 / 12, abs=1e-6)  # 4 + 3 cells below 0
    assert d["saturated_share"] == pytest.approx(4 / 12, abs=1e-6)  # a, b, c of v0; d of v1
    # credits: a 2/3 + 1, d 1, b 2/3, c 2/3 over 2 verbs; b before c by name
    assert d["hubs"] == [
        {"object": "a", "top_k_share": round(5 / 6, 6)},
        {"object": "d", "top_k_share": 0.5},
        {"object": "b", "top_k_share": round(1 / 3, 6)},
    ]
    assert d["max_hub_share"] == round(5 / 6, 6)
    assert d["properties_reaching_no_object"] == ["p2"]
    # 3rd best minus best: v0 -1.0 - -1.0 = 0 (saturated); v1 c -0.2 - d -0.995 = 0.795
    assert d["margins"] == {"v0": 0.0, "v1": pytest.approx(0.795, abs=1e-6)}
    assert d["margin_median"] == pytest.approx(0.3975, abs=1e-6)
    Diagnostics.model_validate(d)  # the report model accepts it
    assert json.loads(json.dumps(d)) == d


def test_shape_mismatch_is_an_error() -> None:
    with pytest.raises(ValueError, match="names give"):
        discrimination_diagnostics(ENERGY, W_VP, W_PO, ["v0"], ["p0", "p1", "p2"], OBJECTS)


def test_report_diff_and_diagnose_carry_them(kb_a: FixtureKB, kb_scoop_v2: FixtureKB) -> None:
    report = BundleReport.model_validate_json((kb_a.bundle / "report.json").read_text("utf-8"))
    assert report.diagnostics is not None and 0.0 < report.diagnostics.affordant_share <= 1.0
    a = load_bundle(kb_a.bundle, check_encoder=False)
    result = diff_bundles(a, load_bundle(kb_scoop_v2.bundle, check_encoder=False))
    assert result["diagnostics"]["a"] == report.diagnostics.model_dump(mode="json")
    assert "### Discrimination" in render_markdown(result)
    run = CliRunner().invoke(app, ["diagnose", str(kb_a.bundle), "--energy-form", "all", "--format", "json"])
    assert run.exit_code == 0, run.output
    forms = json.loads(run.output)["forms"]
    assert set(forms) == {"sum-tanh", "normalized-product", "specificity", "required-veto", "specificity-veto"}
    assert forms["sum-tanh"] == result["diagnostics"]["a"]
    bad = CliRunner().invoke(app, ["diagnose", str(kb_a.bundle), "--energy-form", "veto"])
    assert bad.exit_code == 2 and "unknown E_aff form" in bad.output


def test_diagnose_says_why_a_property_reaches_no_object() -> None:
    """The Markdown report names each dead property, the verbs leaning on it and its strongest
    object edges below tau: in the shipped v1 KB, the six dead ends issue 9 listed; in the
    default KB the one left, a property no object of the vocabulary has (raw fibre)."""
    from craft_e.paths import KB_DIR

    v1 = CliRunner().invoke(app, ["diagnose", str(KB_DIR / "craft-e-v1")])
    assert v1.exit_code == 0, v1.output
    dead = [line for line in v1.output.splitlines() if line.startswith("- ") and "used by" in line]
    assert [line.split(":")[0][2:] for line in dead] == [
        "has a net", "has a probe", "has a teat", "has a wick", "is an award", "worn on the wrist"]
    assert "- has a teat: used by feed (0.40); strongest object edges none (tau 0.5)" in dead
    default = CliRunner().invoke(app, ["diagnose", str(KB_DIR / "craft-e-default")])
    assert default.exit_code == 0, default.output
    report = json.loads((KB_DIR / "craft-e-default" / "report.json").read_text("utf-8"))
    listed = [line.split(":")[0][2:] for line in default.output.splitlines()
              if line.startswith("- ") and "used by" in line]
    assert listed == report["diagnostics"]["properties_reaching_no_object"]  # each one explained
