"""Property-based and fuzz tests: every reader of untrusted input fails only in its documented way.

Readers under test and their only allowed failure:

- ``verify_package`` / ``unpack_package``: :class:`PackageError` — and never a file outside
  ``dest``, never a partial ``dest`` or staging folder left after a failure;
- ``load_bundle`` on a damaged folder: :class:`BundleError`;
- ``read_vocabulary``: :class:`VocabError`;  ``RecordCache.get``: :class:`CacheError`;
- ``record_answers``: :class:`CurationError`.

All runs are deterministic (``derandomize=True``) and sized to keep the module well under a
minute. Seeds come from a tiny *real* bundle built by the curation flow (``craftc curate record``
then ``craftc build``) in a session fixture. Each test counts the cases it ran and how they
ended; the counts are printed at the end of the module (and asserted to be non-trivial).
Defects fuzzing found (unwrapped name errors and non-UTF-8 answers in curation, deeply nested
manifest JSON) are fixed and pinned by the regression tests at the bottom.
"""

from __future__ import annotations

import contextlib
import gzip
import io
import json
import os
import shutil
import tarfile
import tempfile
from collections import Counter, defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from craft_e.compiler.cache import CacheError, RecordCache
from craft_e.compiler.cli import app as craftc
from craft_e.compiler.curate import CurationError, record_answers
from craft_e.compiler.pack import archive_bytes, keygen, load_signing_key, pack_bundle, seal
from craft_e.compiler.sources.llm import LLMSource
from craft_e.compiler.vocab import VocabError, read_vocabulary
from craft_e.runtime.kb.bundle import BundleError, load_bundle, read_manifest, verify_files
from craft_e.runtime.kb.package import PackageError, unpack_package, verify_package
from craft_e.schemas.names import normalize_name, normalize_verb
from craft_e.schemas.v1.bundle import Manifest

VERBS_TXT = "cut\nscoop\n"
OBJECTS_TXT = "knife\nspoon\nbowl\n"
VP_JSONL = """\
{"verb": "cut", "properties": [{"name": "sharp edge", "weight": 0.95}, {"name": "has a blade", "weight": 0.9}, {"name": "rigid", "weight": 0.6}, {"name": "has a handle", "weight": 0.5}, {"name": "metallic", "weight": 0.4}, {"name": "thin", "weight": 0.4}, {"name": "pointed tip", "weight": 0.3}, {"name": "serrated", "weight": 0.3}, {"name": "hinged", "weight": 0.2}, {"name": "hand-held", "weight": 0.5}]}
{"verb": "scoop", "properties": [{"name": "concave", "weight": 0.95}, {"name": "has a handle", "weight": 0.7}, {"name": "rigid", "weight": 0.5}, {"name": "holds liquid", "weight": 0.6}, {"name": "rounded", "weight": 0.4}, {"name": "hand-held", "weight": 0.5}, {"name": "shallow bowl shape", "weight": 0.8}, {"name": "smooth", "weight": 0.2}, {"name": "metallic", "weight": 0.2}, {"name": "long", "weight": 0.3}]}
"""
OP_JSONL = """\
{"object": "knife", "scores": [{"property": "sharp edge", "weight": 0.95}, {"property": "has a blade", "weight": 1.0}, {"property": "rigid", "weight": 0.9}, {"property": "has a handle", "weight": 0.95}, {"property": "metallic", "weight": 0.8}, {"property": "hand-held", "weight": 0.95}, {"property": "thin", "weight": 0.8}, {"property": "pointed tip", "weight": 0.7}]}
{"object": "spoon", "scores": [{"property": "concave", "weight": 0.9}, {"property": "has a handle", "weight": 0.95}, {"property": "rigid", "weight": 0.9}, {"property": "shallow bowl shape", "weight": 0.9}, {"property": "hand-held", "weight": 0.95}, {"property": "metallic", "weight": 0.7}, {"property": "smooth", "weight": 0.8}, {"property": "rounded", "weight": 0.7}]}
{"object": "bowl", "scores": [{"property": "concave", "weight": 0.95}, {"property": "holds liquid", "weight": 0.9}, {"property": "rounded", "weight": 0.9}, {"property": "rigid", "weight": 0.8}, {"property": "smooth", "weight": 0.8}]}
"""

#: per test: outcome -> count (printed at module teardown)
CASES: dict[str, Counter[str]] = defaultdict(Counter)


def fuzz(max_examples: int) -> Callable[[Any], Any]:
    """Deterministic hypothesis settings shared by every test here (no example database)."""
    return settings(
        derandomize=True,
        max_examples=max_examples,
        deadline=None,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )


@pytest.fixture(scope="module", autouse=True)
def report_case_counts(request: pytest.FixtureRequest) -> Iterator[None]:
    yield
    thin = {name: sum(c.values()) for name, c in CASES.items() if sum(c.values()) < 100}
    assert not thin, f"fuzz tests that ran suspiciously few cases: {thin}"
    lines = ["", "fuzz cases per test (outcome: count):"]
    for name, counts in sorted(CASES.items()):
        detail = ", ".join(f"{k}: {v}" for k, v in sorted(counts.items()))
        lines.append(f"  {name}: {sum(counts.values())} cases ({detail})")
    capture = request.config.pluginmanager.get_plugin("capturemanager")
    with capture.global_and_fixture_disabled() if capture else contextlib.nullcontext():
        print("\n".join(lines), flush=True)


def _scratch_root() -> str | None:
    """A RAM-backed folder when there is one: the code under test fsyncs every file it writes,
    which on a real disk would dominate thousands of fuzz cases (durability is not under test
    here; the install tests cover crashes)."""
    shm = Path("/dev/shm")
    return str(shm) if shm.is_dir() and os.access(shm, os.W_OK) else None


@pytest.fixture(scope="session")
def real_kb() -> Iterator[tuple[Path, Path]]:
    """A tiny real bundle: curated answers recorded, then ``craftc build`` (replay provider)."""
    with tempfile.TemporaryDirectory(prefix="craft-fuzz-kb-", dir=_scratch_root()) as tmp:
        yield _build_real_kb(Path(tmp))


def _build_real_kb(root: Path) -> tuple[Path, Path]:
    for name, text in {
        "verbs.txt": VERBS_TXT,
        "objects.txt": OBJECTS_TXT,
        "vp.jsonl": VP_JSONL,
        "op.jsonl": OP_JSONL,
    }.items():
        (root / name).write_text(text)
    runner = CliRunner()
    vocab = ["--verbs", str(root / "verbs.txt"), "--objects", str(root / "objects.txt"),
             "--prompts", "v1"]
    cache = ["--cache", str(root / "cache")]
    for prompt, answers in (("verb_properties", "vp.jsonl"), ("object_properties", "op.jsonl")):
        args = ["curate", "record", "--prompt", prompt, "--answers", str(root / answers)]
        result = runner.invoke(craftc, [*args, *vocab, *cache])
        assert result.exit_code == 0, result.output
    result = runner.invoke(craftc, ["build", *vocab, *cache, "--out", str(root / "kb"), "--quiet"])
    assert result.exit_code == 0, result.output
    return root / "kb", root / "cache"


@pytest.fixture(scope="module")
def signed(real_kb: tuple[Path, Path]) -> Iterator[dict[str, Any]]:
    """The real bundle packed both ways, the key pair, and a scratch folder."""
    with tempfile.TemporaryDirectory(prefix="craft-fuzz-", dir=_scratch_root()) as tmp:
        yield _sign_real_kb(real_kb, Path(tmp))


def _sign_real_kb(real_kb: tuple[Path, Path], root: Path) -> dict[str, Any]:
    pair = keygen(root / "keys")
    packages = {
        c: pack_bundle(real_kb[0], pair.private_key, root / f"kb-{c}.craft", compression=c).out
        for c in ("gzip", "none")
    }
    scratch = root / "scratch"
    scratch.mkdir()
    return {
        "packages": {c: p.read_bytes() for c, p in packages.items()},
        "public": pair.public_key,
        "seed": load_signing_key(pair.private_key)[0],
        "scratch": scratch,
    }


def test_seed_bundle_and_package_are_valid(
    real_kb: tuple[Path, Path], signed: dict[str, Any]
) -> None:
    """The fuzz seeds are valid, so every rejection below is caused by the mutation."""
    kb = load_bundle(real_kb[0])
    assert kb.manifest.verbs == ["cut", "scoop"] and kb.energy.shape == (2, 3)
    for compression, data in signed["packages"].items():
        with tempfile.TemporaryDirectory(dir=signed["scratch"]) as tmp:
            path = Path(tmp) / "kb.craft"
            path.write_bytes(data)
            packed = load_bundle(path, trusted_keys=[signed["public"].read_text()])
            assert packed.manifest == kb.manifest, compression
            np.testing.assert_array_equal(packed.energy, kb.energy)


# --------------------------------------------------------------------------- packages


def _tree(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


def _unpack_outcome(data: bytes, public: Path, scratch: Path, name: str) -> str:
    """Unpack ``data``; check the no-escape / no-partial invariants; return the outcome."""
    with tempfile.TemporaryDirectory(dir=scratch) as tmp:
        work = Path(tmp)
        pkg = work / "in.craft"
        pkg.write_bytes(data)
        dest = work / "out" / "dest"
        try:
            unpack_package(pkg, [public], dest)
        except PackageError:
            assert _tree(work) <= {"in.craft", "out"}, f"{name}: leftovers {_tree(work)}"
            CASES[name]["PackageError"] += 1
            return "rejected"
        unpacked = {p.name for p in dest.iterdir()}
        assert unpacked <= set(BUNDLE_FILE_NAMES), unpacked
        assert _tree(work) == {"in.craft", "out", "out/dest"} | {f"out/dest/{n}" for n in unpacked}
        verify_files(dest, read_manifest(dest))  # success means a fully verified bundle
        CASES[name]["accepted"] += 1
        return "accepted"


@fuzz(max_examples=300)
@given(
    data=st.one_of(
        st.binary(max_size=2048),
        st.binary(max_size=1024).map(lambda b: b"CRAFTPK1" + b),
        st.tuples(st.integers(0, 600), st.binary(max_size=1024)).map(
            lambda t: b"CRAFTPK1" + t[0].to_bytes(4, "big") + t[1]
        ),
    )
)
def test_random_bytes_are_refused(signed: dict[str, Any], data: bytes) -> None:
    outcome = _unpack_outcome(data, signed["public"], signed["scratch"], "random bytes -> unpack")
    assert outcome == "rejected"


Mutation = tuple[str, int, int, bytes]


def _apply(data: bytes, mutations: list[Mutation]) -> bytes:
    out = bytearray(data)
    for kind, pos, arg, junk in mutations:
        pos = pos % (len(out) + 1)
        if kind == "flip" and out:
            out[pos % len(out)] ^= 1 << (arg % 8)
        elif kind == "truncate":
            del out[pos:]
        elif kind == "append":
            out += junk
        elif kind == "insert":
            out[pos:pos] = junk
        elif kind == "delete":
            del out[pos : pos + 1 + arg % 64]
        elif kind == "overwrite":
            out[pos : pos + len(junk)] = junk
    return bytes(out)


def mutations(header_bias: int) -> st.SearchStrategy[list[Mutation]]:
    """1-3 edits; half of the positions land in the first ``header_bias`` bytes (the header)."""
    position = st.one_of(st.integers(0, header_bias), st.integers(0, 1 << 20))
    edit = st.tuples(
        st.sampled_from(["flip", "truncate", "append", "insert", "delete", "overwrite"]),
        position,
        st.integers(0, 255),
        st.binary(min_size=1, max_size=32),
    )
    return st.lists(edit, min_size=1, max_size=3)


HEADER_FIELDS = [
    ("kb_version", '"9.9.9"'),
    ("kb_name", '"other"'),
    ("payload_bytes", "1"),
    ("compression", '"none"'),
    ("key_id", '"0000000000000000"'),
    ("alg", '"rsa"'),
    ("format", '"craft-package/2"'),
    ("signature", "null"),
]


@fuzz(max_examples=400)
@given(
    compression=st.sampled_from(["gzip", "none"]),
    edits=mutations(header_bias=700),
    header_edit=st.one_of(st.none(), st.sampled_from(HEADER_FIELDS)),
)
def test_mutated_packages_are_refused(
    signed: dict[str, Any],
    compression: str,
    edits: list[Mutation],
    header_edit: tuple[str, str] | None,
) -> None:
    original: bytes = signed["packages"][compression]
    data = original
    if header_edit is not None:  # a semantic edit, re-serialized so it stays valid JSON
        end = 12 + int.from_bytes(data[8:12], "big")
        header = json.loads(data[12:end])
        field, value = header_edit
        target = header if field in ("format", "signature") else header["statement"]
        if field in ("key_id", "alg"):
            target = header["signature"]
        target[field] = json.loads(value)
        blob = json.dumps(header, sort_keys=True, separators=(",", ":")).encode()
        data = data[:8] + len(blob).to_bytes(4, "big") + blob + data[end:]
    else:
        data = _apply(data, edits)
    if data == original:  # e.g. a truncation at the very end
        CASES["mutated package -> unpack"]["no-op edit (skipped)"] += 1
        return
    outcome = _unpack_outcome(
        data, signed["public"], signed["scratch"], "mutated package -> unpack"
    )
    assert outcome == "rejected"


@fuzz(max_examples=250)
@given(compression=st.sampled_from(["gzip", "none"]), edits=mutations(header_bias=4096))
def test_resigned_mutated_archives_fail_only_with_package_error(
    real_kb: tuple[Path, Path], signed: dict[str, Any], compression: str, edits: list[Mutation]
) -> None:
    """Mutate the archive *inside* a valid signature: this fuzzes the tar/gzip guards."""
    original: bytes = signed["packages"][compression]
    payload = original[12 + int.from_bytes(original[8:12], "big") :]
    manifest_bytes = (real_kb[0] / "manifest.json").read_bytes()
    manifest = Manifest.model_validate_json(manifest_bytes)
    data = seal(_apply(payload, edits), manifest_bytes, manifest, signed["seed"], compression)  # type: ignore[arg-type]
    _unpack_outcome(
        data, signed["public"], signed["scratch"], "re-signed mutated archive -> unpack"
    )


MEMBER_NAMES = [
    "manifest.json",
    "graph.json",
    "graph.ttl",
    "embeddings.safetensors",
    "affordance_energy.npy",
    "report.json",
    "build_info.json",
    "../escape.txt",
    "/tmp/craft-fuzz-abs.txt",
    "sub/graph.json",
    "./graph.json",
    "graph.json/",
    "",
    ".",
    "x" * 120,
]
MEMBER_TYPES = [
    tarfile.REGTYPE,
    tarfile.AREGTYPE,
    tarfile.SYMTYPE,
    tarfile.LNKTYPE,
    tarfile.CHRTYPE,
    tarfile.BLKTYPE,
    tarfile.DIRTYPE,
    tarfile.FIFOTYPE,
    tarfile.CONTTYPE,
]


@fuzz(max_examples=250)
@given(
    members=st.lists(
        st.tuples(
            st.one_of(st.sampled_from(MEMBER_NAMES), st.text(max_size=20)),
            st.sampled_from(MEMBER_TYPES),
            st.one_of(st.none(), st.binary(max_size=64)),
            st.sampled_from(["", "manifest.json", "/etc/passwd", "../../x"]),
        ),
        max_size=9,
    ),
    keep_valid_prefix=st.integers(0, 6),
    fmt=st.sampled_from([tarfile.USTAR_FORMAT, tarfile.GNU_FORMAT, tarfile.PAX_FORMAT]),
    compression=st.sampled_from(["gzip", "none"]),
)
def test_hostile_member_lists_fail_only_with_package_error(
    real_kb: tuple[Path, Path],
    signed: dict[str, Any],
    members: list[tuple[str, bytes, bytes | None, str]],
    keep_valid_prefix: int,
    fmt: int,
    compression: str,
) -> None:
    """Signed archives of arbitrary member lists: names, types, links, sizes, duplicates."""
    kb = real_kb[0]
    order = [
        "manifest.json",
        "affordance_energy.npy",
        "embeddings.safetensors",
        "graph.json",
        "graph.ttl",
        "report.json",
    ]
    entries: list[tuple[tarfile.TarInfo, bytes]] = []
    for name in order[:keep_valid_prefix]:
        info = tarfile.TarInfo(name)
        data = (kb / name).read_bytes()
        info.size = len(data)
        entries.append((info, data))
    for name, kind, content, link in members:
        info = tarfile.TarInfo(name)
        info.type = kind
        info.linkname = link
        data = (
            (kb / name).read_bytes()
            if content is None and (kb / name).is_file()
            else content or b""
        )
        regular = kind in (tarfile.REGTYPE, tarfile.AREGTYPE, tarfile.CONTTYPE)
        info.size = len(data) if regular else 0
        entries.append((info, data if regular else b""))
    buffer = io.BytesIO()
    try:
        with tarfile.open(fileobj=buffer, mode="w", format=fmt) as archive:
            for info, data in entries:
                archive.addfile(info, io.BytesIO(data) if info.size else None)
    except (ValueError, UnicodeError):  # tarfile cannot even write this name in this format
        CASES["hostile member list -> unpack"]["unwritable by tarfile (skipped)"] += 1
        return
    payload = buffer.getvalue()
    if compression == "gzip":
        payload = gzip.compress(payload, mtime=0)
    manifest_bytes = (kb / "manifest.json").read_bytes()
    manifest = Manifest.model_validate_json(manifest_bytes)
    data = seal(payload, manifest_bytes, manifest, signed["seed"], compression)  # type: ignore[arg-type]
    _unpack_outcome(data, signed["public"], signed["scratch"], "hostile member list -> unpack")
    assert not Path("/tmp/craft-fuzz-abs.txt").exists()


def test_unsigned_archive_of_the_real_bundle_is_refused(
    real_kb: tuple[Path, Path], signed: dict[str, Any]
) -> None:
    kb = real_kb[0]
    tar = archive_bytes([(p.name, p.read_bytes()) for p in sorted(kb.iterdir())])
    with tempfile.TemporaryDirectory(dir=signed["scratch"]) as tmp:
        path = Path(tmp) / "kb.tar.gz"
        path.write_bytes(tar)
        with pytest.raises(PackageError, match="unsigned archive"):
            verify_package(path, [signed["public"]])


# --------------------------------------------------------------------------- bundle folders

BUNDLE_FILE_NAMES = [
    "manifest.json",
    "graph.json",
    "graph.ttl",
    "embeddings.safetensors",
    "affordance_energy.npy",
    "report.json",
    "build_info.json",
    "open_world.json",
    "object_sizes.json",
    "object_colours.json",
    "object_lookalikes.json",
]
JSON_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**40), 2**40)
    | st.floats(allow_nan=False)
    | st.text(max_size=12),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=10,
)


def _mangle_json(value: Any, path: list[int], action: str, replacement: Any) -> Any:
    """Edit one place in a JSON document chosen by ``path`` (indices into keys/items)."""
    if not path or not isinstance(value, dict | list) or not value:
        return replacement if action != "wrap" else [value]
    keys = sorted(value) if isinstance(value, dict) else list(range(len(value)))
    key = keys[path[0] % len(keys)]
    if len(path) == 1 and action == "delete":
        if isinstance(value, dict):
            del value[key]
        else:
            value.pop(key)
        return value
    value[key] = _mangle_json(value[key], path[1:], action, replacement)
    return value


@fuzz(max_examples=300)
@given(
    target=st.sampled_from(BUNDLE_FILE_NAMES),
    action=st.sampled_from(
        ["flip", "truncate", "delete file", "append", "random bytes", "json edit"]
    ),
    pos=st.integers(0, 1 << 16),
    bit=st.integers(0, 7),
    junk=st.binary(min_size=1, max_size=64),
    json_path=st.lists(st.integers(0, 50), min_size=1, max_size=3),
    json_action=st.sampled_from(["replace", "delete", "wrap"]),
    replacement=JSON_VALUES,
)
def test_damaged_bundle_folders_fail_only_with_bundle_error(
    real_kb: tuple[Path, Path],
    signed: dict[str, Any],
    target: str,
    action: str,
    pos: int,
    bit: int,
    junk: bytes,
    json_path: list[int],
    json_action: str,
    replacement: Any,
) -> None:
    name = "damaged bundle folder -> load_bundle"
    with tempfile.TemporaryDirectory(dir=signed["scratch"]) as tmp:
        folder = Path(tmp) / "kb"
        shutil.copytree(real_kb[0], folder)
        path = folder / target
        data = path.read_bytes()
        if action == "flip":
            i = pos % len(data)
            path.write_bytes(data[:i] + bytes([data[i] ^ (1 << bit)]) + data[i + 1 :])
        elif action == "truncate":
            path.write_bytes(data[: pos % len(data)])
        elif action == "delete file":
            path.unlink()
        elif action == "append":
            path.write_bytes(data + junk)
        elif action == "random bytes":
            path.write_bytes(junk)
        elif target.endswith(".json"):
            doc = json.loads(data)
            path.write_text(json.dumps(_mangle_json(doc, json_path, json_action, replacement)))
        else:
            path.write_bytes(data[::-1])
        changed = not path.exists() or path.read_bytes() != data
        try:
            load_bundle(folder)
        except BundleError:
            CASES[name]["BundleError"] += 1
            return
        # accepted: only files outside the verified set, or manifest fields outside the hashes
        CASES[name][f"accepted ({target})" if changed else "accepted (no-op edit)"] += 1
        assert not changed or target in ("build_info.json", "manifest.json")


# --------------------------------------------------------------------------- vocabularies


@fuzz(max_examples=300)
@given(
    data=st.one_of(
        st.binary(max_size=512),
        st.text(max_size=300).map(lambda s: s.encode("utf-8")),
        st.lists(
            st.sampled_from(["cut", "Scoop", " # c", "", "sit_on", "Knives", "x!", "\ufeff"]),
            max_size=8,
        ).map(lambda xs: "\n".join(xs).encode()),
    ),
    kind=st.sampled_from(["verbs", "objects"]),
)
def test_read_vocabulary_fails_only_with_vocab_error(
    signed: dict[str, Any], data: bytes, kind: str
) -> None:
    name = "random bytes -> read_vocabulary"
    with tempfile.TemporaryDirectory(dir=signed["scratch"]) as tmp:
        path = Path(tmp) / "vocab.txt"
        path.write_bytes(data)
        try:
            vocab = read_vocabulary(path, kind=kind)
        except VocabError:
            CASES[name]["VocabError"] += 1
            return
    CASES[name]["accepted"] += 1
    assert vocab.names and len(set(vocab.names)) == len(vocab.names)
    if kind == "verbs":  # verbs are not lemmatized, so normalization is idempotent
        assert all(normalize_verb(n) == n for n in vocab.names)
    else:
        assert all(normalize_name(n, singularize=False) == n for n in vocab.names)


# --------------------------------------------------------------------------- record cache


@fuzz(max_examples=300)
@given(
    which=st.integers(0, 4),
    action=st.sampled_from(["flip", "truncate", "random bytes", "json edit", "append"]),
    pos=st.integers(0, 1 << 16),
    bit=st.integers(0, 7),
    junk=st.binary(min_size=1, max_size=64),
    json_path=st.lists(st.integers(0, 50), min_size=1, max_size=4),
    json_action=st.sampled_from(["replace", "delete", "wrap"]),
    replacement=JSON_VALUES,
)
def test_record_cache_get_fails_only_with_cache_error(
    real_kb: tuple[Path, Path],
    signed: dict[str, Any],
    which: int,
    action: str,
    pos: int,
    bit: int,
    junk: bytes,
    json_path: list[int],
    json_action: str,
    replacement: Any,
) -> None:
    name = "mutated record file -> RecordCache.get"
    records = sorted((real_kb[1] / "llm").glob("*.json"))
    source = records[which % len(records)]
    data = source.read_bytes()
    if action == "flip":
        i = pos % len(data)
        data = data[:i] + bytes([data[i] ^ (1 << bit)]) + data[i + 1 :]
    elif action == "truncate":
        data = data[: pos % len(data)]
    elif action == "random bytes":
        data = junk
    elif action == "append":
        data += junk
    else:
        data = json.dumps(
            _mangle_json(json.loads(data), json_path, json_action, replacement)
        ).encode()
    with tempfile.TemporaryDirectory(dir=signed["scratch"]) as tmp:
        cache = RecordCache(Path(tmp))
        cache.path_for("llm", source.stem).parent.mkdir(parents=True)
        cache.path_for("llm", source.stem).write_bytes(data)
        try:
            record = cache.get("llm", source.stem)
        except CacheError:
            CASES[name]["CacheError"] += 1
            return
    assert record is not None and record.key == source.stem == record.request.key()
    CASES[name]["accepted (request intact)"] += 1


# --------------------------------------------------------------------------- curation answers

NAMES = st.one_of(
    st.sampled_from(
        ["cut", "scoop", "knife", "spoon", "bowl", "Cut", " scoop ", "sharp edge", "rigid"]
    ),
    st.text(max_size=12),
)
PROPERTY = st.fixed_dictionaries({"name": NAMES, "weight": st.floats(-1, 2)})
SCORE = st.fixed_dictionaries({"property": NAMES, "weight": st.floats(-1, 2)})
RANKED = st.fixed_dictionaries({"object": NAMES, "score": st.floats(-1, 2)})
ANSWER = st.one_of(
    JSON_VALUES,
    st.fixed_dictionaries({"verb": NAMES, "properties": st.lists(PROPERTY, max_size=11)}),
    st.fixed_dictionaries({"object": NAMES, "scores": st.lists(SCORE, max_size=6)}),
    st.fixed_dictionaries({"verb": NAMES, "ranking": st.lists(RANKED, max_size=4)}),
)
LINE = st.one_of(
    ANSWER.map(json.dumps), st.text(max_size=40).filter(lambda s: "\n" not in s and "\r" not in s)
)


@fuzz(max_examples=300)
@given(
    prompt=st.sampled_from(["verb_properties", "object_properties", "verb_objects", "nope"]),
    lines=st.lists(LINE, max_size=4),
)
def test_record_answers_fails_only_with_curation_error(
    real_kb: tuple[Path, Path], signed: dict[str, Any], prompt: str, lines: list[str]
) -> None:
    name = "random JSONL -> record_answers"
    with tempfile.TemporaryDirectory(dir=signed["scratch"]) as tmp:
        root = Path(tmp)
        shutil.copytree(real_kb[1] / "llm", root / "cache" / "llm")
        answers = root / "answers.jsonl"
        answers.write_text("\n".join(lines), encoding="utf-8")
        try:
            result = record_answers(
                LLMSource(RecordCache(root / "cache")),
                prompt,
                answers,
                ["cut", "scoop"],
                ["knife", "spoon", "bowl"],
                version="v1",
            )
        except CurationError:
            CASES[name]["CurationError"] += 1
            return
    CASES[name]["accepted"] += 1
    assert result.stored + result.unchanged + len(result.skipped) <= len(lines)


# --------------------------------------------------------------------------- regressions found by fuzzing


def test_record_answers_bad_name_is_a_curation_error(
    real_kb: tuple[Path, Path], tmp_path: Path
) -> None:
    shutil.copytree(real_kb[1] / "llm", tmp_path / "cache" / "llm")
    answers = tmp_path / "a.jsonl"
    answers.write_text('{"verb": "!!", "properties": [{"name": "x", "weight": 0.5}]}\n')
    with pytest.raises(CurationError):
        record_answers(
            LLMSource(RecordCache(tmp_path / "cache")),
            "verb_properties",
            answers,
            ["cut"],
            ["knife"],
        )


def test_record_answers_non_utf8_file_is_a_curation_error(real_kb: tuple[Path, Path], tmp_path: Path) -> None:
    answers = tmp_path / "a.jsonl"
    answers.write_bytes(b'{"verb": "cut\xff"}\n')
    with pytest.raises(CurationError):
        record_answers(
            LLMSource(RecordCache(tmp_path / "cache")),
            "verb_properties",
            answers,
            ["cut"],
            ["knife"],
        )


def test_deeply_nested_manifest_is_a_bundle_error(real_kb: tuple[Path, Path], tmp_path: Path) -> None:
    folder = tmp_path / "kb"
    shutil.copytree(real_kb[0], folder)
    (folder / "manifest.json").write_text("[" * 100_000)
    with pytest.raises(BundleError):
        load_bundle(folder)
