"""Signed packages: keygen, pack, verify, unpack, and the load_bundle hook for ``.craft`` files.

Bundles here are small synthetic ones written by the real emitter (fast, and several versions
can be made); ``test_fuzz_package.py`` does the same on a bundle built by the real compiler.
Hostile archives are *signed with the trusted key* on purpose: signature checks stop strangers,
and these tests show the unpacker still refuses a dangerous archive from a trusted signer.
"""

from __future__ import annotations

import gzip
import io
import json
import os
import stat
import tarfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
import typer
from safetensors.numpy import save as save_safetensors
from typer.testing import CliRunner

from craft_e.compiler.cli_pack import register as register_pack
from craft_e.compiler.emit import file_digest, write_bundle
from craft_e.compiler.pack import (
    PackError,
    UnverifiedBundleError,
    archive_bytes,
    keygen,
    load_signing_key,
    pack_bundle,
    seal,
)
from craft_e.compiler.rdf import turtle_of_graph_json
from craft_e.runtime.encoders.text import MINILM_ID, MINILM_SHA256
from craft_e.runtime.grounding.energies import affordance_energy_matrix
from craft_e.runtime.kb.bundle import BundleError, load_bundle
from craft_e.runtime.kb.package import (
    PACKAGE_MAGIC,
    Limits,
    PackageError,
    PackageHeader,
    container_bytes,
    key_id,
    parse_public_key,
    read_header,
    unpack_package,
    verify_package,
)
from craft_e.schemas.v1.bundle import (
    UNSEALED,
    BuildInfo,
    BundleReport,
    Coverage,
    EnergyInfo,
    Manifest,
    SourceInfo,
    TextEncoderInfo,
    sealed,
)

VERBS = ["cut", "scoop"]
OBJECTS = ["knife", "spoon", "bowl"]
PROPS = ["sharp edge", "concave", "has a handle"]


def make_bundle(out: Path, *, name: str = "tiny", version: str = "1.0.0", seed: int = 0) -> Path:
    """A small but complete v1 bundle written by the real emitter (loads with load_bundle)."""
    rng = np.random.default_rng(seed)
    edges = [
        {"source": "verb:cut", "target": "prop:sharp edge", "weight": 0.9, "provenance": ["r1"]},
        {"source": "prop:sharp edge", "target": "obj:knife", "weight": 0.95, "provenance": ["r2"]},
        {"source": "verb:scoop", "target": "prop:concave", "weight": 0.9, "provenance": ["r1"]},
        {"source": "prop:concave", "target": "obj:spoon", "weight": 0.9, "provenance": ["r3"]},
    ]
    # every node the edges and the manifest name (verification checks the graph against both)
    nodes = [{"id": f"{prefix}:{n}", "kind": kind, "name": n}
             for prefix, kind, names in (("verb", "verb", VERBS), ("prop", "property", PROPS),
                                         ("obj", "object", OBJECTS)) for n in names]
    graph = {
        "directed": True,
        "multigraph": False,
        "graph": {"seed": seed},
        "nodes": nodes,
        "edges": edges,
    }
    rng.uniform(-1, 0, (len(VERBS), len(OBJECTS)))  # the draw of the old random E_aff: same embeddings
    # E_aff as craftc computes it from these edges (validate and pack recompute it from the graph)
    w_vp = np.zeros((len(VERBS), len(PROPS)), np.float32)
    w_po = np.zeros((len(PROPS), len(OBJECTS)), np.float32)
    for edge in edges:
        (src_kind, src), (_, dst) = (str(edge["source"]).split(":", 1), str(edge["target"]).split(":", 1))
        if src_kind == "verb":
            w_vp[VERBS.index(src), PROPS.index(dst)] = float(edge["weight"])  # type: ignore[arg-type]
        else:
            w_po[PROPS.index(src), OBJECTS.index(dst)] = float(edge["weight"])  # type: ignore[arg-type]
    energy = io.BytesIO()
    np.save(energy, affordance_energy_matrix(w_vp, w_po, tau=0.5, form="sum-tanh").astype(np.float32))

    def unit(rows: int) -> npt.NDArray[np.float32]:
        x = rng.normal(size=(rows, 8)).astype(np.float32)
        out: npt.NDArray[np.float32] = x / np.linalg.norm(x, axis=1, keepdims=True)
        return out

    embeddings = save_safetensors(
        {"verb": unit(2), "verb_query": unit(2), "object": unit(3), "property": unit(3)}
    )
    report = BundleReport(
        kb_name=name,
        counts={"verbs": 2},
        pass_counts={},
        drops=[],
        coverage=Coverage(
            verbs_with_fewer_than_k_properties={},
            objects_without_properties=["bowl"],
            objects_unreachable_from_any_verb=["bowl"],
            verbs_reaching_no_object=[],
        ),
    )
    files = {
        "graph.json": json.dumps(graph, sort_keys=True).encode(),
        "graph.ttl": turtle_of_graph_json(graph, name),  # validate and pack regenerate and compare it
        "embeddings.safetensors": embeddings,
        "affordance_energy.npy": energy.getvalue(),
        "report.json": report.model_dump_json().encode(),
    }
    digests = {n: file_digest(d) for n, d in files.items()}
    manifest = Manifest(
        kb_name=name,
        kb_version=version,
        content_sha256=UNSEALED,
        files=digests,
        sources=[SourceInfo(kind="llm", provider="curated", records=3)],
        text_encoder=TextEncoderInfo(
            id=MINILM_ID, weights_sha256=MINILM_SHA256, dim=8, verb_template="something to {verb}"
        ),
        energy=EnergyInfo(tau=0.5),
        verbs=VERBS,
        objects=OBJECTS,
        properties=PROPS,
    )
    manifest = sealed(manifest)
    info = BuildInfo(
        created_at="2026-01-01T00:00:00Z", host="test", craft_e_version="0", duration_s=0.0, argv=[]
    )
    write_bundle(out, files, manifest, info)
    return out


def snapshot(root: Path) -> set[str]:
    """Every path under ``root`` (to prove nothing was written where it should not be)."""
    return {str(p.relative_to(root)) for p in root.rglob("*")}


@pytest.fixture(scope="module")
def keys(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    pair = keygen(tmp_path_factory.mktemp("keys"))
    return pair.private_key, pair.public_key


@pytest.fixture(scope="module")
def other_keys(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    pair = keygen(tmp_path_factory.mktemp("other-keys"))
    return pair.private_key, pair.public_key


@pytest.fixture(scope="module")
def bundle(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_bundle(tmp_path_factory.mktemp("bundle") / "kb")


@pytest.fixture
def package(tmp_path: Path, bundle: Path, keys: tuple[Path, Path]) -> Path:
    return pack_bundle(bundle, keys[0], tmp_path / "pkg" / "kb.craft").out


# --------------------------------------------------------------------------- keys


def test_keygen_writes_private_0600_and_refuses_overwrite(tmp_path: Path) -> None:
    pair = keygen(tmp_path)
    assert stat.S_IMODE(pair.private_key.stat().st_mode) == 0o600
    public = pair.public_key.read_text().strip()
    assert len(public) == 64 and key_id(bytes.fromhex(public)) == pair.key_id
    seed, notes = load_signing_key(pair.private_key)
    assert len(seed) == 32 and notes == []
    with pytest.raises(PackError, match="refusing to overwrite"):
        keygen(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["craft-signing.key", "craft-signing.pub"]


def test_signing_key_errors_name_the_fix(tmp_path: Path, keys: tuple[Path, Path]) -> None:
    with pytest.raises(PackError, match="craftc keygen"):
        load_signing_key(tmp_path / "nope.key")
    with pytest.raises(PackError, match="looks like the public key"):
        load_signing_key(keys[1])
    bad = tmp_path / "bad.key"
    bad.write_text("seed:zz\n")
    with pytest.raises(PackError, match="not a craft signing key"):
        load_signing_key(bad)
    loose = tmp_path / "loose.key"
    loose.write_text(keys[0].read_text())
    loose.chmod(0o644)
    assert "chmod 600" in load_signing_key(loose)[1][0]


def test_public_key_spellings(keys: tuple[Path, Path]) -> None:
    import base64

    raw = bytes.fromhex(keys[1].read_text().strip())
    for spelling in (
        raw,
        raw.hex(),
        raw.hex().encode(),
        base64.b64encode(raw).decode(),
        keys[1],
        str(keys[1]),
    ):
        assert parse_public_key(spelling) == raw
    for bad in ("nope", b"\x00" * 31):  # a missing .pub file: test_a_missing_trusted_key_file_is_called_missing
        with pytest.raises(PackageError, match="not an Ed25519 public key"):
            parse_public_key(bad)


# --------------------------------------------------------------------------- pack / verify / load


def test_pack_is_deterministic_and_verifies(
    tmp_path: Path, bundle: Path, keys: tuple[Path, Path]
) -> None:
    a = pack_bundle(bundle, keys[0], tmp_path / "a.craft")
    b = pack_bundle(bundle, keys[0], tmp_path / "b.craft")
    assert a.out.read_bytes() == b.out.read_bytes()
    assert a.out.read_bytes().startswith(PACKAGE_MAGIC)
    verified = verify_package(a.out, [keys[1]])
    manifest = Manifest.model_validate_json((bundle / "manifest.json").read_bytes())
    assert verified.manifest == manifest
    assert verified.statement.content_sha256 == manifest.content_sha256
    assert verified.key_id == a.key_id
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.craft", "b.craft"]  # no temp left


def test_verify_writes_nothing(tmp_path: Path, package: Path, keys: tuple[Path, Path]) -> None:
    before = snapshot(package.parent)
    verify_package(package, [keys[1]])
    assert snapshot(package.parent) == before == {"kb.craft"}


@pytest.mark.parametrize("compression", ["gzip", "none"])
def test_unpack_roundtrip_matches_the_folder(
    tmp_path: Path, bundle: Path, keys: tuple[Path, Path], compression: str
) -> None:
    pkg = pack_bundle(bundle, keys[0], tmp_path / "kb.craft", compression=compression)  # type: ignore[arg-type]
    assert read_header(pkg.out).statement.compression == compression
    dest = tmp_path / "out"
    unpack_package(pkg.out, [keys[1]], dest)
    for path in bundle.iterdir():
        assert (dest / path.name).read_bytes() == path.read_bytes()
    assert snapshot(tmp_path) == {"kb.craft", "out", *(f"out/{p.name}" for p in bundle.iterdir())}


def test_load_bundle_accepts_a_signed_file(
    package: Path, bundle: Path, keys: tuple[Path, Path]
) -> None:
    folder = load_bundle(bundle)
    packed = load_bundle(package, trusted_keys=[keys[1].read_text()])
    assert packed.path == package
    assert packed.manifest == folder.manifest
    np.testing.assert_array_equal(packed.energy, folder.energy)
    assert packed.paths("cut") == folder.paths("cut")


def test_load_bundle_file_without_trusted_keys_is_refused(package: Path) -> None:
    with pytest.raises(PackageError, match="no trusted keys"):
        load_bundle(package)
    with pytest.raises(BundleError, match="no trusted keys"):
        load_bundle(package, trusted_keys=[])


def test_untrusted_signer_is_refused(package: Path, other_keys: tuple[Path, Path]) -> None:
    with pytest.raises(PackageError, match=r"not trusted.*--trusted-key"):
        verify_package(package, [other_keys[1]])


def test_pack_refuses_a_damaged_bundle(tmp_path: Path, keys: tuple[Path, Path]) -> None:
    broken = make_bundle(tmp_path / "kb")
    (broken / "graph.ttl").write_bytes(b"edited\n")
    with pytest.raises(UnverifiedBundleError, match=r"graph\.ttl.*does not match"):
        pack_bundle(broken, keys[0], tmp_path / "kb.craft")
    assert not (tmp_path / "kb.craft").exists()



def test_pack_never_replaces_what_it_reads_or_a_file_of_another_kind(
    tmp_path: Path, keys: tuple[Path, Path]
) -> None:
    """``-o`` replaces an older package only: not the signing key (lost for good), not a file of
    the bundle being packed, not a user's document."""
    bundle = make_bundle(tmp_path / "kb")
    key = tmp_path / "craft-signing.key"
    key.write_bytes(keys[0].read_bytes())
    document = tmp_path / "notes.txt"
    document.write_text("precious\n")
    graph = (bundle / "graph.json").read_bytes()
    for out, why in ((key, "which this pack reads"), (bundle / "graph.json", "inside"),
                     (document, "not a CRAFT-E package")):
        with pytest.raises(PackError, match=why):
            pack_bundle(bundle, key, out)
    assert key.read_bytes() == keys[0].read_bytes()
    assert document.read_text() == "precious\n"
    assert (bundle / "graph.json").read_bytes() == graph
    assert sorted(p.name for p in tmp_path.iterdir()) == ["craft-signing.key", "kb", "notes.txt"]
    first = pack_bundle(bundle, key, tmp_path / "kb.craft").out
    again = pack_bundle(bundle, key, first)  # an older package is replaced
    assert again.out == first and verify_package(first, [keys[1]])

# --------------------------------------------------------------------------- damaged files


def _payload_offset(data: bytes) -> int:
    return 12 + int.from_bytes(data[8:12], "big")


DAMAGE: dict[str, tuple[Callable[[bytes], bytes], str]] = {
    "truncated payload": (lambda d: d[:-100], "truncated: payload has"),
    "truncated header": (lambda d: d[:40], "truncated inside the header"),
    "appended junk": (lambda d: d + b"junk", "unexpected bytes after the payload"),
    "payload bit flip": (
        lambda d: d[:-50] + bytes([d[-50] ^ 0x01]) + d[-49:],
        "payload does not match its signed sha256",
    ),
    "header edit": (
        lambda d: d.replace(b'"kb_version":"1.0.0"', b'"kb_version":"1.0.1"'),
        "signature does not verify",
    ),
    "header whitespace": (
        lambda d: d[:8] + (int.from_bytes(d[8:12], "big") + 1).to_bytes(4, "big") + b" " + d[12:],
        "not in canonical form",
    ),
    "bad magic": (lambda d: b"XRAFTPK1" + d[8:], "not a CRAFT-E package"),
    "huge header length": (lambda d: d[:8] + b"\xff\xff\xff\xff" + d[12:], "header length"),
    "empty file": (lambda d: b"", "not a CRAFT-E package"),
}


@pytest.mark.parametrize("case", sorted(DAMAGE))
def test_damaged_packages_are_refused_with_a_reason(
    tmp_path: Path, package: Path, keys: tuple[Path, Path], case: str
) -> None:
    mutate, reason = DAMAGE[case]
    bad = tmp_path / "bad.craft"
    bad.write_bytes(mutate(package.read_bytes()))
    with pytest.raises(PackageError, match=reason) as info:
        unpack_package(bad, [keys[1]], tmp_path / "dest")
    assert str(bad) in str(info.value)
    assert snapshot(tmp_path) == {"pkg", "pkg/kb.craft", "bad.craft"}


def test_unsigned_inputs_are_refused(
    tmp_path: Path, package: Path, bundle: Path, keys: tuple[Path, Path]
) -> None:
    data = package.read_bytes()
    header = PackageHeader.model_validate_json(data[12 : _payload_offset(data)])
    unsigned = tmp_path / "unsigned.craft"
    unsigned.write_bytes(
        container_bytes(
            header.model_copy(update={"signature": None}), data[_payload_offset(data) :]
        )
    )
    with pytest.raises(PackageError, match="unsigned package"):
        verify_package(unsigned, [keys[1]])
    plain = tmp_path / "plain.tar.gz"
    plain.write_bytes(archive_bytes([(p.name, p.read_bytes()) for p in sorted(bundle.iterdir())]))
    with pytest.raises(PackageError, match="unsigned archive"):
        verify_package(plain, [keys[1]])
    with pytest.raises(PackageError, match="is a folder"):
        verify_package(bundle, [keys[1]])
    with pytest.raises(PackageError, match="no such file"):
        verify_package(tmp_path / "missing.craft", [keys[1]])


def test_unpack_refuses_an_occupied_destination(
    tmp_path: Path, package: Path, keys: tuple[Path, Path]
) -> None:
    dest = tmp_path / "dest"
    dest.mkdir()
    (dest / "mine.txt").write_text("keep me")
    with pytest.raises(PackageError, match="not an empty folder"):
        unpack_package(package, [keys[1]], dest)
    assert [p.name for p in dest.iterdir()] == ["mine.txt"]


# --------------------------------------------------------------------------- hostile archives


Entry = tuple[tarfile.TarInfo, bytes]


def _entry(name: str, data: bytes = b"", kind: bytes = tarfile.REGTYPE, link: str = "") -> Entry:
    info = tarfile.TarInfo(name)
    info.type = kind
    info.size = len(data) if kind == tarfile.REGTYPE else 0
    info.linkname = link
    info.mtime = 0
    return info, data


def hostile_package(
    path: Path,
    bundle: Path,
    private_key: Path,
    entries: list[Entry],
    *,
    compression: str = "gzip",
    fmt: int = tarfile.USTAR_FORMAT,
) -> Path:
    """A package signed by the trusted key whose archive holds exactly ``entries``."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=fmt) as archive:
        for info, data in entries:
            archive.addfile(info, io.BytesIO(data) if info.type == tarfile.REGTYPE else None)
    payload = buffer.getvalue()
    if compression == "gzip":
        payload = gzip.compress(payload, mtime=0)
    manifest_bytes = (bundle / "manifest.json").read_bytes()
    manifest = Manifest.model_validate_json(manifest_bytes)
    seed, _ = load_signing_key(private_key)
    path.write_bytes(seal(payload, manifest_bytes, manifest, seed, compression))  # type: ignore[arg-type]
    return path


def _good_entries(bundle: Path) -> list[Entry]:
    names = [
        "manifest.json",
        "affordance_energy.npy",
        "embeddings.safetensors",
        "graph.json",
        "graph.ttl",
        "report.json",
    ]
    return [_entry(n, (bundle / n).read_bytes()) for n in names]


HOSTILE: dict[str, tuple[Callable[[list[Entry]], list[Entry]], str]] = {
    "dotdot": (lambda g: [*g, _entry("../evil.txt", b"x")], "path traversal"),
    "nested dotdot": (lambda g: [*g, _entry("sub/../../evil.txt", b"x")], "path traversal"),
    "absolute": (lambda g: [*g, _entry("/tmp/craft-evil.txt", b"x")], "absolute path"),
    "symlink": (
        lambda g: [g[0], _entry("graph.json", kind=tarfile.SYMTYPE, link="/etc/passwd"), *g[1:]],
        "symlink",
    ),
    "hardlink": (
        lambda g: [g[0], _entry("graph.ttl", kind=tarfile.LNKTYPE, link="manifest.json"), *g[1:]],
        "hardlink",
    ),
    "char device": (lambda g: [*g, _entry("report.json", kind=tarfile.CHRTYPE)], "device"),
    "fifo": (lambda g: [*g, _entry("build_info.json", kind=tarfile.FIFOTYPE)], "FIFO"),
    "directory": (lambda g: [*g, _entry("extra", kind=tarfile.DIRTYPE)], "directory"),
    "duplicate": (lambda g: [*g, g[3]], "duplicate member"),
    "unexpected": (lambda g: [*g, _entry("run_me.sh", b"#!/bin/sh\n")], "unexpected member"),
    "manifest not first": (lambda g: [g[1], g[0], *g[2:]], "first member must be manifest.json"),
    "missing member": (lambda g: g[:-1], "missing"),
    "wrong size": (lambda g: [*g[:3], _entry("graph.json", b"{}"), *g[4:]], "the manifest says"),
    "same size, other bytes": (
        lambda g: [*g[:4], _entry("graph.ttl", b"#" * g[4][0].size), *g[5:]],
        "does not match its manifest sha256",
    ),
    "empty archive": (lambda g: [], "archive is empty|archive is unreadable"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_archive_from_a_trusted_signer_is_refused(
    tmp_path: Path, bundle: Path, keys: tuple[Path, Path], case: str
) -> None:
    build, reason = HOSTILE[case]
    work = tmp_path / "work"
    work.mkdir()
    pkg = hostile_package(tmp_path / "hostile.craft", bundle, keys[0], build(_good_entries(bundle)))
    before = snapshot(tmp_path)
    with pytest.raises(PackageError, match=reason):
        unpack_package(pkg, [keys[1]], work / "dest")
    assert snapshot(tmp_path) == before
    assert not Path("/tmp/craft-evil.txt").exists()


def test_control_hostile_builder_makes_a_valid_package(
    tmp_path: Path, bundle: Path, keys: tuple[Path, Path]
) -> None:
    """The hostile cases fail because of their twist, not because the builder is broken."""
    pkg = hostile_package(
        tmp_path / "ok.craft", bundle, keys[0], _good_entries(bundle), fmt=tarfile.PAX_FORMAT
    )
    unpack_package(pkg, [keys[1]], tmp_path / "dest")
    assert load_bundle(tmp_path / "dest").manifest.kb_name == "tiny"


def test_decompression_bomb_is_capped(
    tmp_path: Path, bundle: Path, keys: tuple[Path, Path]
) -> None:
    """A pax header that inflates to 8 MiB (from ~8 KiB) stops at the manifest-derived cap."""
    good = _good_entries(bundle)
    bomb = _entry("graph.json", (bundle / "graph.json").read_bytes())
    bomb[0].pax_headers = {"comment": "A" * (8 << 20)}
    pkg = hostile_package(
        tmp_path / "bomb.craft",
        bundle,
        keys[0],
        [*good[:3], bomb, *good[4:]],
        fmt=tarfile.PAX_FORMAT,
    )
    assert pkg.stat().st_size < 64 * 1024
    with pytest.raises(PackageError, match="decompression bomb"):
        unpack_package(pkg, [keys[1]], tmp_path / "dest")
    assert not (tmp_path / "dest").exists()


def test_member_and_size_limits(tmp_path: Path, package: Path, keys: tuple[Path, Path]) -> None:
    with pytest.raises(PackageError, match="more than 3 members"):
        unpack_package(package, [keys[1]], tmp_path / "a", limits=Limits(max_members=3))
    with pytest.raises(PackageError, match="above the limit of 100 per file"):  # was never enforced
        unpack_package(package, [keys[1]], tmp_path / "b", limits=Limits(max_member_bytes=100))
    with pytest.raises(PackageError, match="limit 10"):
        verify_package(package, [keys[1]], limits=Limits(max_manifest_bytes=10))
    with pytest.raises(PackageError, match="header length"):
        verify_package(package, [keys[1]], limits=Limits(max_header_bytes=64))
    assert snapshot(tmp_path) == {"pkg", "pkg/kb.craft"}


def test_file_swapped_after_verification_is_caught(
    tmp_path: Path, bundle: Path, keys: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The payload is re-hashed while it is extracted, so a verify-then-swap race fails."""
    import craft_e.runtime.kb.package as package_mod

    pkg = pack_bundle(bundle, keys[0], tmp_path / "kb.craft", compression="none").out
    real = package_mod._verify_open

    def verify_then_tamper(path: Path, handle: io.BufferedReader, *args: object) -> object:
        verified = real(path, handle, *args)  # type: ignore[arg-type]
        with path.open("r+b") as out:  # flip a byte in the tar padding after the last member
            out.seek(-1, os.SEEK_END)
            out.write(b"\x01")
        return verified

    monkeypatch.setattr(package_mod, "_verify_open", verify_then_tamper)
    with pytest.raises(PackageError, match="changed while it was being unpacked"):
        unpack_package(pkg, [keys[1]], tmp_path / "dest")
    assert not (tmp_path / "dest").exists()


# --------------------------------------------------------------------------- CLI


def test_cli_keygen_and_pack(tmp_path: Path, bundle: Path) -> None:
    app = typer.Typer()
    register_pack(app)
    runner = CliRunner()
    result = runner.invoke(app, ["keygen", "--out", str(tmp_path / "keys")])
    assert result.exit_code == 0, result.output
    assert "key id" in result.output
    again = runner.invoke(app, ["keygen", "--out", str(tmp_path / "keys")])
    assert again.exit_code == 2 and "refusing to overwrite" in again.output
    key = tmp_path / "keys" / "craft-signing.key"
    out = tmp_path / "kb.craft"
    result = runner.invoke(app, ["pack", str(bundle), "--key", str(key), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "signed by key" in result.output
    verify_package(out, [tmp_path / "keys" / "craft-signing.pub"])
    missing = runner.invoke(
        app, ["pack", str(bundle), "--key", str(tmp_path / "nope"), "-o", str(out)]
    )
    assert missing.exit_code == 2 and "craftc keygen" in missing.output
    broken = make_bundle(tmp_path / "broken")
    (broken / "report.json").write_text("{}")
    bad = runner.invoke(
        app, ["pack", str(broken), "--key", str(key), "-o", str(tmp_path / "b.craft")]
    )
    assert bad.exit_code == 1 and "does not verify" in bad.output


def test_a_file_that_is_not_a_package_is_named_as_such(tmp_path: Path) -> None:
    """A plain file given as a bundle is not "a packed bundle that needs trusted keys"."""
    notes = tmp_path / "notes.txt"
    notes.write_text("not a bundle\n")
    with pytest.raises(BundleError, match="neither a bundle folder nor a packed bundle"):
        load_bundle(notes)


def test_a_missing_trusted_key_file_is_called_missing(tmp_path: Path) -> None:
    from craft_e.runtime.kb.package import parse_public_key

    for value in (tmp_path / "craft-signing.pub", str(tmp_path / "craft-signing.pub")):
        with pytest.raises(PackageError, match="no such file"):
            parse_public_key(value)
    with pytest.raises(PackageError, match="not an Ed25519 public key"):
        parse_public_key("garbage")
