"""Pass 1, reading vocabularies: fixture pairs (``vocab/*.txt`` -> ``*.expected.json``) + errors.

A vocabulary file is the KB author's input; harmless irregularities must be normalized *and
reported* (so the author sees what happened to their file), bad input must stop the build with
the file and line named.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import FIXTURES

from craft_e.compiler.vocab import VocabError, read_vocabulary

VOCAB = FIXTURES / "vocab"
PAIRS = sorted(VOCAB.glob("*.txt"))


def test_fixture_pairs_exist() -> None:
    assert PAIRS, f"no vocabulary fixtures in {VOCAB}"
    for path in PAIRS:
        assert path.with_suffix(".expected.json").is_file(), f"{path} has no expected file"


@pytest.mark.parametrize("path", PAIRS, ids=[p.stem for p in PAIRS])
def test_vocabulary_fixture_pair(path: Path) -> None:
    expected = json.loads(path.with_suffix(".expected.json").read_text(encoding="utf-8"))
    vocab = read_vocabulary(path, kind=expected["kind"])
    assert vocab.names == expected["names"]
    assert vocab.notes == [n.replace("{path}", str(path)) for n in expected["notes"]]


def test_names_keep_first_seen_order_and_are_unique(tmp_path: Path) -> None:
    path = tmp_path / "objects.txt"
    path.write_text("spoon\nKnives\nknife\nbowl\nspoons\n", encoding="utf-8")
    vocab = read_vocabulary(path, kind="objects")
    assert vocab.names == ["spoon", "knife", "bowl"]
    duplicates = [n for n in vocab.notes if "duplicate" in n]
    assert duplicates == [
        f"{path}:3: duplicate of line 2 ('knife'), ignored",
        f"{path}:5: duplicate of line 1 ('spoon'), ignored",
    ]


def test_clean_file_has_no_notes(tmp_path: Path) -> None:
    path = tmp_path / "verbs.txt"
    path.write_text("# verbs\ncut\nscoop\n", encoding="utf-8")
    vocab = read_vocabulary(path)
    assert vocab.names == ["cut", "scoop"]
    assert vocab.notes == []


def test_utf8_bom_is_accepted(tmp_path: Path) -> None:
    path = tmp_path / "verbs.txt"
    path.write_bytes("\ufeffcut\nscoop\n".encode())
    assert read_vocabulary(path).names == ["cut", "scoop"]


@pytest.mark.parametrize(
    "content",
    [b"", b"\n\n   \n", b"# only a comment\n# and another\n"],
    ids=["empty", "blank-lines", "comments-only"],
)
def test_empty_file_is_an_error(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "verbs.txt"
    path.write_bytes(content)
    with pytest.raises(VocabError) as info:
        read_vocabulary(path, kind="verbs")
    assert str(info.value) == f"{path}: no verbs found (the file is empty or only comments)"


def test_non_utf8_file_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "objects.txt"
    path.write_bytes(b"knife\nspoon\ncaf\xe9 cup\nbowl\n")  # Latin-1, not UTF-8
    with pytest.raises(VocabError) as info:
        read_vocabulary(path, kind="objects")
    message = str(info.value)
    assert message.startswith(f"{path}:3: not valid UTF-8")
    assert "0xe9" in message
    assert "UTF-8" in message.split(";")[-1]  # says the fix: re-save as UTF-8


def test_bad_name_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "objects.txt"
    path.write_text("knife\nknife!\n", encoding="utf-8")
    with pytest.raises(VocabError, match=rf"^{path}:2: name 'knife!' contains characters"):
        read_vocabulary(path, kind="objects")


def test_missing_file_and_directory(tmp_path: Path) -> None:
    with pytest.raises(VocabError, match="file not found"):
        read_vocabulary(tmp_path / "nope.txt")
    with pytest.raises(VocabError, match="is a directory"):
        read_vocabulary(tmp_path)


def test_verbs_are_never_singularized_but_objects_are(tmp_path: Path) -> None:
    path = tmp_path / "words.txt"
    path.write_text("dresses\nBrushes\n", encoding="utf-8")
    assert read_vocabulary(path, kind="verbs").names == ["dresses", "brushes"]
    assert read_vocabulary(path, kind="objects").names == ["dress", "brush"]


def test_a_second_tab_is_an_error_not_part_of_the_gloss(tmp_path: Path) -> None:
    path = tmp_path / "verbs.txt"
    path.write_text("cut\nlift\tto raise something\textra\n", encoding="utf-8")
    with pytest.raises(VocabError, match=r"verbs\.txt:2: more than one tab"):
        read_vocabulary(path, kind="verbs")
