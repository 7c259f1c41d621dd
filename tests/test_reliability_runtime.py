"""Bundle, package and install reliability probes (issue 12, items 2, 9, 10, 11 and 12).

Installed and unpacked bundles are readable by another user (umask modes, not 0700); content
is sanity-checked on load; reads refuse FIFOs, devices and oversized files before reading;
rollback survives a crash between its two link switches; a damaged package is refused even
when its version is installed; downgrades need ``--allow-downgrade``; names have a length cap.
"""

from __future__ import annotations

import importlib
import io
import json
import os
import shutil
import stat
import subprocess
import tempfile
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from craft_e.compiler.emit import model_json
from craft_e.compiler.pack import (
    _bundle_members,
    archive_bytes,
    keygen,
    load_signing_key,
    pack_bundle,
    seal,
)
from craft_e.runtime.cli.main import app as craft_app
from craft_e.runtime.kb import install as install_mod
from craft_e.runtime.kb.bundle import BundleError, load_bundle, read_manifest
from craft_e.runtime.kb.install import DowngradeError, current, install, rollback
from craft_e.runtime.kb.package import PackageError, unpack_package, verify_package
from craft_e.schemas.names import normalize_name, normalize_verb
from craft_e.schemas.v1.bundle import MANIFEST_FILE, FileDigest, sealed

make_bundle = importlib.import_module(
    f"{__package__}.test_pack_package" if __package__ else "test_pack_package"
).make_bundle


@pytest.fixture(scope="module")
def keys(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    pair = keygen(tmp_path_factory.mktemp("keys"))
    return pair.private_key, pair.public_key


@pytest.fixture(scope="module")
def packages(tmp_path_factory: pytest.TempPathFactory, keys: tuple[Path, Path]) -> list[Path]:
    root = tmp_path_factory.mktemp("packages")
    out = []
    for i, version in enumerate(["1.0.0", "1.1.0"]):
        folder = make_bundle(root / f"kb-{version}", version=version, seed=i)
        out.append(pack_bundle(folder, keys[0], root / f"kb-{version}.craft").out)
    return out


def craft(*args: str | Path) -> Any:
    app = craft_app
    return CliRunner().invoke(app, [str(a) for a in args], env={"COLUMNS": "2000"})


@pytest.fixture
def umask_022() -> Iterator[None]:
    old = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(old)


@pytest.fixture
def public_tmp() -> Iterator[Path]:
    """A folder other users can traverse (pytest's tmp_path is inside a 0700 folder)."""
    folder = Path(tempfile.mkdtemp(prefix="craft-reliability-"))
    os.chmod(folder, 0o755)
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


# -- item 2: modes of installed and unpacked bundles --------------------------------------------


def _modes(folder: Path) -> tuple[int, set[int]]:
    return stat.S_IMODE(folder.stat().st_mode), {stat.S_IMODE(p.stat().st_mode) for p in folder.iterdir()}


def test_installed_and_unpacked_bundles_get_umask_modes(
    public_tmp: Path, packages: list[Path], keys: tuple[Path, Path], umask_022: None
) -> None:
    into = public_tmp / "kb"
    install(packages[0], into, [keys[1]])
    folder = current(into)
    assert folder is not None
    assert _modes(folder) == (0o755, {0o644})
    assert stat.S_IMODE((into / "versions").stat().st_mode) == 0o755
    unpack_package(packages[0], [keys[1]], public_tmp / "unpacked")
    assert _modes(public_tmp / "unpacked") == (0o755, {0o644})
    assert stat.S_IMODE(packages[0].stat().st_mode) == 0o644  # the .craft file itself


#: runuser lives in /usr/sbin, which a non-login PATH may lack
RUNUSER = shutil.which("runuser", path=os.pathsep.join([os.environ.get("PATH", ""), "/usr/sbin", "/sbin"]))


@pytest.mark.skipif(os.geteuid() != 0 or RUNUSER is None, reason="needs root and runuser to switch users")
def test_another_user_can_read_a_bundle_root_installed(
    public_tmp: Path, packages: list[Path], keys: tuple[Path, Path], umask_022: None
) -> None:
    into = public_tmp / "kb"
    install(packages[0], into, [keys[1]])
    assert RUNUSER is not None
    r = subprocess.run([RUNUSER, "-u", "nobody", "--", "cat", str(into / "current" / MANIFEST_FILE)],
                       capture_output=True, timeout=30)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["kb_version"] == "1.0.0"


# -- item 9: content sanity on load --------------------------------------------------------------


def reseal(folder: Path, name: str, data: bytes) -> None:
    """Replace a bundle file and make every hash consistent again (a buggy or hostile writer)."""
    import hashlib

    (folder / name).write_bytes(data)
    manifest = read_manifest(folder)
    files = {**manifest.files, name: FileDigest(sha256=hashlib.sha256(data).hexdigest(), bytes=len(data))}
    (folder / MANIFEST_FILE).write_bytes(model_json(sealed(manifest.model_copy(update={"files": files}))))


def _npy(array: np.ndarray[Any, Any]) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def _edit_graph(edit: Callable[[dict[str, Any]], None]) -> Callable[[Path], bytes]:
    def make(folder: Path) -> bytes:
        graph = json.loads((folder / "graph.json").read_bytes())
        edit(graph)
        return json.dumps(graph).encode()

    return make


def _nan_energy(folder: Path) -> bytes:
    energy = np.load(folder / "affordance_energy.npy")
    energy[0, 0] = np.nan
    return _npy(energy)


def _wide_embeddings(folder: Path) -> bytes:
    from safetensors.numpy import load_file, save

    tensors = load_file(folder / "embeddings.safetensors")
    return save({k: np.concatenate([v, v], axis=1) for k, v in tensors.items()})


def _string_weight(g: dict[str, Any]) -> None:
    g["edges"][0]["weight"] = "0.9"


def _no_edges(g: dict[str, Any]) -> None:
    del g["edges"]


@pytest.mark.parametrize(
    ("name", "make", "says"),
    [
        ("affordance_energy.npy", _nan_energy, "NaN"),
        ("embeddings.safetensors", _wide_embeddings, "wide"),
        ("graph.json", _edit_graph(_string_weight), "not a finite number"),
        ("graph.json", _edit_graph(_no_edges), "'edges'"),
    ],
    ids=["nan-energy", "embedding-width", "string-weight", "no-edges"],
)
def test_consistent_hashes_do_not_make_content_sane(
    tmp_path: Path, name: str, make: Callable[[Path], bytes], says: str
) -> None:
    folder = make_bundle(tmp_path / "kb")
    reseal(folder, name, make(folder))
    with pytest.raises(BundleError, match=says) as info:
        load_bundle(folder, check_encoder=False)
    assert name in str(info.value)


# -- item 10: reads that could hang or exhaust memory -------------------------------------------


def _returns_within(seconds: float, call: Callable[[], object]) -> BaseException | None:
    """Run ``call`` in a thread; fail the test if it is still running after ``seconds``."""
    box: list[BaseException | None] = [None]

    def run() -> None:
        try:
            call()
        except BaseException as exc:
            box[0] = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), "the read blocked"
    return box[0]


def test_a_fifo_manifest_is_refused_not_waited_on(tmp_path: Path) -> None:
    folder = make_bundle(tmp_path / "kb")
    (folder / MANIFEST_FILE).unlink()
    os.mkfifo(folder / MANIFEST_FILE)
    exc = _returns_within(10, lambda: load_bundle(folder, check_encoder=False))
    assert isinstance(exc, BundleError) and "not a regular file" in str(exc)


def test_a_fifo_package_is_refused_not_waited_on(tmp_path: Path, keys: tuple[Path, Path]) -> None:
    fifo = tmp_path / "kb.craft"
    os.mkfifo(fifo)
    exc = _returns_within(10, lambda: verify_package(fifo, [keys[1]]))
    assert isinstance(exc, PackageError) and "not a regular file" in str(exc)
    box: list[Any] = []
    assert _returns_within(10, lambda: box.append(
        craft("install", fifo, "--into", tmp_path / "into", "--trusted-key", keys[1]))) is None
    assert box[0].exit_code == 2  # not a file: bad input


def test_a_bundle_file_linked_to_dev_zero_is_refused_before_reading(tmp_path: Path) -> None:
    folder = make_bundle(tmp_path / "kb")
    (folder / "graph.ttl").unlink()
    (folder / "graph.ttl").symlink_to("/dev/zero")
    exc = _returns_within(10, lambda: load_bundle(folder, check_encoder=False))
    assert isinstance(exc, BundleError) and "not a regular file" in str(exc)


# -- item 11: install and rollback edges ---------------------------------------------------------


def test_a_crash_between_rollbacks_two_switches_is_completed(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    into = tmp_path / "kb"
    v1 = install(packages[0], into, [keys[1]]).version
    v2 = install(packages[1], into, [keys[1]]).version
    real = install_mod._point

    def crash_before_previous(into_: Path, name: str, version: str) -> None:
        if name == install_mod.PREVIOUS:
            raise KeyboardInterrupt("power lost")
        real(into_, name, version)

    monkeypatch.setattr(install_mod, "_point", crash_before_previous)
    with pytest.raises(KeyboardInterrupt):
        rollback(into)
    monkeypatch.setattr(install_mod, "_point", real)
    assert os.readlink(into / "current") == f"versions/{v1}"  # the switch that matters happened
    # The next command completes the interrupted rollback first: previous is v2 again, so the
    # rollback after it returns to v2 instead of "succeeding" without changing anything.
    result = rollback(into)
    assert (result.version, result.previous) == (v2, v1)
    assert os.readlink(into / "current") == f"versions/{v2}"
    assert os.readlink(into / "previous") == f"versions/{v1}"
    assert not (into / ".rollback").is_symlink()


def test_rollback_refuses_when_current_equals_previous(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]
) -> None:
    into = tmp_path / "kb"
    v1 = install(packages[0], into, [keys[1]]).version
    install(packages[1], into, [keys[1]], prune=False)
    os.unlink(into / "current")
    os.symlink(f"versions/{v1}", into / "current")  # what an older craft's crash left
    r = craft("rollback", "--into", into)
    assert r.exit_code == 2, r.output
    assert "both name" in r.output.replace("\n", "")


def test_a_damaged_package_of_an_installed_version_is_refused(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]
) -> None:
    into = tmp_path / "kb"
    install(packages[0], into, [keys[1]])
    members, manifest = _bundle_members(make_bundle(tmp_path / "same", version="1.0.0", seed=0))
    members = [(n, b"\0" * len(d) if n == "graph.json" else d) for n, d in members]
    seed, _ = load_signing_key(keys[0])
    bad = tmp_path / "bad.craft"
    bad.write_bytes(seal(archive_bytes(members), members[0][1], manifest, seed, "gzip"))
    verify_package(bad, [keys[1]])  # signed, so the header and manifest check out
    r = craft("install", bad, "--into", into, "--trusted-key", keys[1])
    assert r.exit_code == 1, r.output
    assert "graph.json" in r.output


def test_downgrade_needs_allow_downgrade(tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]) -> None:
    into = tmp_path / "kb"
    install(packages[1], into, [keys[1]])
    with pytest.raises(DowngradeError, match=r"older than the installed 1\.1\.0"):
        install(packages[0], into, [keys[1]])
    r = craft("install", packages[0], "--into", into, "--trusted-key", keys[1])
    assert r.exit_code == 2 and "--allow-downgrade" in r.output.replace("\n", "")
    r = craft("install", packages[0], "--into", into, "--trusted-key", keys[1], "--allow-downgrade")
    assert r.exit_code == 0, r.output
    folder = current(into)
    assert folder is not None and read_manifest(folder).kb_version == "1.0.0"


# -- item 12: name length cap --------------------------------------------------------------------


def test_a_huge_name_is_refused_fast_and_not_echoed() -> None:
    """Refused on its length alone: a string that fails on any other work proves no pass ran."""

    class NoWork(str):
        def __getattribute__(self, attr: str) -> Any:
            raise AssertionError(f"normalize touched the huge name ({attr}) before refusing it")

    huge = NoWork("a" * 10_000_000)
    for normalize in (normalize_name, normalize_verb):
        with pytest.raises(ValueError, match="longer than 100 characters") as info:
            normalize(huge)
        assert len(str(info.value)) < 300


def test_a_huge_verb_in_a_verbs_file_is_exit_2_with_a_short_message(tmp_path: Path) -> None:
    from craft_e.compiler.cli import app as craftc_app

    verbs = tmp_path / "verbs.txt"
    verbs.write_text("cut\n" + "x" * 10_000_000 + "\n", encoding="utf-8")
    r = CliRunner().invoke(craftc_app, ["build", "--verbs", str(verbs), "--out", str(tmp_path / "o"), "--quiet"])
    assert r.exit_code == 2, r.output[:500]
    assert "longer than 100 characters" in r.output.replace("\n", "")
    assert len(r.output) < 2000
