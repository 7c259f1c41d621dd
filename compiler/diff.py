"""``craftc diff A B``: what changed between two bundles, for a pull-request review.

A KB change is reviewed the way code is: the reviewer needs to see *what* knowledge moved
(structural diff: verbs, objects, properties, edges, weights over a threshold) and *what it does*
to the robot's choices (behavioural diff: for each verb in both bundles, its top-k objects by
``E_aff`` before and after). The behavioural diff is the part that catches surprises — a small
weight edit can flip which object the robot hands over for "cut".

The result is a plain JSON-able dict so CI can archive it (``--format json``), render it as
Markdown for a PR comment (:func:`render_markdown`), and gate a merge on it
(:func:`gate_failures`, ``--fail-on``). Every list is sorted, so the same two bundles always
give the same bytes.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterable
from typing import Any

from ..runtime.kb.bundle import Bundle
from ..runtime.kb.diagnostics import HEADLINE, bundle_diagnostics, headline_value

#: Weight deltas are rounded to this many decimals before the threshold comparison, so that a
#: change written as 0.2 -> 0.1 counts as exactly 0.1 (binary floats would say 0.1000...03).
DELTA_DECIMALS = 6
#: Lists longer than this go into a collapsible ``<details>`` block in the Markdown.
LONG_LIST = 10
#: At most this many rows per Markdown table or names per list: GitHub rejects comments over
#: 65,536 characters, and a whole-KB rewrite can remove thousands of edges. ``--format json``
#: always carries everything.
MAX_ROWS = 100
#: Fixed gate rules, and rules that take a bound (``edges-removed>N``).
FLAG_RULES = ("top1-changed", "verb-removed", "any-change")
BOUND_RULES = ("edges-removed", "weight-changes")
VALID_RULES = (*FLAG_RULES, *(f"{r}>N" for r in BOUND_RULES))
#: Hubs listed per side in the Markdown diagnostics.
N_HUBS_SHOWN = 10
_BOUND_RULE = re.compile(r"^(?P<name>[a-z0-9-]+)\s*>\s*(?P<bound>\d+)$")

Edge = tuple[str, str]
Json = dict[str, Any]


class DiffError(ValueError):
    """A diff request cannot be honoured (unknown ``--fail-on`` rule); the message says the fix."""


# ---------------------------------------------------------------------------------------------
# Reading the two bundles
# ---------------------------------------------------------------------------------------------


def _edges(bundle: Bundle) -> tuple[dict[Edge, float], dict[Edge, float]]:
    """``(verb, property) -> w_vp`` and ``(property, object) -> w_po`` from graph.json."""
    return bundle.graph.vp_weights(), bundle.graph.po_weights()


def _forbidden(bundle: Bundle) -> set[Edge]:
    """``(verb, object)`` pairs an override marked "never pick"."""
    return set(bundle.graph.forbidden_pairs())


def _added_removed(a: Iterable[str], b: Iterable[str]) -> Json:
    sa, sb = set(a), set(b)
    return {"added": sorted(sb - sa), "removed": sorted(sa - sb)}


def _edge_rows(
    edges: dict[Edge, float], keys: Iterable[Edge], names: tuple[str, str]
) -> list[Json]:
    return [{names[0]: s, names[1]: t, "weight": edges[(s, t)]} for s, t in sorted(keys)]


def _edge_diff(a: dict[Edge, float], b: dict[Edge, float], names: tuple[str, str]) -> Json:
    return {
        "added": _edge_rows(b, b.keys() - a.keys(), names),
        "removed": _edge_rows(a, a.keys() - b.keys(), names),
    }


def _weight_changes(
    a: dict[Edge, float], b: dict[Edge, float], kind: str, names: tuple[str, str], threshold: float
) -> list[Json]:
    rows = []
    for s, t in sorted(a.keys() & b.keys()):
        delta = round(b[(s, t)] - a[(s, t)], DELTA_DECIMALS)
        if abs(delta) > threshold:
            rows.append(
                {
                    "edge": kind,
                    names[0]: s,
                    names[1]: t,
                    "old": a[(s, t)],
                    "new": b[(s, t)],
                    "delta": delta,
                }
            )
    return rows


def top_objects(bundle: Bundle, verb: str, k: int) -> list[Json]:
    """The ``k`` best objects for ``verb``: ascending ``E_aff``, ties broken by object name.

    Only objects the verb actually reaches (``E_aff < 0``) are ranked. ``E_aff = 0`` means no
    property links them, and ``+1`` marks a "never pick" pair; neither is an answer the robot
    would give, and ranking them would fill short lists with alphabetical noise that "changes"
    whenever an unrelated object is added.
    """
    row = bundle.energy[bundle.verb_index[verb]]  # [O]
    scored = [
        (float(row[i]), obj) for i, obj in enumerate(bundle.manifest.objects) if float(row[i]) < 0.0
    ]
    scored.sort()
    return [{"object": obj, "energy": round(e, 6)} for e, obj in scored[:k]]


def _behaviour(a: Bundle, b: Bundle, top_k: int) -> list[Json]:
    rows = []
    for verb in sorted(set(a.manifest.verbs) & set(b.manifest.verbs)):
        top_a, top_b = top_objects(a, verb, top_k), top_objects(b, verb, top_k)
        names_a = [r["object"] for r in top_a]
        names_b = [r["object"] for r in top_b]
        top1_a = names_a[0] if names_a else None
        top1_b = names_b[0] if names_b else None
        rows.append(
            {
                "verb": verb,
                "a": top_a,
                "b": top_b,
                "entered": sorted(set(names_b) - set(names_a)),
                "left": sorted(set(names_a) - set(names_b)),
                "top1_a": top1_a,
                "top1_b": top1_b,
                "top1_changed": top1_a != top1_b,
                "order_changed": names_a != names_b,
            }
        )
    return rows


def _added_object_effects(behaviour: list[Json], a: Bundle, b: Bundle) -> list[Json]:
    """Per object new in ``b``: the verbs whose top-k it entered (with its rank) and the
    objects it pushed out — the ranking changes that growing the vocabulary causes."""
    added = set(b.manifest.objects) - set(a.manifest.objects)
    out: dict[str, Json] = {}
    for row in behaviour:
        names_b = [r["object"] for r in row["b"]]
        for obj in row["entered"]:
            if obj in added:
                entry = out.setdefault(obj, {"object": obj, "verbs": []})
                entry["verbs"].append({"verb": row["verb"], "rank": names_b.index(obj) + 1,
                                       "top1": row["top1_b"] == obj,
                                       "displaced": [o for o in row["left"] if o not in added]})
    return [out[o] for o in sorted(out)]


def _size_diff(a: Bundle, b: Bundle) -> Json:
    """Typical sizes (``object_sizes.json``, the size cue's knowledge) added, removed or changed."""
    def row(name: str, bundle: Bundle) -> Json:
        size = bundle.sizes[name]
        return {"dimensions_cm": [round(100 * v, 2) for v in size.dimensions_m], "variability": size.variability}

    changed = [{"object": n, "a": row(n, a), "b": row(n, b)} for n in sorted(set(a.sizes) & set(b.sizes))
               if a.sizes[n] != b.sizes[n]]
    return {**_added_removed(a.sizes, b.sizes), "changed": changed}


def _colour_diff(a: Bundle, b: Bundle) -> Json:
    """Typical colours (``object_colours.json``, the colour cue's knowledge) added, removed or changed."""
    def row(name: str, bundle: Bundle) -> Json:
        entry = bundle.colours[name]
        return {"colours": dict(entry.shares), "variability": entry.variability}

    changed = [{"object": n, "a": row(n, a), "b": row(n, b)} for n in sorted(set(a.colours) & set(b.colours))
               if a.colours[n] != b.colours[n]]
    return {**_added_removed(a.colours, b.colours), "changed": changed}


def _lookalike_diff(a: Bundle, b: Bundle) -> Json:
    """Look-alike classes (``object_lookalikes.json``, the look-alike cue's knowledge) added, removed or changed."""
    changed = [{"object": n, "a": {"classes": dict(a.lookalikes[n])}, "b": {"classes": dict(b.lookalikes[n])}}
               for n in sorted(set(a.lookalikes) & set(b.lookalikes)) if a.lookalikes[n] != b.lookalikes[n]]
    return {**_added_removed(a.lookalikes, b.lookalikes), "changed": changed}


def _identity(bundle: Bundle) -> Json:
    m = bundle.manifest
    return {
        "path": str(bundle.path),
        "kb_name": m.kb_name,
        "kb_version": m.kb_version,
        "content_sha256": m.content_sha256,
        "energy_form": m.energy.form,
        "tau": m.energy.tau,
        "text_encoder": m.text_encoder.id,
    }


def diff_bundles(a: Bundle, b: Bundle, top_k: int = 5, threshold: float = 0.1) -> dict[str, Any]:
    """Structural and behavioural differences from bundle ``a`` (old) to ``b`` (new).

    Weight changes are reported when ``|new - old| > threshold`` (after rounding the delta to
    :data:`DELTA_DECIMALS`). The behavioural diff covers every verb present in both bundles;
    verbs only in one side are already listed as added/removed.
    """
    if top_k < 1:
        raise DiffError(f"top_k must be at least 1, got {top_k}")
    if threshold < 0 or math.isnan(threshold):
        raise DiffError(f"threshold must be a non-negative number, got {threshold}")
    vp_a, po_a = _edges(a)
    vp_b, po_b = _edges(b)
    vp_names, po_names = ("verb", "property"), ("property", "object")
    edges = {
        "verb_property": _edge_diff(vp_a, vp_b, vp_names),
        "property_object": _edge_diff(po_a, po_b, po_names),
    }
    weights = _weight_changes(vp_a, vp_b, "verb_property", vp_names, threshold)
    weights += _weight_changes(po_a, po_b, "property_object", po_names, threshold)
    weights.sort(
        key=lambda r: (
            -abs(r["delta"]),
            r["edge"],
            r.get("verb", r["property"]),
            r.get("object", r["property"]),
        )
    )
    fa, fb = _forbidden(a), _forbidden(b)
    forbidden = {
        "added": [{"verb": v, "object": o} for v, o in sorted(fb - fa)],
        "removed": [{"verb": v, "object": o} for v, o in sorted(fa - fb)],
    }
    behaviour = _behaviour(a, b, top_k)
    ia, ib = _identity(a), _identity(b)
    settings = [
        {"setting": key, "a": ia[key], "b": ib[key]}
        for key in ("energy_form", "tau", "text_encoder")
        if ia[key] != ib[key]
    ]
    result: Json = {
        "a": ia,
        "b": ib,
        "identical": ia["content_sha256"] == ib["content_sha256"],
        "top_k": top_k,
        "threshold": threshold,
        "settings_changed": settings,
        "verbs": _added_removed(a.manifest.verbs, b.manifest.verbs),
        "objects": _added_removed(a.manifest.objects, b.manifest.objects),
        "properties": _added_removed(a.manifest.properties, b.manifest.properties),
        "edges": edges,
        "weight_changes": weights,
        "forbidden": forbidden,
        "behaviour": behaviour,
        "added_objects_ranked": _added_object_effects(behaviour, a, b),
        "sizes": _size_diff(a, b),
        "colours": _colour_diff(a, b),
        "lookalikes": _lookalike_diff(a, b),
        # does E_aff discriminate? (affordant/saturated shares, hubs, margins), before and after
        "diagnostics": {"a": bundle_diagnostics(a), "b": bundle_diagnostics(b)},
    }
    result["summary"] = _summary(result)
    return result


def _summary(result: Json) -> dict[str, int]:
    """Counts for the headline and the gates (one place computes them)."""
    counts: dict[str, int] = {}
    for part in ("verbs", "objects", "properties"):
        counts[f"{part}_added"] = len(result[part]["added"])
        counts[f"{part}_removed"] = len(result[part]["removed"])
    for kind in ("verb_property", "property_object"):
        counts[f"{kind}_edges_added"] = len(result["edges"][kind]["added"])
        counts[f"{kind}_edges_removed"] = len(result["edges"][kind]["removed"])
    counts["edges_added"] = (
        counts["verb_property_edges_added"] + counts["property_object_edges_added"]
    )
    counts["edges_removed"] = (
        counts["verb_property_edges_removed"] + counts["property_object_edges_removed"]
    )
    counts["weight_changes"] = len(result["weight_changes"])
    counts["forbidden_added"] = len(result["forbidden"]["added"])
    counts["forbidden_removed"] = len(result["forbidden"]["removed"])
    counts["verbs_compared"] = len(result["behaviour"])
    counts["verbs_topk_changed"] = sum(
        1 for r in result["behaviour"] if r["order_changed"] or r["entered"] or r["left"]
    )
    counts["verbs_top1_changed"] = sum(1 for r in result["behaviour"] if r["top1_changed"])
    counts["sizes_added"] = len(result["sizes"]["added"])
    counts["sizes_removed"] = len(result["sizes"]["removed"])
    counts["sizes_changed"] = len(result["sizes"]["changed"])
    counts["colours_added"] = len(result["colours"]["added"])
    counts["colours_removed"] = len(result["colours"]["removed"])
    counts["colours_changed"] = len(result["colours"]["changed"])
    counts["lookalikes_added"] = len(result["lookalikes"]["added"])
    counts["lookalikes_removed"] = len(result["lookalikes"]["removed"])
    counts["lookalikes_changed"] = len(result["lookalikes"]["changed"])
    return counts


# ---------------------------------------------------------------------------------------------
# Gates (--fail-on)
# ---------------------------------------------------------------------------------------------


def _top1_changed(result: Json) -> str | None:
    changed = [r for r in result["behaviour"] if r["top1_changed"]]
    if not changed:
        return None
    shown = ", ".join(
        f"{r['verb']} ({r['top1_a'] or '(none)'} -> {r['top1_b'] or '(none)'})"
        for r in changed[:10]
    )
    more = f" and {len(changed) - 10} more" if len(changed) > 10 else ""
    return f"top1-changed: the best object changed for {len(changed)} verb(s): {shown}{more}"


def _verb_removed(result: Json) -> str | None:
    removed = result["verbs"]["removed"]
    if not removed:
        return None
    return f"verb-removed: {len(removed)} verb(s) removed: {', '.join(removed)}"


def _any_change(result: Json) -> str | None:
    if result["identical"]:
        return None
    s = result["summary"]
    return (
        f"any-change: content sha256 {result['a']['content_sha256'][:12]} -> "
        f"{result['b']['content_sha256'][:12]} ({s['edges_added']} edges added, "
        f"{s['edges_removed']} removed, {s['weight_changes']} weight changes, "
        f"top-k changed for {s['verbs_topk_changed']} verb(s))"
    )


_FLAG_CHECKS: dict[str, Callable[[Json], str | None]] = {
    "top1-changed": _top1_changed,
    "verb-removed": _verb_removed,
    "any-change": _any_change,
}
_BOUND_COUNTS = {"edges-removed": "edges_removed", "weight-changes": "weight_changes"}


def _unknown(rule: str) -> DiffError:
    return DiffError(f"unknown --fail-on rule {rule!r}; valid rules: {', '.join(VALID_RULES)}")


def parse_rules(rules: Iterable[str]) -> list[str]:
    """Normalize and check ``--fail-on`` rules (comma-separated values are split).

    Checked up front so a typo fails loudly instead of silently never gating. An empty or blank
    rule (``--fail-on "$RULE"`` with ``RULE`` unset, a stray comma) is an error too: skipping it
    would make the gate pass having checked nothing.
    """
    parsed: list[str] = []
    for item in rules:
        for raw in item.split(","):
            rule = raw.strip().lower()
            if not rule:
                raise DiffError(
                    f"empty --fail-on rule in {item!r} (an unset variable?); valid rules: "
                    f"{', '.join(VALID_RULES)}"
                )
            if rule in _FLAG_CHECKS:
                parsed.append(rule)
                continue
            match = _BOUND_RULE.match(rule)
            if match is None or match["name"] not in _BOUND_COUNTS:
                if rule in _BOUND_COUNTS:
                    raise DiffError(f"--fail-on rule {rule!r} needs a bound, e.g. {rule}>0")
                raise _unknown(raw.strip())
            parsed.append(f"{match['name']}>{int(match['bound'])}")
    return parsed


def gate_failures(result: dict[str, Any], rules: list[str]) -> list[str]:
    """One message per ``--fail-on`` rule the diff violates (empty: the gate passes).

    Rules: ``top1-changed``, ``verb-removed``, ``any-change``, ``edges-removed>N``,
    ``weight-changes>N``. An unknown rule raises :class:`DiffError` naming the valid ones.
    """
    failures: list[str] = []
    for rule in parse_rules(rules):
        if rule in _FLAG_CHECKS:
            message = _FLAG_CHECKS[rule](result)
            if message is not None:
                failures.append(message)
            continue
        name, bound = rule.split(">")
        count = int(result["summary"][_BOUND_COUNTS[name]])
        if count > int(bound):
            failures.append(f"{rule}: {count} {name.replace('-', ' ')} (allowed at most {bound})")
    return failures


# ---------------------------------------------------------------------------------------------
# Markdown
# ---------------------------------------------------------------------------------------------


def _code(name: object) -> str:
    """A name as inline code, safe inside a table cell."""
    return "`" + str(name).replace("`", "'").replace("|", "\\|") + "`"


def _names(items: list[str]) -> str:
    if not items:
        return "—"
    more = f" … and {len(items) - MAX_ROWS} more" if len(items) > MAX_ROWS else ""
    return ", ".join(_code(i) for i in items[:MAX_ROWS]) + more


def _fmt(value: float) -> str:
    """Weights to at most three decimals, without trailing zeros (0.5, not 0.500)."""
    return f"{value:.3f}".rstrip("0").rstrip(".")


def _rows(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows[:MAX_ROWS]]
    if len(rows) > MAX_ROWS:
        lines += ["", f"… and {len(rows) - MAX_ROWS} more rows (see `craftc diff --format json`)"]
    return lines


def _table(header: list[str], rows: list[list[str]], summary: str) -> list[str]:
    """A Markdown table, folded into ``<details>`` when it is long (PR comments stay readable)."""
    lines = _rows(header, rows)
    if len(rows) <= LONG_LIST:
        return [*lines, ""]
    return [f"<details><summary>{summary}</summary>", "", *lines, "", "</details>", ""]


def _name_list(title: str, items: list[str]) -> list[str]:
    if len(items) <= LONG_LIST * 2:
        return [f"- {title} ({len(items)}): {_names(items)}"]
    return [
        f"- <details><summary>{title} ({len(items)})</summary>",
        "",
        f"  {_names(items)}",
        "",
        "  </details>",
    ]


def _top_list(rows: list[Json]) -> str:
    return " ".join(f"{i}. {_code(r['object'])}" for i, r in enumerate(rows, start=1)) or "—"


def _diagnostics_section(result: Json) -> list[str]:
    """Before/after table of the discrimination diagnostics (absent in diffs made before them)."""
    diag = result.get("diagnostics")
    if not diag:
        return []
    a, b = diag["a"], diag["b"]
    rows = []
    for key, label, lower_better in HEADLINE:
        va, vb = headline_value(a, key), headline_value(b, key)
        if key == "properties_reaching_no_object":
            cells = [f"{va:.0f}", f"{vb:.0f}", f"{vb - va:+.0f}"]
        elif key.endswith("share"):
            cells = [f"{100 * va:.1f} %", f"{100 * vb:.1f} %", f"{100 * (vb - va):+.1f}"]
        else:
            cells = [f"{va:.3f}", f"{vb:.3f}", f"{vb - va:+.3f}"]
        better = "" if va == vb else " ✅" if (vb < va) == lower_better else " ⚠️"
        rows.append([label, *cells[:2], cells[2] + better])
    lines = [
        "### Discrimination: does E_aff tell objects apart?",
        "",
        *_rows(["diagnostic", "before", "after", "Δ"], rows),
        "",
    ]
    for side, d in (("before", a), ("after", b)):
        hubs = ", ".join(
            f"{_code(h['object'])} {100 * h['top_k_share']:.0f} %" for h in d["hubs"][:N_HUBS_SHOWN]
        )
        lines.append(f"- top-{d['top_k']} hubs {side}: {hubs or '—'}")
    new_dead = sorted(
        set(b["properties_reaching_no_object"]) - set(a["properties_reaching_no_object"])
    )
    if new_dead:
        lines.append(f"- properties newly reaching no object: {_names(new_dead)}")
    return [*lines, ""]


def render_markdown(result: dict[str, Any]) -> str:
    """The diff as a Markdown PR comment: headline counts, then tables, long ones collapsed."""
    a, b, s = result["a"], result["b"], result["summary"]
    out = [
        f"## KB diff: {_code(a['kb_name'])} {a['kb_version']} → {_code(b['kb_name'])} {b['kb_version']}",
        "",
        f"Content sha256 `{a['content_sha256'][:16]}…` → `{b['content_sha256'][:16]}…`",
        "",
    ]
    if result["identical"]:
        out += ["**No changes**: both bundles have the same content hash.", ""]
        return "\n".join(out)
    out += [
        f"**{s['verbs_top1_changed']}** of {s['verbs_compared']} verbs changed their top-1 object, "
        f"**{s['verbs_topk_changed']}** changed their top-{result['top_k']}; "
        f"**{s['edges_added']}** edges added, **{s['edges_removed']}** removed, "
        f"**{s['weight_changes']}** weight changes over {_fmt(result['threshold'])}.",
        "",
        "| | added | removed |",
        "|---|---:|---:|",
    ]
    for label, key in (
        ("verbs", "verbs"),
        ("objects", "objects"),
        ("properties", "properties"),
        ("verb → property edges", "verb_property_edges"),
        ("property → object edges", "property_object_edges"),
        ("never-pick pairs", "forbidden"),
        ("typical sizes (size cue)", "sizes"),
        ("typical colours (colour cue)", "colours"),
        ("look-alike classes (look-alike cue)", "lookalikes"),
    ):
        out.append(f"| {label} | {s[key + '_added']} | {s[key + '_removed']} |")
    out.append("")
    if result["sizes"]["changed"]:
        rows = [[_code(c["object"]),
                 " x ".join(_fmt(v) for v in c["a"]["dimensions_cm"]) + f" cm, {c['a']['variability']}",
                 " x ".join(_fmt(v) for v in c["b"]["dimensions_cm"]) + f" cm, {c['b']['variability']}"]
                for c in result["sizes"]["changed"]]
        out += _table(["object", "typical size before", "after"], rows,
                      f"{len(rows)} typical sizes changed")
    if result["colours"]["changed"]:
        def shown(entry: Json) -> str:
            return ", ".join(f"{t} {_fmt(v)}" for t, v in entry["colours"].items()) + f"; {entry['variability']}"

        rows = [[_code(c["object"]), shown(c["a"]), shown(c["b"])] for c in result["colours"]["changed"]]
        out += _table(["object", "typical colours before", "after"], rows,
                      f"{len(rows)} typical colours changed")
    if result["lookalikes"]["changed"]:
        def classes(entry: Json) -> str:
            return ", ".join(f"{c} {_fmt(v)}" for c, v in entry["classes"].items())

        rows = [[_code(c["object"]), classes(c["a"]), classes(c["b"])] for c in result["lookalikes"]["changed"]]
        out += _table(["object", "look-alike classes before", "after"], rows,
                      f"{len(rows)} look-alike answers changed")
    for row in result["settings_changed"]:
        out += [
            f"⚠️ setting {_code(row['setting'])} changed: {_code(row['a'])} → {_code(row['b'])}",
            "",
        ]

    out += _diagnostics_section(result)
    changed = [r for r in result["behaviour"] if r["order_changed"] or r["entered"] or r["left"]]
    changed.sort(key=lambda r: (not r["top1_changed"], r["verb"]))  # flips first: review those
    out += [f"### Behaviour: top-{result['top_k']} objects by E_aff", ""]
    if not changed:
        out += [f"No verb's top-{result['top_k']} changed ({s['verbs_compared']} compared).", ""]
    else:
        rows = [
            [
                _code(r["verb"]) + (" ⚠️" if r["top1_changed"] else ""),
                _code(r["top1_a"]) if r["top1_a"] else "—",
                _code(r["top1_b"]) if r["top1_b"] else "—",
                _names(r["entered"]),
                _names(r["left"]),
            ]
            for r in changed
        ]
        out += _table(
            ["verb", "top-1 before", "top-1 after", "entered", "left"],
            rows,
            f"{len(changed)} verbs whose top-{result['top_k']} changed",
        )
        detail = [[_code(r["verb"]), _top_list(r["a"]), _top_list(r["b"])] for r in changed]
        out += [
            "<details><summary>Full rankings before and after</summary>",
            "",
            *_rows(["verb", "before", "after"], detail),
            "",
            "</details>",
            "",
        ]

    effects = result.get("added_objects_ranked", [])
    if result["objects"]["added"]:
        out += [f"### Added objects: ranking changes they cause (top-{result['top_k']})", ""]
        if not effects:
            out += [f"No added object entered any verb's top-{result['top_k']}.", ""]
        else:
            rows = [
                [
                    _code(e["object"]),
                    ", ".join(
                        _code(v["verb"]) + f" #{v['rank']}" + (" ⚠️ top-1" if v["top1"] else "")
                        for v in e["verbs"]
                    ),
                    _names(sorted({o for v in e["verbs"] for o in v["displaced"]})),
                ]
                for e in effects
            ]
            out += _table(
                ["added object", "entered the top of (rank)", "displaced"],
                rows,
                f"{len(effects)} added objects entered a verb's top-{result['top_k']}",
            )

    lists = [
        (f"{title} {verb}", result[part][key])
        for part, title in (
            ("verbs", "Verbs"),
            ("objects", "Objects"),
            ("properties", "Properties"),
        )
        for key, verb in (("added", "added"), ("removed", "removed"))
        if result[part][key]
    ]
    if lists:
        out += ["### Vocabulary", ""]
        for title, items in lists:
            out += _name_list(title, items)
        out.append("")

    edge_rows: list[list[str]] = []
    for kind, (src, dst) in (
        ("verb_property", ("verb", "property")),
        ("property_object", ("property", "object")),
    ):
        for change, sign in (("added", "+"), ("removed", "−")):
            edge_rows += [
                [sign, f"{_code(e[src])} → {_code(e[dst])}", _fmt(e["weight"])]
                for e in result["edges"][kind][change]
            ]
    if edge_rows:
        out += [
            "### Edges",
            "",
            *_table(["", "edge", "weight"], edge_rows, f"{len(edge_rows)} edges added or removed"),
        ]

    if result["weight_changes"]:
        rows = []
        for w in result["weight_changes"]:
            src, dst = (
                ("verb", "property") if w["edge"] == "verb_property" else ("property", "object")
            )
            delta = f"{w['delta']:+.3f}".rstrip("0").rstrip(".")
            rows.append(
                [f"{_code(w[src])} → {_code(w[dst])}", _fmt(w["old"]), _fmt(w["new"]), delta]
            )
        out += [
            f"### Weight changes over {_fmt(result['threshold'])}",
            "",
            *_table(["edge", "before", "after", "Δ"], rows, f"{len(rows)} weight changes"),
        ]

    forbidden = [("+", f) for f in result["forbidden"]["added"]] + [
        ("−", f) for f in result["forbidden"]["removed"]
    ]
    if forbidden:
        rows = [[sign, _code(f["verb"]), _code(f["object"])] for sign, f in forbidden]
        out += [
            "### Never-pick pairs",
            "",
            *_table(["", "verb", "object"], rows, f"{len(rows)} pairs"),
        ]
    return "\n".join(out).rstrip("\n") + "\n"
