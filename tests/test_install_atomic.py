"""``install`` / ``rollback`` / ``current``: versions side by side, atomic switch, crash safety.

The property that matters on a robot: at every instant ``current`` names a complete, verified
bundle. Crashes are simulated both in-process (an exception inside the copy step, or between
unpacking and switching) and for real (SIGKILL of a subprocess in the middle of copying).
"""

from __future__ import annotations

import fcntl
import importlib
import io
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from craft_e.compiler.pack import keygen, pack_bundle
from craft_e.runtime.cli.main import app as craft_app
from craft_e.runtime.kb import install as install_mod
from craft_e.runtime.kb import package as package_mod
from craft_e.runtime.kb.bundle import load_bundle
from craft_e.runtime.kb.install import (
    DamagedVersionError,
    InstallError,
    current,
    install,
    installed,
    rollback,
)
from craft_e.runtime.kb.package import DestinationError, PackageError

# make_bundle lives beside the package tests; resolve it whether tests/ is a package or not
make_bundle = importlib.import_module(
    f"{__package__}.test_pack_package" if __package__ else "test_pack_package"
).make_bundle


@pytest.fixture(scope="module")
def keys(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    pair = keygen(tmp_path_factory.mktemp("keys"))
    return pair.private_key, pair.public_key


@pytest.fixture(scope="module")
def packages(tmp_path_factory: pytest.TempPathFactory, keys: tuple[Path, Path]) -> list[Path]:
    """Three versions of one KB, packed and signed."""
    root = tmp_path_factory.mktemp("packages")
    out = []
    for i, version in enumerate(["1.0.0", "1.1.0", "2.0.0"]):
        folder = make_bundle(root / f"kb-{version}", version=version, seed=i)
        out.append(pack_bundle(folder, keys[0], root / f"kb-{version}.craft").out)
    return out


def version_of(into: Path) -> str | None:
    folder = current(into)
    return None if folder is None else load_bundle(folder).manifest.kb_version


def tree(root: Path) -> dict[str, str]:
    """Names -> link target or file size: a snapshot that notices any change."""
    out: dict[str, str] = {}
    for p in sorted(root.rglob("*")):
        rel = str(p.relative_to(root))
        out[rel] = (
            f"-> {os.readlink(p)}"
            if p.is_symlink()
            else str(p.stat().st_size)
            if p.is_file()
            else "dir"
        )
    return out


def test_install_switch_and_prune(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]
) -> None:
    into = tmp_path / "kb"
    assert current(into) is None and installed(into) == []
    first = install(packages[0], into, [keys[1]])
    assert first.version.startswith("tiny-1.0.0-") and len(first.version.rsplit("-", 1)[1]) == 12
    assert os.readlink(into / "current") == f"versions/{first.version}"  # relative: movable
    assert not (into / "previous").exists() and first.previous is None
    assert version_of(into) == "1.0.0"

    second = install(packages[1], into, [keys[1]])
    assert version_of(into) == "1.1.0" and second.previous == first.version
    third = install(packages[2], into, [keys[1]])
    assert version_of(into) == "2.0.0" and third.previous == second.version
    names = [v.version for v in installed(into)]
    assert names == sorted([second.version, third.version])  # 1.0.0 pruned
    marks = {v.version: (v.is_current, v.is_previous) for v in installed(into)}
    assert marks == {third.version: (True, False), second.version: (False, True)}


def test_reinstalling_current_changes_nothing(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]
) -> None:
    into = tmp_path / "kb"
    install(packages[0], into, [keys[1]])
    install(packages[1], into, [keys[1]])
    before = tree(into)
    again = install(packages[1], into, [keys[1]])
    assert again.reused and tree(into) == before


def test_keep_all_versions(tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]) -> None:
    into = tmp_path / "kb"
    for pkg in packages:
        install(pkg, into, [keys[1]], prune=False)
    assert len(installed(into)) == 3


def test_rollback_toggles_and_verifies(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]
) -> None:
    into = tmp_path / "kb"
    install(packages[0], into, [keys[1]])
    with pytest.raises(InstallError, match="nothing to roll back to"):
        rollback(into)
    install(packages[1], into, [keys[1]])
    rollback(into)
    assert version_of(into) == "1.0.0"
    rollback(into)
    assert version_of(into) == "1.1.0"
    previous = into / os.readlink(into / "previous")
    (previous / "graph.json").write_bytes(b"{}")
    with pytest.raises(DamagedVersionError, match="no longer verifies"):
        rollback(into)
    assert version_of(into) == "1.1.0"
    with pytest.raises(InstallError, match="no such install folder"):
        rollback(tmp_path / "nowhere")


def test_refused_package_leaves_the_install_untouched(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]
) -> None:
    into = tmp_path / "kb"
    install(packages[0], into, [keys[1]])
    before = tree(into)
    stranger = keygen(tmp_path / "stranger")
    with pytest.raises(PackageError, match="not trusted"):
        install(packages[1], into, [stranger.public_key])
    tampered = tmp_path / "tampered.craft"
    data = bytearray(packages[1].read_bytes())
    data[-10] ^= 0xFF
    tampered.write_bytes(bytes(data))
    with pytest.raises(PackageError, match="payload does not match"):
        install(tampered, into, [keys[1]])
    assert tree(into) == before



def test_install_touches_only_what_it_made(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]
) -> None:
    """A person's folders and files under ``versions/`` survive installs and pruning (only version
    folders with a bundle and install's own staging names are removed), and a refused package
    writes nothing, not even the ``--into`` folder."""
    into = tmp_path / "kb"
    mine = [into / "versions" / "v2023" / "a.txt", into / "versions" / ".git" / "HEAD",
            into / "versions" / ".keep", into / "versions" / "my-notes" / "notes.txt"]
    for path in mine:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("data\n")
    staging = into / "versions" / f".{'x-1.0.0-' + '0' * 12}.ab12cd34.check"
    staging.mkdir()
    for package in (*packages, packages[0]):  # three installs, with pruning
        install(package, into, [keys[1]], allow_downgrade=True)
    assert all(path.read_text() == "data\n" for path in mine)
    assert not staging.exists()  # a crashed run's leftover, by install's own naming
    tampered = tmp_path / "tampered.craft"
    data = bytearray(packages[0].read_bytes())
    data[-10] ^= 0xFF
    tampered.write_bytes(bytes(data))
    fresh = tmp_path / "new" / "deeper"
    with pytest.raises(PackageError, match="payload does not match"):
        install(tampered, fresh, [keys[1]])
    assert not (tmp_path / "new").exists()

def test_damaged_version_is_repaired_by_reinstall(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]
) -> None:
    into = tmp_path / "kb"
    install(packages[0], into, [keys[1]])
    result = install(packages[1], into, [keys[1]])
    (result.path / "report.json").write_text("{}")
    assert [v.problem is not None for v in installed(into, verify=True)] == [False, True]
    repaired = install(packages[1], into, [keys[1]])
    assert not repaired.reused and version_of(into) == "1.1.0"
    assert all(v.problem is None for v in installed(into, verify=True))


def test_crash_inside_the_copy_step_keeps_the_old_current(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    into = tmp_path / "kb"
    old = install(packages[0], into, [keys[1]])
    before = tree(into)
    real = package_mod._write_member
    calls = 0

    def crash_on_third(*args: Any, **kwargs: Any) -> None:
        nonlocal calls
        calls += 1
        if calls == 3:
            raise RuntimeError("crash in the copy step (simulated)")
        real(*args, **kwargs)

    monkeypatch.setattr(package_mod, "_write_member", crash_on_third)
    with pytest.raises(RuntimeError, match="simulated"):
        install(packages[1], into, [keys[1]])
    assert tree(into) == before  # no half version, staging removed, links unchanged
    assert current(into) == (into / "versions" / old.version).resolve()
    assert version_of(into) == "1.0.0"
    monkeypatch.undo()
    assert install(packages[1], into, [keys[1]]).version != old.version


def test_disk_full_is_a_destination_error(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    into = tmp_path / "kb"
    install(packages[0], into, [keys[1]])
    before = tree(into)
    real = package_mod._write_chunk

    class FullDisk(io.BytesIO):
        def write(self, data: Any) -> int:
            raise OSError(28, "No space left on device")

    def full(out: Any, chunk: bytes, target: Path) -> None:
        real(FullDisk() if target.name == "embeddings.safetensors" else out, chunk, target)

    monkeypatch.setattr(package_mod, "_write_chunk", full)
    with pytest.raises(DestinationError, match=r"No space left on device.*free disk space"):
        install(packages[1], into, [keys[1]])
    assert tree(into) == before


def test_crash_between_unpack_and_switch(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    into = tmp_path / "kb"
    install(packages[0], into, [keys[1]])
    real = install_mod._point

    def crash_on_current(into_: Path, name: str, version: str) -> None:
        if name == "current":
            raise KeyboardInterrupt("power cut (simulated)")
        real(into_, name, version)

    monkeypatch.setattr(install_mod, "_point", crash_on_current)
    with pytest.raises(KeyboardInterrupt):
        install(packages[1], into, [keys[1]])
    assert version_of(into) == "1.0.0"  # the new folder exists, but is not current
    monkeypatch.undo()
    result = install(packages[1], into, [keys[1]])
    assert result.reused and version_of(into) == "1.1.0"


KILL_SCRIPT = textwrap.dedent(
    """
    import sys, time, pathlib
    import craft_e.runtime.kb.package as package
    from craft_e.runtime.kb.install import install

    real = package._write_member

    def slow(*args, **kwargs):
        real(*args, **kwargs)
        pathlib.Path(sys.argv[3]).write_text("copying")
        time.sleep(120)

    package._write_member = slow
    install(sys.argv[1], sys.argv[2], [sys.argv[4]])
    """
)


def test_sigkill_mid_install_leaves_old_current_usable(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]
) -> None:
    into = tmp_path / "kb"
    install(packages[0], into, [keys[1]])
    marker = tmp_path / "copying"
    proc = subprocess.Popen(
        [sys.executable, "-c", KILL_SCRIPT, str(packages[1]), str(into), str(marker), str(keys[1])]
    )
    try:
        deadline = time.monotonic() + 60
        while not marker.exists():
            assert proc.poll() is None, "installer exited before the copy step"
            assert time.monotonic() < deadline, "installer never reached the copy step"
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    leftovers = [p.name for p in (into / "versions").iterdir() if p.name.startswith(".")]
    assert leftovers, "expected the killed installer's staging folder"
    assert version_of(into) == "1.0.0"
    assert len(installed(into)) == 1  # the half copy is not a version
    install(packages[1], into, [keys[1]])  # sweeps the leftovers under the lock
    assert version_of(into) == "1.1.0"
    assert not [p for p in (into / "versions").iterdir() if p.name.startswith(".")]


def test_second_installer_fails_fast(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]
) -> None:
    into = tmp_path / "kb"
    into.mkdir()
    fd = os.open(into / ".lock", os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        with pytest.raises(InstallError, match="another `craft install`"):
            install(packages[0], into, [keys[1]])
    finally:
        os.close(fd)
    install(packages[0], into, [keys[1]])


def test_foreign_current_is_refused(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]
) -> None:
    into = tmp_path / "kb"
    (into / "current").mkdir(parents=True)
    with pytest.raises(InstallError, match="not a symlink made by `craft install`"):
        install(packages[0], into, [keys[1]])
    (into / "current").rmdir()
    (into / "current").symlink_to("/etc")
    with pytest.raises(InstallError, match="not made by `craft install`"):
        current(into)


def test_cli_install_rollback_installed(
    tmp_path: Path, packages: list[Path], keys: tuple[Path, Path]
) -> None:
    app = craft_app
    runner = CliRunner()
    into = str(tmp_path / "kb")
    pub = str(keys[1])
    result = runner.invoke(app, ["install", str(packages[0]), "--into", into, "--trusted-key", pub])
    assert result.exit_code == 0, result.output
    assert "installed tiny-1.0.0-" in result.output
    nothing = runner.invoke(app, ["rollback", "--into", into])
    assert nothing.exit_code == 2 and "nothing to roll back to" in nothing.output
    assert (
        runner.invoke(
            app, ["install", str(packages[1]), "--into", into, "--trusted-key", pub]
        ).exit_code
        == 0
    )
    listing = runner.invoke(app, ["installed", "--into", into, "--verify"])
    assert listing.exit_code == 0
    assert "* tiny-1.1.0-" in listing.output and "- tiny-1.0.0-" in listing.output
    back = runner.invoke(app, ["rollback", "--into", into])
    assert back.exit_code == 0 and "current -> tiny-1.0.0-" in back.output
    as_json = runner.invoke(app, ["installed", "--into", into, "--json"])
    assert '"current": true' in as_json.output
    stranger = keygen(tmp_path / "stranger").public_key
    refused = runner.invoke(
        app, ["install", str(packages[2]), "--into", into, "--trusted-key", str(stranger)]
    )
    assert refused.exit_code == 1 and "not trusted" in refused.output
    missing = runner.invoke(
        app, ["install", str(tmp_path / "no.craft"), "--into", into, "--trusted-key", pub]
    )
    assert missing.exit_code == 2 and "no such file" in missing.output


def test_runtime_side_imports_neither_compiler_nor_network_libraries() -> None:
    """The robot installs and loads packages with the runtime alone (DESIGN: no compiler there)."""
    code = (
        "import sys\n"
        "import craft_e.runtime.cli.install, craft_e.runtime.kb.install, craft_e.runtime.kb.package\n"
        "from craft_e.runtime.kb.bundle import load_bundle\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('httpx', 'rdflib')"
        " or m.startswith('craft_e.compiler'))\n"
        "print(bad)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
