"""ConceptNet source: REST client (local server replaying recorded pages), CSV dump, OMCS, draft.

The API tests serve ``shared/data/conceptnet/api_samples/c_en_spoon_pages.json`` from 127.0.0.1
(``tests.servers.ConceptNetPages``) and check pagination, retries, the page bound and offline
replay from records. The OMCS tests assert edges whose facts were grepped from the shared files.
"""

from __future__ import annotations

import gzip
import hashlib
import shutil
from collections import Counter
from pathlib import Path

import pytest
from servers import ConceptNetPages, FakeServer, Reply

from craft_e.compiler.cache import RecordCache
from craft_e.compiler.draft import KnowledgeDraft
from craft_e.compiler.sources.conceptnet import (
    API_PROVIDER,
    CONCEPTNET_SOURCE,
    MAP_STAGE,
    READ_STAGE,
    ConceptNetAPI,
    ConceptNetInputError,
    Fact,
    VerbMatcher,
    api_facts,
    canonical_relation,
    conceptnet_draft,
    english_term,
    parse_spec,
    read_assertions_csv,
    read_omcs,
    scaled_weight,
)
from craft_e.compiler.sources.llm import SourceError
from craft_e.paths import shared_dir

DATA = shared_dir() / "data" / "conceptnet"
SPOON_PAGES = DATA / "api_samples" / "c_en_spoon_pages.json"
CSV_SAMPLE = DATA / "assertions_format_sample.csv"
OMCS = [DATA / n for n in ("omcs_test.txt", "omcs_dev1.txt", "omcs_dev2.txt")]



@pytest.fixture(autouse=True)
def _shared_data_present() -> None:
    """These are contract tests against shared fixtures: missing data is a failure, not a skip."""
    missing = [str(p) for p in (SPOON_PAGES, CSV_SAMPLE, *OMCS) if not p.is_file()]
    assert not missing, f"shared ConceptNet data missing: {missing}; set CRAFT_SHARED to the shared folder"


def _no_sleep(_: float) -> None:
    return None


@pytest.fixture
def pages() -> ConceptNetPages:
    return ConceptNetPages(SPOON_PAGES)


def _edges(draft: KnowledgeDraft) -> set[tuple[str, str, str]]:
    """(verb, property, object) paths of a draft, for compact assertions."""
    return {
        (verb, prop, obj)
        for verb, props in draft.verb_props.items()
        for prop in props
        for obj in draft.prop_objs.get(prop, {})
    }


# -- REST client ---------------------------------------------------------------------------


def test_term_edges_follow_next_page_until_exhausted(tmp_path: Path, pages: ConceptNetPages) -> None:
    cache = RecordCache(tmp_path)
    with FakeServer(responder=pages) as server:
        api = ConceptNetAPI(base_url=server.url, cache=cache, sleep=_no_sleep)
        listing = api.term_edges("spoon")
    assert len(listing.edges) == len(pages.edges) == 220
    assert not listing.truncated
    # first page without offset, then every recorded nextPage, then the empty last page
    offsets = [r.query.get("offset") for r in server.received]
    assert offsets == [None, *[str(o) for o in range(20, 240, 20)]]
    assert all(r.route == "/c/en/spoon" for r in server.received)
    records = [r for _, r in cache.iter_records(CONCEPTNET_SOURCE)]
    assert len(records) == len(listing.record_keys) == 12
    assert {r.request.provider for r in records} == {API_PROVIDER}
    assert all(r.request.params["url"] == f"{server.url}/c/en/spoon" for r in records)
    page_ids = [e["@id"] for _, e in listing.edges]
    assert page_ids == [e["@id"] for e in pages.edges]  # order kept across pages


def test_records_replay_offline(tmp_path: Path, pages: ConceptNetPages) -> None:
    cache = RecordCache(tmp_path)
    with FakeServer(responder=pages) as server:
        url = server.url
        first = ConceptNetAPI(base_url=url, cache=cache, sleep=_no_sleep).term_edges("spoon")
    # the server is gone: every page must come from the records
    api = ConceptNetAPI(base_url=url, cache=cache, attempts=1, sleep=_no_sleep)
    again = api.term_edges("spoon")
    assert again == first
    assert api.stats["pages from cache"] == 12 and api.stats["pages fetched"] == 0


def test_page_bound_stops_and_reports_truncation(pages: ConceptNetPages) -> None:
    with FakeServer(responder=pages) as server:
        api = ConceptNetAPI(base_url=server.url, max_pages=3, sleep=_no_sleep)
        listing = api.term_edges("spoon")
    assert len(server.received) == 3 and len(listing.edges) == 60
    assert listing.truncated and api.stats["listings truncated at max pages"] == 1


def test_502_then_success_is_retried(tmp_path: Path, pages: ConceptNetPages) -> None:
    sleeps: list[float] = []
    cache = RecordCache(tmp_path)
    with FakeServer([Reply(502, b"Bad Gateway")], responder=pages) as server:
        api = ConceptNetAPI(base_url=server.url, cache=cache, max_pages=2, sleep=sleeps.append)
        listing = api.term_edges("spoon")
    assert [r.query.get("offset") for r in server.received] == [None, None, "20"]
    assert sleeps == [0.5] and len(listing.edges) == 40
    assert len(list(cache.iter_records(CONCEPTNET_SOURCE))) == 2  # nothing stored for the 502


def test_page_that_is_not_json_is_retried(pages: ConceptNetPages) -> None:
    with FakeServer([Reply(200, b"<html>maintenance</html>")], responder=pages) as server:
        listing = ConceptNetAPI(base_url=server.url, max_pages=1, sleep=_no_sleep).term_edges("spoon")
    assert len(server.received) == 2 and len(listing.edges) == 20


def test_persistent_5xx_raises_source_error(tmp_path: Path) -> None:
    cache = RecordCache(tmp_path)
    with FakeServer(responder=lambda r: Reply(503, b"down")) as server:
        api = ConceptNetAPI(base_url=server.url, cache=cache, attempts=3, sleep=_no_sleep)
        with pytest.raises(SourceError, match="gave up after 3 attempts"):
            api.term_edges("spoon")
    assert len(server.received) == 3
    assert list(cache.iter_records(CONCEPTNET_SOURCE)) == []


def test_404_is_not_retried() -> None:
    not_found = FakeServer(responder=lambda r: Reply(404, {"error": "not found"}))
    with not_found as server, pytest.raises(SourceError, match="HTTP 404"):
        ConceptNetAPI(base_url=server.url, sleep=_no_sleep).term_edges("spoon")
    assert len(server.received) == 1


def test_api_facts_keep_english_relations_used(pages: ConceptNetPages) -> None:
    with FakeServer(responder=pages) as server:
        listing = ConceptNetAPI(base_url=server.url, sleep=_no_sleep).term_edges("spoon")
    stats: Counter[str] = Counter()
    facts = {(f.rel, f.head, f.tail, f.weight) for f in api_facts(listing, stats)}
    assert ("UsedFor", "spoon", "stirring coffee", 1.0) in facts  # weight 2.0 / scale 2.0
    assert ("CapableOf", "spoon", "eat with", 0.5) in facts  # weight 1.0
    assert ("HasA", "spoon", "cupped end and handle", 0.5) in facts
    assert stats["edges read"] == 220
    assert stats["skipped: relation not used"] + stats["skipped: not English"] + len(facts) <= 220


def test_api_draft_builds_and_replays_offline(tmp_path: Path, pages: ConceptNetPages) -> None:
    cache = RecordCache(tmp_path)
    verbs, objects = ["eat", "scoop", "stir", "cut"], ["spoon"]
    with FakeServer(responder=pages) as server:
        url = server.url
        draft = conceptnet_draft(verbs, objects, f"api:{url}", cache)
    # /query?start= for the object, then for the property term it has
    assert [r.query["start"] for r in server.received] == ["/c/en/spoon", "/c/en/cupped_end_and_handle"]
    assert {("eat", "used for eat", "spoon"), ("scoop", "used for scoop", "spoon"),
            ("stir", "used for stir", "spoon")} <= _edges(draft)
    assert "cut" not in draft.verb_props  # no fact says a spoon cuts: no edge is invented
    assert draft.prop_objs["has cupped end and handle"]["spoon"].weight == 0.5
    assert draft.counters[MAP_STAGE]["verbs without any fact"] == 1
    link = draft.prop_objs["used for stir"]["spoon"]
    assert "/a/[/r/UsedFor/,/c/en/spoon/,/c/en/stirring_coffee/]" in link.provenance
    assert any(len(p) == 64 for p in link.provenance)  # the page record's key
    (info,) = draft.sources
    assert (info.kind, info.provider, info.records) == ("conceptnet", API_PROVIDER, 2)

    replayed = conceptnet_draft(verbs, objects, f"api:{url}", cache)  # server closed
    assert replayed.verb_props == draft.verb_props and replayed.prop_objs == draft.prop_objs
    assert replayed.counters[READ_STAGE]["pages from cache"] == 2


# -- assertions CSV ------------------------------------------------------------------------

CSV_FACTS = {
    ("UsedFor", "balalaika", "make music", 1.0),  # weight 2.828 -> capped at 1
    ("UsedFor", "balalaika", "making music", 0.5),
    ("HasProperty", "education in united state", "certainly thing", 0.5),
}


def test_csv_reader_on_format_sample() -> None:
    stats: Counter[str] = Counter()
    facts = list(read_assertions_csv(CSV_SAMPLE, stats))
    assert {(f.rel, f.head, f.tail, f.weight) for f in facts} == CSV_FACTS
    assert facts[1].source_id == "/a/[/r/UsedFor/,/c/en/balalaika/,/c/en/make_music/]"
    assert stats["lines read"] == 764
    assert stats["skipped: not English"] == 4  # ja/zh UsedFor and CapableOf lines


def test_csv_reader_reads_gzip(tmp_path: Path) -> None:
    gz = tmp_path / "assertions.csv.gz"
    with CSV_SAMPLE.open("rb") as src, gzip.open(gz, "wb") as dst:
        shutil.copyfileobj(src, dst)
    assert list(read_assertions_csv(gz)) == list(read_assertions_csv(CSV_SAMPLE))


def test_csv_reader_rejects_other_files(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("/a/x\t/r/UsedFor\t/c/en/a\t/c/en/b\t{}\nnot\ta dump\n")
    with pytest.raises(ConceptNetInputError, match=r"bad\.csv:2: expected 5 tab-separated"):
        list(read_assertions_csv(bad))
    with pytest.raises(ConceptNetInputError, match="file not found"):
        list(read_assertions_csv(tmp_path / "missing.csv"))


def test_csv_draft_merges_facts_and_names_the_file_hash() -> None:
    draft = conceptnet_draft(["make"], ["balalaika"], f"csv:{CSV_SAMPLE}")
    link = draft.prop_objs["used for make"]["balalaika"]
    assert link.weight == 1.0 and len(link.provenance) == 2  # make music + making music
    assert draft.counters[MAP_STAGE]["repeated facts merged into an edge"] >= 1
    (info,) = draft.sources
    digest = hashlib.sha256(CSV_SAMPLE.read_bytes()).hexdigest()
    assert info.provider == "conceptnet-csv"
    assert info.prompts == [f"assertions_format_sample.csv@sha256:{digest}"]


# -- OMCS ----------------------------------------------------------------------------------

OMCS_VERBS = ["cut", "open", "write", "eat", "drink", "break", "sweep", "tighten", "fly"]
OMCS_OBJECTS = ["knife", "key", "pen", "spoon", "fork", "cup", "hammer", "toothbrush", "broom",
                "bottle", "wrench", "glass"]


def test_omcs_reader_keeps_true_facts_only() -> None:
    stats: Counter[str] = Counter()
    facts = list(read_omcs(OMCS, stats))
    triples = {(f.rel, f.head, f.tail) for f in facts}
    assert ("UsedFor", "knife", "cut") in triples  # omcs: UsedFor knife cut 1
    assert ("UsedFor", "knife", "yellow") not in triples  # omcs: UsedFor knife yellow 0
    assert stats["lines read"] == 4800
    assert stats["skipped: false statement (label 0)"] == 2400
    assert all(f.weight == 1.0 for f in facts)


def test_omcs_draft_has_the_grepped_edges() -> None:
    draft = conceptnet_draft(OMCS_VERBS, OMCS_OBJECTS, f"omcs:{DATA}")
    edges = _edges(draft)
    expected = {
        ("cut", "used for cut", "knife"),  # UsedFor knife cut / cut food
        ("open", "used for open", "key"),  # UsedFor key open door / open lock
        ("write", "used for write", "pen"),  # UsedFor pen write
        ("eat", "used for eat", "spoon"),  # UsedFor spoon eat
        ("eat", "used for eat", "fork"),  # UsedFor fork eat food with
        ("drink", "used for drink", "cup"),  # UsedFor cup drink / drink from
        ("break", "used for break", "hammer"),  # CapableOf hammer break glass
        ("sweep", "used for sweep", "broom"),  # UsedFor broom sweep
        ("tighten", "used for tighten", "wrench"),
        ("drink", "made of glass", "cup"),  # MadeOf cup glass + UsedFor glass drink
        ("drink", "made of glass", "bottle"),  # MadeOf bottle glass
    }
    assert expected <= edges
    assert draft.prop_objs["has bristle"]["toothbrush"].weight == 1.0  # HasA toothbrush bristle
    assert draft.prop_objs["made of plastic"].keys() >= {"cup", "bottle"}
    assert draft.prop_objs["clear"]["glass"].weight == 1.0  # HasProperty glass clear
    assert draft.verb_props["cut"]["used for cut"].weight == 1.0
    assert "fly" not in draft.verb_props  # nothing here is used for flying: reported, not padded
    assert draft.counters[MAP_STAGE]["verbs without any fact"] == 1
    assert all(link.relation == "conceptnet" for props in draft.verb_props.values()
               for link in props.values())
    provenance = draft.prop_objs["used for cut"]["knife"].provenance
    assert all(p.startswith(("omcs_test.txt:", "omcs_dev1.txt:", "omcs_dev2.txt:")) for p in provenance)
    (info,) = draft.sources
    assert info.provider == "omcs" and info.records == 4800 and len(info.prompts) == 3


def test_omcs_draft_is_deterministic() -> None:
    a = conceptnet_draft(OMCS_VERBS, OMCS_OBJECTS, f"omcs:{DATA}")
    b = conceptnet_draft(OMCS_VERBS, OMCS_OBJECTS, f"omcs:{DATA}")
    assert (a.verb_props, a.prop_objs, a.counters) == (b.verb_props, b.prop_objs, b.counters)


def test_negated_facts_drop_edges_and_are_counted(tmp_path: Path) -> None:
    for name in ("omcs_test.txt", "omcs_dev1.txt", "omcs_dev2.txt"):
        (tmp_path / name).write_text("")
    (tmp_path / "omcs_test.txt").write_text(
        "UsedFor\tknife\tcut bread\t1\n"
        "HasProperty\tknife\tsharp\t1\n"
        "UsedFor\tsharp\tcut\t1\n"
        "HasProperty\tspoon\tsharp\t1\n"
        "NotHasProperty\tspoon\tsharp\t1\n"
        "NotCapableOf\tknife\tcut\t0\n"  # a false negation is no negation
        "CapableOf\tspoon\tcut\t1\n"
        "NotCapableOf\tspoon\tcutting\t1\n"
    )
    draft = conceptnet_draft(["cut"], ["knife", "spoon"], f"omcs:{tmp_path}")
    assert set(draft.prop_objs["used for cut"]) == {"knife"}
    assert set(draft.prop_objs["sharp"]) == {"knife"}
    assert draft.verb_props["cut"]["sharp"].provenance == ("omcs_test.txt:3",)
    dropped = {(d.item, d.reason) for d in draft.drops}
    assert dropped == {
        ("sharp -> spoon", "negated: NotHasProperty fact omcs_test.txt:5"),
        ("used for cut -> spoon", "negated: NotCapableOf fact omcs_test.txt:8"),
    }
    assert draft.counters[MAP_STAGE]["dropped: negated"] == 2


def test_omcs_reader_names_bad_lines(tmp_path: Path) -> None:
    bad = tmp_path / "omcs.txt"
    bad.write_text("UsedFor\tpen\twrite\t1\nUsedFor pen write 1\n")
    with pytest.raises(ConceptNetInputError, match=r"omcs\.txt:2: expected 'rel<TAB>head"):
        list(read_omcs([bad]))


# -- names, matching, specs ----------------------------------------------------------------


def test_verb_matcher_is_conservative() -> None:
    matcher = VerbMatcher(["cut", "stir", "scoop", "write", "write with", "eat", "tie", "use"])
    assert matcher.match("cut") == ("cut", True)
    assert matcher.match("cutting") == ("cut", True)
    assert matcher.match("stirring coffee") == ("stir", False)
    assert matcher.match("scooping food") == ("scoop", False)
    assert matcher.match("eats") == ("eat", True)
    assert matcher.match("tying knot") == ("tie", False)
    assert matcher.match("using") == ("use", True)
    assert matcher.match("write with pen") == ("write with", False)
    assert matcher.match("write letter") == ("write", False)
    assert matcher.match("make cut") is None  # the verb must lead the phrase
    assert matcher.match("cutter") is None


def test_names_and_weights() -> None:
    assert canonical_relation("/r/UsedFor") == canonical_relation("usedfor") == "UsedFor"
    assert canonical_relation("/r/Synonym") == "Synonym"
    assert english_term("/c/en/make_music/v/wn/creation") == "make_music"
    assert english_term("/c/ja/テスト") is None and english_term("http://x") is None
    assert scaled_weight(2.828) == 1.0 and scaled_weight(1.0) == 0.5 and scaled_weight(-1) == 0.0
    assert Fact("UsedFor", "a", "b", 1.0, "x", "k").provenance == ("k", "x")


def test_spec_parsing() -> None:
    assert parse_spec("omcs").kind == "omcs"
    assert parse_spec("csv:/data/assertions.csv.gz").location == "/data/assertions.csv.gz"
    assert parse_spec("api").location == "https://api.conceptnet.io"
    assert parse_spec("api:http://localhost:8084").location == "http://localhost:8084"
    with pytest.raises(ValueError, match="unknown ConceptNet source 'wordnet'"):
        parse_spec("wordnet")
    with pytest.raises(ValueError, match="unknown ConceptNet source"):
        parse_spec("csv:")
