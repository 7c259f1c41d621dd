"""ConceptNet as a knowledge source: the paper's CRAFT baseline KB, read three ways.

* ``read_omcs``: the OMCS test/dev files in ``shared/data/conceptnet`` (``rel<TAB>head<TAB>tail
  <TAB>label``), the offline default; only label-1 lines are true facts.
* ``read_assertions_csv``: a local ConceptNet 5 assertions dump (``.csv`` or ``.csv.gz``,
  tab-separated ``uri, rel, start, end, info-JSON``), streamed line by line, English only.
* ``ConceptNetAPI``: the REST API (``/c/en/<term>``, ``/query``) over httpx, following
  ``view.nextPage`` up to a page bound. Every page is stored as a record under the cache source
  ``conceptnet`` (provider ``conceptnet-api``, identity = URL + query), so a build that fetched
  once replays offline; local files are identified by their sha256 instead.

All three yield the same ``Fact``. ``conceptnet_draft`` then maps facts to verb -> property ->
object edges using only what the facts say (no similarity, no invented links) and counts what
it read, kept and dropped: ConceptNet's coverage of tool use is thin, and the report must say so.
"""

from __future__ import annotations

import codecs
import gzip
import json
import zlib
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO
from urllib.parse import parse_qsl, urlsplit

import httpx

from ...files import sha256_file
from ...paths import shared_dir
from ...schemas.names import normalize_name
from ...schemas.v1.bundle import SourceInfo
from ...schemas.v1.records import Record, RecordRequest
from ..cache import RecordCache
from ..draft import KnowledgeDraft, Link
from .http_retry import make_client, response_json, send, with_retries
from .llm import SourceError, TransportError

CONCEPTNET_SOURCE = "conceptnet"
API_PROVIDER = "conceptnet-api"
API_MODEL = "conceptnet5"
#: Version of how pages are requested and summarized: part of every page record's key.
API_REQUEST_ID = "conceptnet-api@v1"
DEFAULT_API_URL = "https://api.conceptnet.io"
OMCS_FILES = ("omcs_test.txt", "omcs_dev1.txt", "omcs_dev2.txt")
#: ConceptNet weights are ~1 per contributor and grow with votes; 2.0 (one source + one vote)
#: maps to w_po = 1, a single unconfirmed source to 0.5 (still >= the default tau).
DEFAULT_WEIGHT_SCALE = 2.0
DEFAULT_MAX_PAGES = 20
DEFAULT_PAGE_SIZE = 100

USE_RELATIONS = ("UsedFor", "CapableOf")
PROPERTY_RELATIONS = ("HasProperty", "HasA", "MadeOf")
NEGATIONS = {
    "NotUsedFor": "UsedFor",
    "NotCapableOf": "CapableOf",
    "NotHasProperty": "HasProperty",
    "NotHasA": "HasA",
    "NotMadeOf": "MadeOf",
}
RELATIONS = frozenset(USE_RELATIONS + PROPERTY_RELATIONS) | frozenset(NEGATIONS)
_CANONICAL = {name.lower(): name for name in RELATIONS}
_PROPERTY_PREFIX = {"HasProperty": "", "HasA": "has ", "MadeOf": "made of "}

READ_STAGE = "conceptnet_read"
MAP_STAGE = "conceptnet_map"
Progress = Callable[[str, int], None]


class ConceptNetInputError(ValueError):
    """A local ConceptNet file or a ``--conceptnet`` spec cannot be used; names file/line/fix."""


@dataclass(frozen=True)
class Fact:
    """One ConceptNet assertion with normalized names and a weight in [0, 1].

    ``source_id`` says where it was read (``omcs_test.txt:12`` or a ConceptNet assertion URI);
    ``record_key`` is the cache record an API fact came from (empty for local files).
    """

    rel: str
    head: str
    tail: str
    weight: float
    source_id: str
    record_key: str = ""

    @property
    def provenance(self) -> tuple[str, ...]:
        return (self.record_key, self.source_id) if self.record_key else (self.source_id,)


# --------------------------------------------------------------------------------------------
# names and relations


def canonical_relation(name: str) -> str:
    """``/r/UsedFor``, ``usedfor`` and ``UsedFor`` all name ``UsedFor``; unknown names pass."""
    bare = name.rsplit("/", 1)[-1] if name.startswith("/r/") else name
    return _CANONICAL.get(bare.lower(), bare)


def english_term(uri: str) -> str | None:
    """``/c/en/make_music/v/...`` -> ``make_music``; None for other languages or non-concepts."""
    parts = uri.split("/")
    if len(parts) < 4 or parts[1] != "c" or parts[2] != "en" or not parts[3]:
        return None
    return parts[3]


def term_uri(name: str) -> str:
    """The ConceptNet URI of a normalized name (``toy car`` -> ``/c/en/toy_car``)."""
    return "/c/en/" + name.replace(" ", "_")


def make_fact(
    rel: str, head: str, tail: str, weight: float, source_id: str, stats: Counter[str],
    record_key: str = "",
) -> Fact | None:
    """A ``Fact`` with normalized names, or None (counted) when a name cannot be normalized."""
    try:
        head_name = normalize_name(head)
        tail_name = normalize_name(tail)
    except ValueError:
        stats["skipped: name not normalizable"] += 1
        return None
    return Fact(rel, head_name, tail_name, weight, source_id, record_key)


def scaled_weight(weight: float, scale: float = DEFAULT_WEIGHT_SCALE) -> float:
    """A ConceptNet edge weight mapped into [0, 1] (``min(1, weight / scale)``, never < 0)."""
    return min(1.0, max(0.0, weight / scale))


# --------------------------------------------------------------------------------------------
# local files


_GZIP_MAGIC = b"\x1f\x8b"


def _check_file(path: Path) -> None:
    """``path`` is an existing regular file, or an error that says what it is instead."""
    if path.is_dir():
        raise ConceptNetInputError(
            f"{path}: is a folder, not a ConceptNet file; name the file itself (--conceptnet "
            "csv:<assertions.csv[.gz]>, or omcs:<folder> for a folder of OMCS files)"
        )
    if not path.is_file():
        raise ConceptNetInputError(f"{path}: file not found")


def _open_text(path: Path) -> TextIO:
    _check_file(path)
    if path.suffix == ".gz":
        return gzip.open(path, "rt", encoding="utf-8", newline="\n")
    return path.open("r", encoding="utf-8", newline="\n")


def _not_text(path: Path, where: str) -> ConceptNetInputError:
    """The error for a file whose bytes are not UTF-8 text (a gzip without ``.gz``: say so)."""
    try:
        with path.open("rb") as handle:
            gzipped = handle.read(2) == _GZIP_MAGIC
    except OSError:
        gzipped = False
    hint = ("it is gzip-compressed: name it with a .gz suffix" if gzipped and path.suffix != ".gz"
            else "a ConceptNet file is UTF-8 text (or .gz of it)")
    return ConceptNetInputError(f"{where}: not valid UTF-8 text; {hint}")


def _text_lines(path: Path) -> Iterator[tuple[int, str]]:
    """``(line number, line)`` of a local ConceptNet file, with every read failure turned into
    an error naming the file (a bare codec, gzip or I/O message would name nothing)."""
    lineno = 0
    try:
        with _open_text(path) as handle:
            for lineno, line in enumerate(handle, start=1):
                yield lineno, line
    except UnicodeDecodeError:
        # text is decoded in chunks, so the bad byte lies somewhere after the last line read
        raise _not_text(path, f"{path}: past line {lineno}" if lineno else str(path)) from None
    except (gzip.BadGzipFile, EOFError, zlib.error) as exc:
        raise ConceptNetInputError(
            f"{path}: not a readable gzip file ({exc}); re-download it, or drop the .gz suffix "
            "if it is plain text"
        ) from None
    except OSError as exc:
        raise ConceptNetInputError(f"{path}: cannot read it ({exc.strerror or exc})") from None


def check_local_file(path: Path) -> None:
    """Read the head of a local ConceptNet file (before a build's other work): a wrong path, a
    folder, a file that is not gzip or not UTF-8 text fails here, naming the file."""
    _check_file(path)
    try:
        with path.open("rb") as handle:
            head = handle.read(64 * 1024)
        if path.suffix == ".gz":
            if head[:2] != _GZIP_MAGIC:
                raise ConceptNetInputError(
                    f"{path}: not a gzip file, though named .gz; re-download it, or drop the .gz "
                    "suffix if it is plain text"
                )
            with gzip.open(path, "rb") as unzipped:
                head = unzipped.read(64 * 1024)
    except (gzip.BadGzipFile, EOFError, zlib.error) as exc:
        raise ConceptNetInputError(f"{path}: not a readable gzip file ({exc}); re-download it") from None
    except OSError as exc:
        raise ConceptNetInputError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    try:
        codecs.getincrementaldecoder("utf-8")().decode(head, final=False)
    except UnicodeDecodeError:
        raise _not_text(path, str(path)) from None


def read_omcs(
    paths: Sequence[Path], stats: Counter[str] | None = None,
    relations: frozenset[str] = RELATIONS,
) -> Iterator[Fact]:
    """True facts (label 1) of OMCS-format files, weight 1.0; malformed lines are errors."""
    stats = Counter() if stats is None else stats
    for path in paths:
        for lineno, line in _text_lines(path):
            fact = _omcs_line(path, lineno, line, stats, relations)
            if fact is not None:
                yield fact


def _omcs_line(
    path: Path, lineno: int, line: str, stats: Counter[str], relations: frozenset[str]
) -> Fact | None:
    text = line.rstrip("\r\n")
    if not text.strip():
        return None
    fields = text.split("\t")
    if len(fields) != 4 or fields[3].strip() not in ("0", "1"):
        raise ConceptNetInputError(
            f"{path}:{lineno}: expected 'rel<TAB>head<TAB>tail<TAB>0|1', got {text[:80]!r}"
        )
    stats["lines read"] += 1
    if fields[3].strip() == "0":
        stats["skipped: false statement (label 0)"] += 1
        return None
    rel = canonical_relation(fields[0].strip())
    if rel not in relations:
        stats["skipped: relation not used"] += 1
        return None
    return make_fact(rel, fields[1], fields[2], 1.0, f"{path.name}:{lineno}", stats)


def read_assertions_csv(
    path: Path, stats: Counter[str] | None = None, relations: frozenset[str] = RELATIONS,
    weight_scale: float = DEFAULT_WEIGHT_SCALE,
) -> Iterator[Fact]:
    """English facts of a ConceptNet 5 assertions dump (``.csv`` / ``.csv.gz``), streamed.

    The JSON info column is parsed only for lines that pass the cheap relation and language
    filters, so the full 34M-line dump is read in one pass without holding it in memory.
    """
    stats = Counter() if stats is None else stats
    for lineno, line in _text_lines(path):
        fact = _csv_line(path, lineno, line, stats, relations, weight_scale)
        if fact is not None:
            yield fact


def _csv_line(
    path: Path, lineno: int, line: str, stats: Counter[str], relations: frozenset[str],
    weight_scale: float,
) -> Fact | None:
    fields = line.rstrip("\r\n").split("\t")
    if len(fields) != 5:
        raise ConceptNetInputError(
            f"{path}:{lineno}: expected 5 tab-separated columns (uri, rel, start, end, info), "
            f"got {len(fields)}; is this a ConceptNet 5 assertions CSV?"
        )
    stats["lines read"] += 1
    uri, rel_uri, start, end, info = fields
    rel = canonical_relation(rel_uri)
    if rel not in relations:
        stats["skipped: relation not used"] += 1
        return None
    head, tail = english_term(start), english_term(end)
    if head is None or tail is None:
        stats["skipped: not English"] += 1
        return None
    try:
        weight = float(json.loads(info).get("weight", 1.0))
    except (ValueError, TypeError, AttributeError):
        raise ConceptNetInputError(
            f"{path}:{lineno}: the info column is not a JSON object with a numeric weight"
        ) from None
    return make_fact(rel, head, tail, scaled_weight(weight, weight_scale), uri, stats)


# --------------------------------------------------------------------------------------------
# REST API


@dataclass(frozen=True)
class Listing:
    """All pages of one paginated API answer: the edges, the records read, and the bound hit."""

    edges: list[tuple[str, dict[str, Any]]]  # (record key, raw edge)
    record_keys: list[str]
    truncated: bool


@dataclass
class ConceptNetAPI:
    """A cache-first ConceptNet REST client; each fetched page becomes a ``conceptnet`` record."""

    base_url: str = DEFAULT_API_URL
    cache: RecordCache | None = None
    client: httpx.Client | None = None
    timeout_s: float = 30.0
    attempts: int = 4
    backoff_s: float = 0.5
    max_pages: int = DEFAULT_MAX_PAGES
    page_size: int = DEFAULT_PAGE_SIZE
    sleep: Callable[[float], None] | None = None
    stats: Counter[str] = field(default_factory=Counter)

    def __post_init__(self) -> None:
        self.base_url = self.base_url.rstrip("/")
        self._client = self.client or make_client(self.timeout_s)

    def close(self) -> None:
        if self.client is None:
            self._client.close()

    def term_edges(self, term: str, limit: int | None = None) -> Listing:
        """Every edge of ``/c/en/<term>`` (both directions, all languages), page by page."""
        query = {} if limit is None else {"limit": str(limit)}
        return self.listing(f"/c/en/{term.replace(' ', '_')}", query, subject=term_uri(term))

    def query(self, **filters: str) -> Listing:
        """``/query`` with ``node``/``rel``/``start``/``end``/``other`` filters."""
        query = {k: v for k, v in sorted(filters.items()) if v}
        query["limit"] = str(self.page_size)
        subject = filters.get("start") or filters.get("node") or filters.get("end") or "query"
        return self.listing("/query", query, subject=subject)

    def listing(self, path: str, query: dict[str, str], subject: str) -> Listing:
        """Follow ``view.nextPage`` until it is absent, repeats, or ``max_pages`` is reached."""
        edges: list[tuple[str, dict[str, Any]]] = []
        keys: list[str] = []
        seen: set[str] = set()
        next_ref: tuple[str, dict[str, str]] | None = (path, query)
        while next_ref is not None and len(keys) < self.max_pages:
            identity = json.dumps(next_ref, sort_keys=True)
            if identity in seen:
                self.stats["pagination loops stopped"] += 1
                break
            seen.add(identity)
            record = self.page(next_ref[0], next_ref[1], subject)
            keys.append(record.key)
            edges.extend((record.key, e) for e in record.payload.get("edges", []))
            next_page = record.payload.get("next_page")
            next_ref = _split_ref(next_page) if isinstance(next_page, str) and next_page else None
        truncated = next_ref is not None and len(keys) >= self.max_pages
        if truncated:
            self.stats["listings truncated at max pages"] += 1
        return Listing(edges, keys, truncated)

    def page(self, path: str, query: dict[str, str], subject: str) -> Record:
        """One page as a record: from the cache when recorded, else fetched and stored."""
        request = self._request(path, query, subject)
        key = request.key()
        if self.cache is not None:
            cached = self.cache.get(CONCEPTNET_SOURCE, key)
            if cached is not None:
                self.stats["pages from cache"] += 1
                return cached
        record = self._fetch(request, key, path, query)
        if self.cache is not None:
            self.cache.put(record)
        self.stats["pages fetched"] += 1
        return record

    def _request(self, path: str, query: dict[str, str], subject: str) -> RecordRequest:
        return RecordRequest(
            provider=API_PROVIDER, model=API_MODEL, prompt=API_REQUEST_ID, messages=[],
            params={"url": self.base_url + path, "query": dict(sorted(query.items()))},
            subject=subject,
        )

    def _fetch(self, request: RecordRequest, key: str, path: str, query: dict[str, str]) -> Record:
        url = self.base_url + path
        what = f"conceptnet GET {path}?{'&'.join(f'{k}={v}' for k, v in sorted(query.items()))}"

        def once() -> tuple[httpx.Response, dict[str, Any]]:
            response = send(self._client, "GET", url, what=what, params=query)
            return response, _page_payload(response_json(response, what), what)

        try:
            response, payload = with_retries(once, what=what, attempts=self.attempts,
                                             backoff_s=self.backoff_s, sleep=self.sleep)
        except TransportError as exc:
            raise SourceError(f"{exc} (base URL {self.base_url}; is the API reachable?)") from None
        return Record(key=key, source=CONCEPTNET_SOURCE, request=request,
                      raw_response=response.text, payload=payload,
                      note=f"fetched from {self.base_url}")


def _split_ref(ref: str) -> tuple[str, dict[str, str]]:
    """``/c/en/spoon?offset=20&limit=20`` -> (``/c/en/spoon``, {offset, limit}).

    Absolute URLs are reduced to path + query and re-based on our ``base_url``, so a mirror or a
    local test server keeps serving the following pages.
    """
    parts = urlsplit(ref)
    return parts.path, dict(sorted(parse_qsl(parts.query, keep_blank_values=True)))


def _page_payload(data: Any, what: str) -> dict[str, Any]:
    """The parts of a page the draft needs: edges and the next page reference."""
    if not isinstance(data, dict) or not isinstance(data.get("edges", []), list):
        raise TransportError(f"{what}: response is not a ConceptNet page (no 'edges' list)")
    view = data.get("view")
    next_page = view.get("nextPage") if isinstance(view, dict) else None
    edges = [e for e in data.get("edges", []) if isinstance(e, dict)]
    return {"edges": edges, "next_page": next_page if isinstance(next_page, str) else None}


def api_facts(
    listing: Listing, stats: Counter[str], relations: frozenset[str] = RELATIONS,
    weight_scale: float = DEFAULT_WEIGHT_SCALE,
) -> Iterator[Fact]:
    """English facts of the wanted relations among a listing's edges."""
    for record_key, edge in listing.edges:
        stats["edges read"] += 1
        rel_node, start, end = edge.get("rel"), edge.get("start"), edge.get("end")
        rel = canonical_relation(rel_node.get("@id", "") if isinstance(rel_node, dict) else "")
        if rel not in relations:
            stats["skipped: relation not used"] += 1
            continue
        head = english_term(start.get("@id", "")) if isinstance(start, dict) else None
        tail = english_term(end.get("@id", "")) if isinstance(end, dict) else None
        if head is None or tail is None:
            stats["skipped: not English"] += 1
            continue
        raw_weight = edge.get("weight", 1.0)
        weight = scaled_weight(float(raw_weight) if isinstance(raw_weight, int | float) else 1.0,
                               weight_scale)
        fact = make_fact(rel, head, tail, weight, str(edge.get("@id", "")), stats, record_key)
        if fact is not None:
            yield fact


# --------------------------------------------------------------------------------------------
# verb matching


def _inflections(word: str) -> set[str]:
    """Regular English forms of a verb (3rd person, -ing), to read ``cutting`` as ``cut``."""
    forms = {word, word + "s", word + "ing"}
    if word.endswith(("s", "sh", "ch", "x", "z", "o")):
        forms.add(word + "es")
    if word.endswith("y") and len(word) > 2 and word[-2] not in "aeiou":
        forms.add(word[:-1] + "ies")
    if word.endswith("ie"):
        forms.add(word[:-2] + "ying")
    elif word.endswith("e") and not word.endswith("ee"):
        forms.add(word[:-1] + "ing")
    if len(word) >= 3 and word[-1] not in "aeiouwxy" and word[-2] in "aeiou" \
            and word[-3] not in "aeiou":
        forms.add(word + word[-1] + "ing")  # stir -> stirring, cut -> cutting
    return forms


class VerbMatcher:
    """Finds the vocabulary verb a ConceptNet phrase starts with, longest verb first.

    ``cut`` matches ``cut``, ``cutting`` and ``cut food``; ``write with`` wins over ``write``
    for ``write with pen``. A verb must be the phrase's first word(s): ``make cut`` is not
    ``cut``, which keeps matches conservative.
    """

    def __init__(self, verbs: Iterable[str]) -> None:
        self._forms: dict[tuple[str, ...], str] = {}
        for verb in verbs:
            first, *rest = verb.split(" ")
            for form in sorted(_inflections(first)):
                self._forms.setdefault((form, *rest), verb)
        self._longest = max((len(k) for k in self._forms), default=0)

    def match(self, phrase: str) -> tuple[str, bool] | None:
        """``(verb, exact)`` where ``exact`` means the whole phrase is the verb; else None."""
        words = tuple(phrase.split(" "))
        for n in range(min(len(words), self._longest), 0, -1):
            verb = self._forms.get(words[:n])
            if verb is not None:
                return verb, n == len(words)
        return None


# --------------------------------------------------------------------------------------------
# facts -> draft


def used_for(verb: str) -> str:
    """The property node that carries ``obj UsedFor/CapableOf verb`` facts."""
    return f"used for {verb}"


def property_node(rel: str, tail: str) -> str:
    """``HasProperty sharp`` -> ``sharp``; ``HasA handle`` -> ``has handle``; ``MadeOf`` ..."""
    return _PROPERTY_PREFIX[rel] + tail


def _put(table: dict[str, dict[str, Link]], src: str, dst: str, weight: float,
         provenance: tuple[str, ...], draft: KnowledgeDraft) -> None:
    """Add an edge; a repeat keeps the larger weight and the union of provenance."""
    links = table.setdefault(src, {})
    old = links.get(dst)
    if old is None:
        links[dst] = Link(weight, provenance, "conceptnet")
        draft.count(MAP_STAGE, "edges kept")
        return
    merged = tuple(sorted(set(old.provenance) | set(provenance)))
    links[dst] = Link(max(old.weight, weight), merged, "conceptnet")
    draft.count(MAP_STAGE, "repeated facts merged into an edge")


@dataclass
class FactMapper:
    """Maps facts onto a draft; property terms found on objects are remembered for verb links."""

    draft: KnowledgeDraft
    matcher: VerbMatcher
    term_props: dict[str, set[str]] = field(default_factory=dict)

    def object_fact(self, fact: Fact) -> None:
        """``obj UsedFor verb`` -> verb -> used for verb -> obj; ``obj HasA x`` -> has x -> obj."""
        draft = self.draft
        if fact.rel in USE_RELATIONS:
            found = self.matcher.match(fact.tail)
            if found is None:
                draft.count(MAP_STAGE, "skipped: use of an object is no vocabulary verb")
                return
            verb, exact = found
            draft.count(MAP_STAGE, "verb matched exactly" if exact else "verb matched as phrase head")
            prop = used_for(verb)
            _put(draft.verb_props, verb, prop, 1.0, fact.provenance, draft)
            _put(draft.prop_objs, prop, fact.head, fact.weight, fact.provenance, draft)
        else:
            prop = property_node(fact.rel, fact.tail)
            self.term_props.setdefault(fact.tail, set()).add(prop)
            _put(draft.prop_objs, prop, fact.head, fact.weight, fact.provenance, draft)

    def property_fact(self, fact: Fact) -> None:
        """``x UsedFor verb`` where x is a property term of some object -> verb -> x's node."""
        found = self.matcher.match(fact.tail)
        if found is None:
            self.draft.count(MAP_STAGE, "skipped: use of a property is no vocabulary verb")
            return
        for prop in sorted(self.term_props[fact.head]):
            _put(self.draft.verb_props, found[0], prop, fact.weight, fact.provenance, self.draft)

    def negation(self, fact: Fact, objects: set[str]) -> None:
        """A ``Not*`` fact removes the edge its positive form would give; counted either way."""
        positive = NEGATIONS[fact.rel]
        if fact.head not in objects and fact.head not in self.term_props:
            self.draft.count(MAP_STAGE, "skipped: negation about a term outside the objects")
            return
        removed = 0
        if fact.head in objects:
            removed += self._drop_object_edge(positive, fact)
        if positive in USE_RELATIONS and fact.head in self.term_props:
            found = self.matcher.match(fact.tail)
            if found is not None:
                for prop in sorted(self.term_props[fact.head]):
                    removed += self._drop(self.draft.verb_props, found[0], prop, fact)
        if not removed:
            self.draft.count(MAP_STAGE, "negations matching no edge")

    def _drop_object_edge(self, positive: str, fact: Fact) -> int:
        if positive in USE_RELATIONS:
            found = self.matcher.match(fact.tail)
            if found is None:
                return 0
            return self._drop(self.draft.prop_objs, used_for(found[0]), fact.head, fact)
        return self._drop(self.draft.prop_objs, property_node(positive, fact.tail), fact.head, fact)

    def _drop(self, table: dict[str, dict[str, Link]], src: str, dst: str, fact: Fact) -> int:
        if dst not in table.get(src, {}):
            return 0
        del table[src][dst]
        self.draft.drop(MAP_STAGE, f"{src} -> {dst}", f"negated: {fact.rel} fact {fact.source_id}")
        return 1


def map_facts(draft: KnowledgeDraft, facts: Iterable[Fact]) -> None:
    """Turn facts into edges: object facts first, then property-term uses, then negations."""
    objects = set(draft.objects)
    mapper = FactMapper(draft, VerbMatcher(draft.verbs))
    uses: list[Fact] = []
    negations: list[Fact] = []
    for fact in facts:
        if fact.rel in NEGATIONS:
            negations.append(fact)
            continue
        if fact.rel in USE_RELATIONS:
            uses.append(fact)
        if fact.head in objects:
            mapper.object_fact(fact)
        elif fact.rel not in USE_RELATIONS:
            draft.count(MAP_STAGE, "skipped: property of a term outside the objects")
    for fact in uses:
        if fact.head in mapper.term_props:
            mapper.property_fact(fact)
        elif fact.head not in objects:
            draft.count(MAP_STAGE, "skipped: use of a term outside the objects")
    for fact in negations:
        mapper.negation(fact, objects)
    for verb in draft.verbs:
        if not draft.verb_props.get(verb):
            draft.count(MAP_STAGE, "verbs without any fact")


# --------------------------------------------------------------------------------------------
# the pass


@dataclass(frozen=True)
class Spec:
    """A parsed ``--conceptnet`` value: where facts come from."""

    kind: str  # omcs | csv | api
    location: str


def parse_spec(spec: str) -> Spec:
    """``omcs`` / ``omcs:<folder>`` / ``csv:<path>`` / ``api`` / ``api:<base_url>``."""
    kind, _, rest = spec.strip().partition(":")
    if kind == "omcs":
        return Spec("omcs", rest or str(shared_dir() / "data" / "conceptnet"))
    if kind == "csv" and rest:
        return Spec("csv", rest)
    if kind == "api":
        return Spec("api", rest or DEFAULT_API_URL)
    raise ConceptNetInputError(
        f"unknown ConceptNet source {spec!r}; use 'omcs' (the shared OMCS files, default), "
        f"'csv:<assertions.csv[.gz]>' or 'api[:<base_url>]'"
    )


def local_files(spec: str) -> list[Path]:
    """The local files a ``--conceptnet`` spec reads (none for the API)."""
    parsed = parse_spec(spec)
    if parsed.kind == "omcs":
        return [Path(parsed.location) / name for name in OMCS_FILES]
    return [Path(parsed.location)] if parsed.kind == "csv" else []


def check_spec(spec: str) -> None:
    """Check a ``--conceptnet`` spec and the head of every file it names, before a build's work."""
    for path in local_files(spec):
        check_local_file(path)


def conceptnet_draft(
    verbs: Sequence[str], objects: Sequence[str], spec: str = "omcs",
    cache: RecordCache | None = None, progress: Progress | None = None,
    *, api: ConceptNetAPI | None = None,
) -> KnowledgeDraft:
    """The CRAFT baseline KB: verb -> property -> object edges read off ConceptNet facts.

    ``api`` injects a configured client (tests, mirrors); otherwise one is made from ``spec``
    with ``cache`` as its record store. ``verbs`` and ``objects`` are vocabulary names, already
    normalized (``read_vocabulary``); fact names go through the same normalization.
    """
    draft = KnowledgeDraft(verbs=list(verbs), objects=list(objects))
    parsed = parse_spec(spec)
    stats: Counter[str] = Counter()
    if parsed.kind == "api":
        client = api or ConceptNetAPI(base_url=parsed.location, cache=cache)
        try:
            info = _from_api(draft, client, stats, progress)
        finally:
            if api is None:
                client.close()
    else:
        info = _from_files(draft, parsed, stats, progress)
    for what, n in sorted(stats.items()):
        draft.count(READ_STAGE, what, n)
    draft.sources.append(info)
    return draft


def _wanted(objects: set[str]) -> Callable[[Fact], bool]:
    """Facts worth keeping from a file: about an object, or a use/negation of any term."""
    return lambda f: f.head in objects or f.rel in USE_RELATIONS or f.rel in NEGATIONS


def _from_files(
    draft: KnowledgeDraft, spec: Spec, stats: Counter[str], progress: Progress | None
) -> SourceInfo:
    if spec.kind == "omcs":
        folder = Path(spec.location)
        paths = [folder / name for name in OMCS_FILES]
        facts: Iterator[Fact] = read_omcs(paths, stats)
        provider, model = "omcs", "omcs-true-facts"
    else:
        paths = [Path(spec.location)]
        facts = read_assertions_csv(paths[0], stats)
        provider, model = "conceptnet-csv", "conceptnet5-assertions"
    wanted = _wanted(set(draft.objects))
    kept = [f for f in facts if wanted(f)]
    if progress:
        progress("conceptnet", len(paths))
    stats["facts kept for mapping"] += len(kept)
    map_facts(draft, kept)
    ids = [f"{p.name}@sha256:{sha256_file(p)}" for p in paths]
    return SourceInfo(kind="conceptnet", provider=provider, model=model, prompts=ids,
                      records=stats["lines read"])


def _from_api(
    draft: KnowledgeDraft, api: ConceptNetAPI, stats: Counter[str], progress: Progress | None
) -> SourceInfo:
    """Object facts via ``/query?start=<object>``, then the uses of each property term found."""
    facts: list[Fact] = []
    keys: set[str] = set()
    for obj in draft.objects:
        facts.extend(_start_facts(api, obj, stats, keys))
        if progress:
            progress("conceptnet", 1)
    terms = sorted({f.tail for f in facts if f.rel in PROPERTY_RELATIONS} - set(draft.objects))
    for term in terms:
        facts.extend(f for f in _start_facts(api, term, stats, keys) if f.rel in USE_RELATIONS
                     or f.rel in NEGATIONS)
        if progress:
            progress("conceptnet", 1)
    stats["facts kept for mapping"] += len(facts)
    map_facts(draft, facts)
    for what, n in api.stats.items():
        stats[what] += n
    return SourceInfo(kind="conceptnet", provider=API_PROVIDER, model=api.base_url,
                      prompts=[API_REQUEST_ID], records=len(keys))


def _start_facts(api: ConceptNetAPI, name: str, stats: Counter[str], keys: set[str]) -> list[Fact]:
    listing = api.query(start=term_uri(name))
    keys.update(listing.record_keys)
    return [f for f in api_facts(listing, stats) if f.head == name]
