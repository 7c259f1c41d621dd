"""Name normalization shared by the compiler and the runtime.

Graph node names must match across sources (an LLM writes "Knives", ConceptNet writes
``/c/en/knife``, a scene file writes ``kitchen_knife``), so every name goes through one function:
lowercase, underscores and hyphen-runs to spaces, collapsed whitespace, and a conservative
singular lemma of the last word. The lemmatizer is rule-based on purpose: it must give the same
answer on every machine, with no corpus download.
"""

from __future__ import annotations

import re

# Words whose plural rule is irregular or that look plural but are not.
_INVARIANT = {
    "scissors",
    "pliers",
    "tongs",
    "glasses",
    "goggles",
    "pants",
    "trousers",
    "shorts",
    "jeans",
    "tweezers",
    "binoculars",
    "headphones",
    "clippers",
    "shears",
    "chopsticks",
    "sunglasses",
    "bus",
    "gas",
    "lens",
    "chess",
    "glass",
    "grass",
    "dress",
    "class",
    "mass",
    "moss",
    "boss",
    "cross",
    "press",
    "compass",
    "harness",
    "mattress",
    "canvas",
    "cactus",
    "octopus",
    "virus",
    "bonus",
    "status",
    "asparagus",
    "hummus",
    "walrus",
    "iris",
    "species",
    "series",
    "news",
    "mathematics",
    "physics",
    "electronics",
    "athletics",
    "billiards",
    "checkers",
    "darts",
    "dominoes",
    "marbles",
    "cards",
    "stairs",
    "bellows",
    "barracks",
    "means",
    "overalls",
    "pajamas",
    "earmuffs",
    "mittens",
    "dice",
    "lego",
    "bass",
    "chassis",
    "corps",
    "fish",
    "sheep",
    "deer",
    "aircraft",
    "hovercraft",
    "spacecraft",
    "swiss",
    "lotus",
    "hibiscus",
    "campus",
    "circus",
    "citrus",
    "fungus",
    "thesis",
    "axis",
    "basis",
    "analysis",
    "tennis",
    "always",
    "this",
    "yes",
    "plus",
    "minus",
    "atlas",
    "alias",
    "ibis",
    "pelvis",
    "rhinoceros",
    "hippopotamus",
    "kudos",
    "cosmos",
    "chaos",
    "pathos",
    "mucus",
    "abacus",
    "bias",
    "is",
    "was",
    "has",
    "does",
    "goes",
    "its",
    "sandals",
    "shoes",
}
_IRREGULAR = {
    "knives": "knife",
    "axes": "axe",  # the -xes rule would give "ax"; the vocabularies spell the tool "axe"
    "wives": "wife",
    "lives": "life",
    "leaves": "leaf",
    "loaves": "loaf",
    "shelves": "shelf",
    "halves": "half",
    "wolves": "wolf",
    "calves": "calf",
    "scarves": "scarf",
    "hooves": "hoof",
    "children": "child",
    "men": "man",
    "women": "woman",
    "teeth": "tooth",
    "feet": "foot",
    "geese": "goose",
    "mice": "mouse",
    "oxen": "ox",
    "people": "person",
    "dice": "dice",
    "cacti": "cactus",
    "fungi": "fungus",
    "potatoes": "potato",
    "tomatoes": "tomato",
    "heroes": "hero",
    "echoes": "echo",
    "mangoes": "mango",
    "shoes": "shoe",
    "sandals": "sandal",
    "boxes": "box",
    "matches": "match",
    "brushes": "brush",
    "dishes": "dish",
    "glasses": "glasses",
    "cups": "cup",
    "blocks": "block",
    "balls": "ball",
    "marbles": "marbles",
    "clothes": "clothes",
    "bristles": "bristles",
    "handles": "handle",
    "wheels": "wheel",
    "knobs": "knob",
    "keys": "key",
    "tines": "tine",
    "prongs": "prong",
    "strings": "string",
    "buttons": "button",
    "holes": "hole",
    "blades": "blade",
    "edges": "edge",
    "jaws": "jaw",
    "legs": "leg",
    "wings": "wing",
    "sides": "side",
    "pieces": "piece",
    "bags": "bag",
    "toys": "toy",
}

_SEPARATORS = re.compile(r"[_\s]+")
_ALLOWED = re.compile(r"^[a-z0-9][a-z0-9 '\-./&+]*$")
#: Longest name accepted (a verb, property or object is a few words). Checked before any other
#: work, and a rejected name is echoed only in part, so a 10 MB "verb" costs nothing and never
#: comes back in full in an error message or a log.
MAX_NAME_CHARS = 100
_ECHO_CHARS = 40


def shown(raw: str, limit: int = _ECHO_CHARS) -> str:
    """``repr`` of a user's name, cut to ``limit`` characters with the full length noted."""
    if len(raw) <= limit:
        return repr(raw)
    return f"{raw[:limit]!r}... ({len(raw)} characters)"


def _singular(word: str) -> str:
    """A deterministic English singularizer for nouns (last word of a name only)."""
    if word in _IRREGULAR:
        return _IRREGULAR[word]
    if word in _INVARIANT or len(word) <= 3:
        return word
    if word.endswith("ies") and len(word) > 4:
        return word[:-3] + "y"
    if word.endswith(("ches", "shes", "sses", "xes", "zzes")):
        return word[:-2]
    if word.endswith("ss") or word.endswith("us") or word.endswith("is"):
        return word
    if word.endswith("s") and not word.endswith("ss"):
        return word[:-1]
    return word


def normalize_name(raw: str, *, singularize: bool = True) -> str:
    """Normalize a verb, property or object name: lowercase, spaces, singular last word.

    Raises ``ValueError`` for names that are empty after normalization, longer than
    ``MAX_NAME_CHARS``, or carry characters that would make a poor graph id (the caller names
    the file and line).
    """
    if len(raw) > 4 * MAX_NAME_CHARS:  # surrounding whitespace aside, far too long: no work
        raise ValueError(f"name {shown(raw)} is longer than {MAX_NAME_CHARS} characters")
    name = _SEPARATORS.sub(" ", raw.strip().lower()).strip()
    if not name:
        raise ValueError("empty name")
    if len(name) > MAX_NAME_CHARS:
        raise ValueError(f"name {shown(raw)} is longer than {MAX_NAME_CHARS} characters")
    if not _ALLOWED.match(name):
        raise ValueError(f"name {shown(raw, 60)} contains characters outside [a-z0-9 '-./&+]")
    if singularize:
        words = name.split(" ")
        words[-1] = _singular(words[-1])
        name = " ".join(words)
    return name


def normalize_verb(raw: str) -> str:
    """Verbs are lowercase phrases ("sit on", "pour from"); they are never singularized."""
    return normalize_name(raw, singularize=False)


def normalize_property(raw: str) -> str:
    """Properties are short phrases ("has bristles", "holds liquid"): lowercase, no lemma."""
    return normalize_name(raw, singularize=False)


def is_normalized(name: str, *, singular: bool = True) -> bool:
    """Whether ``name`` is what ``normalize_name`` gives for some input (``singular=False``: what
    ``normalize_verb`` / ``normalize_property`` give).

    Why: the runtime normalizes every name it is asked for (a verb, a scene's object), so a bundle
    whose axes hold another spelling ("CUT", "knives") can never be asked for it. The singular
    lemma is not idempotent ("mens" gives "men", which gives "man"), so a name counts as
    normalized when some input gives it, not only when normalizing it again leaves it alone.
    """
    try:
        if normalize_name(name, singularize=False) != name:
            return False
    except ValueError:
        return False
    if not singular:
        return True
    last = name.rsplit(" ", 1)[-1]
    if _singular(last) == last:  # most names: their own lemma
        return True
    inputs = {last, last + "s", last + "es", *(k for k, v in _IRREGULAR.items() if v == last)}
    if last.endswith("y"):
        inputs.add(last[:-1] + "ies")
    return any(_singular(word) == last for word in inputs)
