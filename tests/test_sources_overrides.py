"""The overrides pass: a good file edits the draft with provenance; bad files fail clearly.

Each bad file must produce an ``OverridesError`` naming the file, the line of the offending
table (or key) and the key, so the author can fix it without guessing.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from craft_e.compiler.draft import KnowledgeDraft, Link
from craft_e.compiler.sources.overrides import STAGE, OverridesError, apply_overrides


def _draft() -> KnowledgeDraft:
    draft = KnowledgeDraft(verbs=["cut", "stir"], objects=["knife", "spoon", "mug"])
    draft.verb_props = {
        "cut": {"sharp": Link(0.9, ("rec-a",)), "has handle": Link(0.4, ("rec-a",))},
        "stir": {"long": Link(0.8, ("rec-b",))},
    }
    draft.prop_objs = {
        "sharp": {"knife": Link(1.0, ("rec-c",)), "spoon": Link(0.3, ("rec-d",))},
        "has handle": {"knife": Link(0.9, ("rec-c",))},
        "long": {"spoon": Link(0.9, ("rec-d",))},
    }
    return draft


def _write(tmp_path: Path, text: str, name: str = "overrides.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


GOOD = """\
# corrections to the generated KB
[[add]]
verb = "cut"
property = "serrated edge"
w_vp = 0.7

[[add]]
property = "serrated edge"
object = "knife"
w_po = 1.0

[[remove]]
property = "sharp"
object = "spoon"

[[reweight]]
verb = "cut"
property = "has handle"
w_vp = 0.2
note = "handles matter little for cutting"

[[forbid]]
verb = "stir"
object = "knife"

[[remove]]
verb = "cut"
property = "has handle"
"""


def test_good_file_edits_the_draft(tmp_path: Path) -> None:
    draft = _draft()
    path = _write(tmp_path, GOOD)
    apply_overrides(draft, path)
    assert draft.verb_props["cut"]["serrated edge"] == Link(0.7, ("override:overrides.toml:2",), "override")
    assert draft.prop_objs["serrated edge"]["knife"] == Link(1.0, ("override:overrides.toml:7",), "override")
    assert "spoon" not in draft.prop_objs["sharp"]
    assert "has handle" not in draft.verb_props["cut"]  # reweighted on line 16, removed on line 26
    assert draft.forbidden == {("stir", "knife")}
    counts = draft.counters[STAGE]
    assert counts["added vp edges"] == 1 and counts["added po edges"] == 1
    assert counts["reweighted vp edges"] == 1 and counts["forbidden pairs"] == 1
    assert counts["dropped: removed by override"] == 2 and counts["edits read"] == 6
    assert {(d.item, d.reason) for d in draft.drops} == {
        ("sharp -> spoon", "removed by override: override:overrides.toml:12"),
        ("cut -> has handle", "removed by override: override:overrides.toml:26"),
    }
    (info,) = draft.sources
    assert (info.kind, info.model, info.records) == ("overrides", "overrides.toml", 6)
    assert info.prompts[0].startswith("overrides.toml@sha256:")


def test_reweight_keeps_the_original_provenance(tmp_path: Path) -> None:
    draft = _draft()
    apply_overrides(draft, _write(tmp_path, '[[reweight]]\nproperty = "long"\nobject = "spoon"\nw_po = 0.5\n'))
    assert draft.prop_objs["long"]["spoon"] == Link(0.5, ("rec-d", "override:overrides.toml:1"), "override")


def test_inline_array_tables_work(tmp_path: Path) -> None:
    draft = _draft()
    apply_overrides(draft, _write(tmp_path, 'forbid = [{verb = "cut", object = "mug"}]\n'))
    assert draft.forbidden == {("cut", "mug")}


def test_names_are_normalized(tmp_path: Path) -> None:
    draft = _draft()
    apply_overrides(draft, _write(tmp_path, '[[forbid]]\nverb = "Cut"\nobject = "Knives"\n'))
    assert draft.forbidden == {("cut", "knife")}


BAD_FILES = {
    "syntax error": ('[[add]]\nverb = "cut"\nproperty = sharp\n', r"overrides\.toml:3: TOML syntax error"),
    "unknown key": ('[[add]]\nverb = "cut"\nproprety = "sharp"\nw_vp = 0.5\n',
                    r"overrides\.toml:3: \[\[add\]\] #1, key 'proprety': unknown key; allowed keys"),
    "weight out of range": ('[[add]]\nverb = "cut"\nproperty = "hard"\n\nw_vp = 1.5\n',
                            r"overrides\.toml:5: \[\[add\]\] #1, key 'w_vp': weight 1\.5 out of range; "
                            r"use a number in \[0, 1\]"),
    "unknown verb": ('[[forbid]]\nverb = "cut"\nobject = "mug"\n\n[[forbid]]\nverb = "slice"\nobject = "mug"\n',
                     r"overrides\.toml:6: \[\[forbid\]\] #2, key 'verb': unknown verb 'slice'"),
    "unknown object": ('[[add]]\nproperty = "sharp"\nobject = "saw"\nw_po = 1\n',
                       r"overrides\.toml:3: .*key 'object': unknown object 'saw'"),
    "unknown property": ('[[add]]\nproperty = "pointy"\nobject = "knife"\nw_po = 1\n',
                         r"overrides\.toml:2: .*key 'property': unknown property 'pointy'; add it to a verb"),
    "wrong type": ('[[reweight]]\nverb = "cut"\nproperty = "sharp"\nw_vp = "high"\n',
                   r"overrides\.toml:4: .*key 'w_vp': expected a number, got str"),
    "bool weight": ('[[reweight]]\nverb = "cut"\nproperty = "sharp"\nw_vp = true\n',
                    r"key 'w_vp': expected a number, got bool"),
    "name not a string": ('[[forbid]]\nverb = 3\nobject = "mug"\n', r"overrides\.toml:2: .*key 'verb': expected a string"),
    "unknown table": ('[[rename]]\nverb = "cut"\n', r"overrides\.toml:1: unknown key 'rename'"),
    "single brackets": ('[add]\nverb = "cut"\n', r"overrides\.toml:1: 'add' must be an array of tables"),
    "verb and object": ('[[add]]\nverb = "cut"\nobject = "knife"\nw_vp = 1\n',
                        r"overrides\.toml:1: \[\[add\]\] #1: names object, verb; an edge is"),
    "wrong weight key": ('[[add]]\nverb = "cut"\nproperty = "hard"\nw_po = 0.5\n',
                         r"overrides\.toml:4: .*key 'w_po': w_po does not belong to a vp edge"),
    "missing weight": ('[[add]]\nverb = "cut"\nproperty = "hard"\n', r"missing key 'w_vp'"),
    "add existing": ('[[add]]\nverb = "cut"\nproperty = "sharp"\nw_vp = 0.5\n',
                     r"edge cut -> sharp already exists .*use \[\[reweight\]\]"),
    "remove missing": ('[[remove]]\nproperty = "long"\nobject = "knife"\n', r"no edge long -> knife to remove"),
    "reweight missing": ('[[reweight]]\nproperty = "long"\nobject = "knife"\nw_po = 0.1\n',
                         r"no edge long -> knife to reweight; use \[\[add\]\]"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_files_name_file_line_and_key(tmp_path: Path, case: str) -> None:
    text, pattern = BAD_FILES[case]
    with pytest.raises(OverridesError, match=pattern):
        apply_overrides(_draft(), _write(tmp_path, text))


def test_missing_file_and_bad_encoding(tmp_path: Path) -> None:
    with pytest.raises(OverridesError, match="overrides file not found"):
        apply_overrides(_draft(), tmp_path / "nope.toml")
    bad = tmp_path / "latin1.toml"
    bad.write_bytes('[[forbid]]\nverb = "caf\xe9"\n'.encode("latin-1"))
    with pytest.raises(OverridesError, match="not valid UTF-8"):
        apply_overrides(_draft(), bad)


def test_overrides_error_is_a_value_error() -> None:
    assert issubclass(OverridesError, ValueError)  # the CLI maps ValueError to exit code 2
