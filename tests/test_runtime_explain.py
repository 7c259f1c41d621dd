"""``explain_pair``: paths, energy, rank and close-match errors (used by ``craftc explain``)."""

from __future__ import annotations

import pytest
from runtime_fixtures import RuntimeKBs, runtime_kbs_fixture  # noqa: F401

from craft_e.runtime.grounding.explain import UnknownNameError, explain_pair
from craft_e.runtime.kb.bundle import load_bundle


def test_explain_pair_renders_paths_with_weights_and_records(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    ex = explain_pair(kb, "cut", "cleaver")
    assert ex.rank == 1 and ex.e_aff == pytest.approx(float(kb.energy[kb.verb_index["cut"], kb.object_index["cleaver"]]))
    props = {p.prop: (p.w_vp, p.w_po) for p in ex.paths}
    assert props["sharp edge"] == (0.95, 1.0)
    assert "serrated" not in props  # cleaver has no serrated score
    text = ex.render()
    first = text.splitlines()[1]
    assert first.startswith("  cut -(0.95)-> sharp edge -(1.00)-> cleaver")  # strongest path first
    assert "records" in text and "rank 1 of 24" in text


def test_explain_forbidden_and_pathless(runtime_kbs: RuntimeKBs) -> None:
    kb = load_bundle(runtime_kbs.kb)
    assert "forbidden" in explain_pair(kb, "cut", "umbrella").render()
    ex = explain_pair(kb, "eat", "umbrella")
    assert ex.paths == [] and "no path" in ex.render()
    assert explain_pair(kb, "Eat", "Bananas").obj == "banana"


@pytest.mark.parametrize(("verb", "obj", "kind", "match"), [("cutt", "cleaver", "verb", "cut"),
                                                             ("cut", "cleavr", "object", "cleaver")])
def test_unknown_names_list_close_matches(runtime_kbs: RuntimeKBs, verb: str, obj: str, kind: str, match: str) -> None:
    kb = load_bundle(runtime_kbs.kb)
    with pytest.raises(UnknownNameError) as info:
        explain_pair(kb, verb, obj)
    assert info.value.kind == kind and match in info.value.close_matches
    assert isinstance(info.value, ValueError) and match in str(info.value)


def test_craftc_explain_uses_it(runtime_kbs: RuntimeKBs) -> None:
    from typer.testing import CliRunner

    from craft_e.compiler.cli import app

    result = CliRunner().invoke(app, ["explain", str(runtime_kbs.kb), "hit", "hammer"])
    assert result.exit_code == 0, result.output
    assert "hit -(0.90)-> hard striking surface -(1.00)-> hammer" in result.output
    bad = CliRunner().invoke(app, ["explain", str(runtime_kbs.kb), "hitt", "hammer"])
    assert bad.exit_code == 2 and "hit" in bad.output
