"""``craftc build --out`` never destroys what a user owns (issue 12, items 1 and 2).

Only a missing path, an empty folder or an existing bundle may become the bundle; a user's
folder, a file, the working directory or a folder holding an input is refused with exit 2 and
left byte-for-byte as it was. Bundles get the umask's modes (0755/0644), not mkdtemp's 0700.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
from conftest import KB_NAME, FixtureKB
from test_cli_craftc import craftc, flat, replay_args


def snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_a_users_folder_is_refused_and_kept(kb_a: FixtureKB, tmp_path: Path) -> None:
    users = tmp_path / "u"
    users.mkdir()
    (users / "notes.txt").write_text("x")
    result = craftc(*replay_args(kb_a.cache, users))
    assert result.exit_code == 2, result.output
    assert "not a CRAFT-E bundle" in flat(result.output)
    assert "--force" not in flat(result.output)
    assert snapshot(users) == {"notes.txt": b"x"}
    assert [p.name for p in tmp_path.iterdir()] == ["u"]  # no staging folder left behind


def test_force_does_not_unlock_a_users_folder(kb_a: FixtureKB, tmp_path: Path) -> None:
    users = tmp_path / "u"
    users.mkdir()
    (users / "notes.txt").write_text("x")
    result = craftc(*replay_args(kb_a.cache, users), "--force")
    assert result.exit_code == 2
    assert (users / "notes.txt").read_text() == "x"


def test_a_bundle_with_user_files_in_it_needs_force(
    kb_a: FixtureKB, tmp_path: Path
) -> None:
    out = tmp_path / "b"
    assert craftc(*replay_args(kb_a.cache, out)).exit_code == 0
    (out / "my-notes.md").write_text("mine")
    result = craftc(*replay_args(kb_a.cache, out))
    assert result.exit_code == 2
    assert "my-notes.md" in flat(result.output)
    assert (out / "my-notes.md").read_text() == "mine"
    assert craftc(*replay_args(kb_a.cache, out), "--force").exit_code == 0  # it is a bundle
    assert not (out / "my-notes.md").exists()


def test_an_existing_file_and_the_verbs_file_are_refused(kb_a: FixtureKB, tmp_path: Path) -> None:
    target = tmp_path / "verbs-copy.txt"
    target.write_text("cut\n")
    result = craftc(*replay_args(kb_a.cache, target))
    assert result.exit_code == 2
    assert "existing file" in flat(result.output)
    assert target.read_text() == "cut\n"


def test_the_working_directory_and_input_folders_are_refused(
    kb_a: FixtureKB, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    checkout = tmp_path / "checkout"
    (checkout / ".git").mkdir(parents=True)
    (checkout / ".git" / "HEAD").write_text("ref: refs/heads/main\n")
    monkeypatch.chdir(checkout)
    result = craftc(*replay_args(kb_a.cache, checkout))
    assert result.exit_code == 2
    assert (checkout / ".git" / "HEAD").exists()
    # The record cache's own folder (an input of the build) is refused too.
    before = snapshot(kb_a.cache)
    result = craftc(*replay_args(kb_a.cache, kb_a.cache.parent))
    assert result.exit_code == 2
    assert snapshot(kb_a.cache) == before


def test_a_symlink_is_refused(kb_a: FixtureKB, tmp_path: Path) -> None:
    real = tmp_path / "real"
    real.mkdir()
    link = tmp_path / "link"
    link.symlink_to(real)
    assert craftc(*replay_args(kb_a.cache, link)).exit_code == 2


def test_a_bundle_is_replaced_and_another_kbs_bundle_needs_force(
    kb_a: FixtureKB, tmp_path: Path
) -> None:
    out = tmp_path / "b"
    assert craftc(*replay_args(kb_a.cache, out)).exit_code == 0
    assert craftc(*replay_args(kb_a.cache, out)).exit_code == 0  # same kb: rebuilt in place
    other = [a if a != KB_NAME else "other-kb" for a in replay_args(kb_a.cache, out)]
    result = craftc(*other)
    assert result.exit_code == 2
    assert "--force" in flat(result.output)
    assert craftc(*other, "--force").exit_code == 0


def test_an_empty_folder_may_become_the_bundle(kb_a: FixtureKB, tmp_path: Path) -> None:
    out = tmp_path / "empty"
    out.mkdir()
    assert craftc(*replay_args(kb_a.cache, out)).exit_code == 0
    assert (out / "manifest.json").is_file()


def test_bundle_modes_follow_the_umask(kb_a: FixtureKB, tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        out = tmp_path / "b"
        assert craftc(*replay_args(kb_a.cache, out)).exit_code == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE(out.stat().st_mode) == 0o755
    for child in out.iterdir():
        assert stat.S_IMODE(child.stat().st_mode) == 0o644, child
