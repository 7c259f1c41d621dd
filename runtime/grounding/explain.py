"""Why does a bundle think ``object`` affords ``verb``? The paths behind ``E_aff(verb, object)``.

Used by ``craftc explain`` and by people reviewing a KB: every number in the energy is traced to a
verb -> property -> object path with its two weights and the record ids they came from, so a
surprising choice can be followed back to the answer that caused it.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass

from ..kb.bundle import Bundle, PathStep


class UnknownNameError(ValueError):
    """A verb or object the bundle does not contain; the message lists close matches."""

    def __init__(self, kind: str, name: str, kb: str, close_matches: list[str]) -> None:
        self.kind = kind
        self.name = name
        self.close_matches = close_matches
        hint = f"close matches: {', '.join(close_matches)}" if close_matches else "no close match"
        super().__init__(f"unknown {kind} {name!r}: not in KB {kb} ({hint})")


@dataclass(frozen=True)
class Explanation:
    verb: str
    obj: str
    kb: str
    e_aff: float
    energy_form: str
    tau: float
    paths: list[PathStep]
    forbidden: bool
    rank: int  # 1-based rank of the object among all the KB's objects for this verb
    n_objects: int
    gloss: str = ""  # the sense the object was asked in (prompt v2 bundles)
    verb_gloss: str = ""  # the sense the verb was asked in (glossed verbs, prompt v3)
    definitions: dict[str, str] | None = None  # property -> its one-line definition (v2)
    roles: dict[str, str] | None = None  # property -> "required" | "helpful" for this verb (v2)

    def render(self) -> str:
        """Human-readable: E_aff, rank, then each path strongest first with short record ids."""
        lines = [f"{self.verb} -> {self.obj} in {self.kb}: E_aff = {self.e_aff:+.4f} "
                 f"({self.energy_form}, tau = {self.tau:g}); rank {self.rank} of {self.n_objects} objects"]
        if self.verb_gloss:
            lines.append(f"{self.verb} (verb): {self.verb_gloss}")
        if self.gloss:
            lines.append(f"{self.obj}: {self.gloss}")
        if self.forbidden:
            lines.append(f"forbidden: the KB marks {self.obj!r} as never to be picked for {self.verb!r} "
                         "(E_aff set to the maximum, 1.0)")
        if not self.paths:
            lines.append(f"no path: no property of {self.verb!r} links to {self.obj!r} with w_po >= {self.tau:g}")
        for p in sorted(self.paths, key=lambda p: (-(p.w_vp + p.w_po), p.prop)):
            records = ", ".join(short_record(k) for k in p.provenance)
            role = (self.roles or {}).get(p.prop)
            tag = f" ({role})" if role else ""
            lines.append(f"  {p.verb} -({p.w_vp:.2f})-> {p.prop}{tag} -({p.w_po:.2f})-> {p.obj}   [records {records}]")
            definition = (self.definitions or {}).get(p.prop)
            if definition:
                lines.append(f"      {p.prop}: {definition}")
        missing = [
            prop for prop, role in sorted((self.roles or {}).items())
            if role == "required" and prop not in {p.prop for p in self.paths}
        ]
        if missing:
            lines.append(f"lacks required: {', '.join(missing)}")
        return "\n".join(lines)


def _resolve(kind: str, raw: str, names: list[str], kb: str) -> str:
    from ...schemas.names import normalize_name, normalize_verb

    try:
        name = normalize_verb(raw) if kind == "verb" else normalize_name(raw)
    except ValueError:
        name = raw.strip().lower()
    if name in names:
        return name
    if raw in names:
        return raw
    raise UnknownNameError(kind, raw, kb, difflib.get_close_matches(name, names, n=5, cutoff=0.6))


def explain_pair(bundle: Bundle, verb: str, obj: str) -> Explanation:
    """The paths, energy and rank behind ``E_aff(verb, obj)`` in ``bundle``."""
    m = bundle.manifest
    kb = f"{m.kb_name}@{m.kb_version}"
    v = _resolve("verb", verb, m.verbs, kb)
    o = _resolve("object", obj, m.objects, kb)
    row = bundle.energy[bundle.verb_index[v]]  # [O]
    e = float(row[bundle.object_index[o]])
    g = bundle.index  # lookups only: no models of every edge for one explanation
    roles: dict[str, str] = dict(g.roles(v))
    definitions = {prop: d for prop in roles if (d := g.definition(prop)) is not None}
    return Explanation(
        verb=v, obj=o, kb=kb, e_aff=e, energy_form=m.energy.form, tau=m.energy.tau,
        paths=bundle.paths(v, o), forbidden=(v, o) in set(g.forbidden_pairs()),
        rank=int((row < e).sum()) + 1, n_objects=len(m.objects),
        gloss=g.gloss(o) or "", verb_gloss=g.verb_gloss(v) or "", definitions=definitions,
        roles=roles,
    )


def short_record(key: str) -> str:
    """A provenance entry as ``craftc explain`` prints it: a record key (64 hex digits) as its
    first 12, which find the record file; anything else, such as an override's
    ``override:<file>:<line>``, whole (cut to 12 it named no file and no line)."""
    return key[:12] if len(key) == 64 and all(c in "0123456789abcdef" for c in key) else key

