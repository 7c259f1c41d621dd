"""Reading verb and object vocabulary files: one name per line, ``#`` comments allowed.

A line may carry a gloss after a tab (``name<TAB>gloss``): the sense the name is meant in
(``crane<TAB>a large long-necked wading bird``). Prompt v2 puts it into the object's prompt.

Bad input gets a clear error naming the file and line; harmless irregularities (blank lines,
duplicates after normalization, case) are normalized and *reported*, not silently absorbed. A
duplicate whose gloss differs from the first line's is an error: one of the two senses would be
dropped.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from ..paths import artifacts_hint
from ..schemas.names import normalize_name, normalize_verb


class VocabError(ValueError):
    """A vocabulary file cannot be used; the message names the file, the line and the fix."""


@dataclass
class Vocabulary:
    """Normalized names in first-seen order, plus what normalization changed."""

    path: Path
    names: list[str]
    notes: list[str] = field(default_factory=list)
    glosses: dict[str, str] = field(default_factory=dict)  # name -> its sense (optional column)


MAX_GLOSS_CHARS = 300


def read_vocabulary(path: Path, *, kind: str = "verbs") -> Vocabulary:
    """Read and normalize a verbs (``kind="verbs"``) or objects file."""
    normalize: Callable[[str], str] = normalize_verb if kind == "verbs" else normalize_name
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise VocabError(
            f"{path}: file not found (pass a text file with one {kind[:-1]} per line){artifacts_hint(path)}"
        ) from None
    except IsADirectoryError:
        raise VocabError(f"{path}: is a directory, expected a text file of {kind}") from None
    except OSError as exc:  # unreadable: an input problem, never one of the bundle's output
        raise VocabError(f"{path}: cannot read the {kind} file ({exc.strerror or exc})") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        bad_line = data[: exc.start].count(b"\n") + 1
        raise VocabError(
            f"{path}:{bad_line}: not valid UTF-8 (byte 0x{data[exc.start]:02x}); re-save the file as UTF-8"
        ) from None
    names: list[str] = []
    seen: dict[str, int] = {}
    notes: list[str] = []
    blank = 0
    glosses: dict[str, str] = {}
    for lineno, raw_line in enumerate(text.splitlines(), start=1):
        # ``name<TAB>gloss``: the gloss fixes the sense (it may contain '#'); '#' starts a
        # comment in the name column only.
        name_part, _, gloss = raw_line.partition("\t")
        if "\t" in gloss:
            raise VocabError(
                f"{path}:{lineno}: more than one tab; write 'name<TAB>gloss' (one tab, the gloss "
                "in words separated by spaces)"
            )
        line = name_part.split("#", 1)[0].strip()
        gloss = " ".join(gloss.split())
        if gloss and not line:
            raise VocabError(
                f"{path}:{lineno}: a gloss without a name; write 'name<TAB>gloss'"
            )
        if len(gloss) > MAX_GLOSS_CHARS:
            raise VocabError(
                f"{path}:{lineno}: gloss of {len(gloss)} characters (max {MAX_GLOSS_CHARS}); "
                "shorten it to one line"
            )
        if not line:
            blank += 1 if not raw_line.strip().startswith("#") else 0
            continue
        try:
            name = normalize(line)
        except ValueError as exc:
            raise VocabError(f"{path}:{lineno}: {exc}; use plain lowercase words") from None
        if name != line:
            notes.append(f"{path}:{lineno}: {line!r} normalized to {name!r}")
        if name in seen:
            first = glosses.get(name, "")
            if gloss and gloss != first:
                # two senses for one name: keeping either silently would ask in a sense the
                # author may not have meant
                kept = f"gloss {first!r}" if first else "no gloss"
                raise VocabError(
                    f"{path}:{lineno}: {name!r} again, with gloss {gloss!r}; line {seen[name]} "
                    f"gives it {kept}. Keep one line per {kind[:-1]} with the gloss you mean"
                )
            notes.append(f"{path}:{lineno}: duplicate of line {seen[name]} ({name!r}), ignored")
            continue
        seen[name] = lineno
        names.append(name)
        if gloss:
            glosses[name] = gloss
    if blank:
        notes.append(f"{path}: {blank} blank line(s) ignored")
    if not names:
        raise VocabError(f"{path}: no {kind} found (the file is empty or only comments)")
    return Vocabulary(path=path, names=names, notes=notes, glosses=glosses)
