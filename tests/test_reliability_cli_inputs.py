"""Bad input to ``craftc build/diff/keygen`` and ``craft install/installed`` (probe round 2).

Each test failed before its fix: an empty ``--fail-on`` rule passed a gate unchecked; NaN or
negative ``--batch-wait`` and a blank ``--record-provider`` were accepted; an unreadable input
(a folder as ``--overrides``, a ConceptNet file that is not gzip or not text) was reported as
"cannot write the bundle"; a build nested a bundle inside another or failed below a file with
"racing another build"; ``--out ""`` / ``--into ""`` meant the working directory; a junk
``--trusted-key`` was called a private key (exit 1); ``craft install`` wrote into a bundle
folder; ``craft installed`` on a missing folder said "nothing installed" (exit 0); and a
duplicate vocabulary line's different gloss was dropped silently. Exit codes are the README's.
"""

from __future__ import annotations

import errno
import gzip
import shutil
from pathlib import Path

import pytest
from conftest import KB_NAME, KB_SMALL, FixtureKB
from test_cli_craftc import craftc, flat, replay_args
from typer.testing import CliRunner, Result

from craft_e.compiler.diff import VALID_RULES, DiffError, parse_rules
from craft_e.compiler.pack import keygen, pack_bundle
from craft_e.compiler.sources.conceptnet import ConceptNetInputError, read_assertions_csv
from craft_e.compiler.vocab import VocabError, read_vocabulary
from craft_e.runtime.cli.main import app as craft_app
from craft_e.runtime.kb.install import InstallError, install, installed, rollback


def craft(*args: str | Path) -> Result:
    return CliRunner().invoke(craft_app, [str(a) for a in args], env={"COLUMNS": "2000"})


def tree(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


# --- craftc diff --fail-on ----------------------------------------------------------------------


@pytest.mark.parametrize("rule", ["", " ", "top1-changed,", ",verb-removed"])
def test_an_empty_fail_on_rule_is_refused(rule: str) -> None:
    with pytest.raises(DiffError, match="empty --fail-on rule") as info:
        parse_rules([rule])
    assert all(valid in str(info.value) for valid in VALID_RULES)


def test_diff_with_an_unset_rule_is_exit_2_not_a_passed_gate(kb_a: FixtureKB) -> None:
    result = craftc("diff", kb_a.bundle, kb_a.bundle, "--fail-on", "")
    assert result.exit_code == 2, result.output
    assert "empty --fail-on rule" in flat(result.output)
    assert "top1-changed" in flat(result.output)


# --- craftc build: options ----------------------------------------------------------------------


@pytest.mark.parametrize("wait", ["nan", "-5", "inf"])
def test_batch_wait_must_be_a_finite_number_of_seconds(
    kb_a: FixtureKB, tmp_path: Path, wait: str
) -> None:
    result = craftc(*replay_args(kb_a.cache, tmp_path / "out"), "--batch-wait", wait)
    assert result.exit_code == 2, result.output
    assert "--batch-wait" in flat(result.output) and ">= 0" in flat(result.output)
    assert not (tmp_path / "out").exists()


def test_batch_wait_zero_is_allowed(kb_a: FixtureKB, tmp_path: Path) -> None:
    """0 is meaningful for a batch provider (poll once); a replay build ignores it."""
    result = craftc(*replay_args(kb_a.cache, tmp_path / "out"), "--batch-wait", "0")
    assert result.exit_code == 0, result.output


@pytest.mark.parametrize("blank", ["", "  "])
def test_a_blank_record_provider_is_a_usage_error(
    kb_a: FixtureKB, tmp_path: Path, blank: str
) -> None:
    result = craftc(*replay_args(kb_a.cache, tmp_path / "out"), "--record-provider", blank)
    assert result.exit_code == 2, result.output
    assert "--record-provider is empty" in flat(result.output)
    assert "no record" not in flat(result.output)


# --- craftc build: inputs are not outputs -------------------------------------------------------


def test_a_folder_as_overrides_names_the_input_not_the_out(kb_a: FixtureKB, tmp_path: Path) -> None:
    folder = tmp_path / "ov"
    folder.mkdir()
    result = craftc(*replay_args(kb_a.cache, tmp_path / "out"), "--overrides", folder)
    assert result.exit_code == 2, result.output
    text = flat(result.output)
    assert f"{folder}: is a folder; --overrides takes a TOML file" in text
    assert "cannot write the bundle" not in text
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("name", "data", "expected"),
    [
        ("bad.csv.gz", b"not gzip at all\n", "not a gzip file, though named .gz"),
        ("bin.csv", b"\xff\xfe\x00binary", "not valid UTF-8 text"),
        ("zipped.csv", gzip.compress(b"a\tb\n"), "gzip-compressed: name it with a .gz suffix"),
        ("folder", None, "is a folder, not a ConceptNet file"),
    ],
    ids=["not-gzip", "not-text", "gzip-without-suffix", "folder"],
)
def test_an_unreadable_conceptnet_file_is_an_input_error(
    kb_a: FixtureKB, tmp_path: Path, name: str, data: bytes | None, expected: str
) -> None:
    path = tmp_path / name
    if data is None:
        path.mkdir()
    else:
        path.write_bytes(data)
    result = craftc(*replay_args(kb_a.cache, tmp_path / "out"), "--mode", "conceptnet",
                    "--conceptnet", f"csv:{path}")
    assert result.exit_code == 2, result.output
    text = flat(result.output)
    assert f"{path}: " in text and expected in text
    assert "cannot write the bundle" not in text and "codec can't decode" not in text
    assert not (tmp_path / "out").exists()


def test_the_csv_reader_names_the_file_of_a_damaged_gzip(tmp_path: Path) -> None:
    """The streaming reader (not only the build's up-front check) names the file and line."""
    truncated = tmp_path / "cut.csv.gz"
    truncated.write_bytes(gzip.compress(b"/a/x\t/r/UsedFor\t/c/en/a\t/c/en/b\t{}\n" * 50)[:-12])
    with pytest.raises(ConceptNetInputError, match=r"cut\.csv\.gz: not a readable gzip file"):
        list(read_assertions_csv(truncated))
    latin = tmp_path / "latin.csv"
    latin.write_bytes(b"/a/x\t/r/UsedFor\t/c/en/a\t/c/en/b\t{}\n" * 5000 + b"/a/\xe9\t")
    with pytest.raises(ConceptNetInputError, match=r"latin\.csv: past line \d+: not valid UTF-8"):
        list(read_assertions_csv(latin))


def test_an_input_read_error_is_not_called_an_output_error(
    kb_a: FixtureKB, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import craft_e.compiler.build as build_mod

    def failing_pass(*args: object, **kwargs: object) -> None:
        raise OSError(errno.EIO, "Input/output error", str(tmp_path / "some-input.txt"))

    monkeypatch.setattr(build_mod, "_source_pass", failing_pass)
    result = craftc(*replay_args(kb_a.cache, tmp_path / "out"))
    assert result.exit_code == 2, result.output
    text = flat(result.output)
    assert f"cannot read {tmp_path / 'some-input.txt'} (Input/output error)" in text
    assert "cannot write the bundle" not in text


# --- craftc build / keygen: where the output goes -------------------------------------------------


def test_out_below_a_file_says_so(kb_a: FixtureKB, tmp_path: Path) -> None:
    afile = tmp_path / "afile.txt"
    afile.write_text("mine\n")
    result = craftc(*replay_args(kb_a.cache, afile / "sub"))
    assert result.exit_code == 2, result.output
    text = flat(result.output)
    assert f"{afile} is a file, not a folder" in text and "racing" not in text
    assert afile.read_text() == "mine\n"


def test_out_inside_a_bundle_is_refused(kb_a: FixtureKB, tmp_path: Path) -> None:
    outer = tmp_path / "outer"
    shutil.copytree(kb_a.bundle, outer)
    before = tree(outer)
    for nested in (outer / "sub", outer / "sub" / "deeper"):
        result = craftc(*replay_args(kb_a.cache, nested))
        assert result.exit_code == 2, result.output
        assert f"is inside the bundle {KB_NAME!r} at {outer}" in flat(result.output)
    assert tree(outer) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["outer"]


def test_empty_out_paths_are_refused(
    kb_a: FixtureKB, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    args = [str(a) for a in replay_args(kb_a.cache, Path("placeholder"))]
    args[args.index("placeholder")] = ""
    result = craftc(*args)
    assert result.exit_code == 2, result.output
    assert "empty path" in flat(result.output)
    keys = craftc("keygen", "--out", "")
    assert keys.exit_code == 2, keys.output
    assert "empty path" in flat(keys.output)
    assert list(work.iterdir()) == []


# --- vocabularies ----------------------------------------------------------------------------------


def test_a_duplicate_with_another_gloss_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "objects.txt"
    path.write_text("crane\ta large wading bird\nknife\nCrane\ta lifting machine\n")
    with pytest.raises(VocabError) as info:
        read_vocabulary(path, kind="objects")
    message = str(info.value)
    assert f"{path}:3:" in message and "line 1" in message
    assert "'a lifting machine'" in message and "'a large wading bird'" in message
    path.write_text("knife\nknife\ta blade with a handle\n")  # the first line had no gloss
    with pytest.raises(VocabError, match=r"objects\.txt:2: 'knife' again.*line 1 gives it no gloss"):
        read_vocabulary(path, kind="objects")


def test_duplicates_that_agree_stay_notes(tmp_path: Path) -> None:
    path = tmp_path / "objects.txt"
    path.write_text("crane\ta  large wading bird\ncrane\ta large wading bird\ncrane\n")
    vocab = read_vocabulary(path, kind="objects")
    assert vocab.names == ["crane"] and vocab.glosses == {"crane": "a large wading bird"}
    assert sum("duplicate of line 1" in n for n in vocab.notes) == 2


def test_every_shipped_vocabulary_still_loads() -> None:
    root = Path(__file__).resolve().parents[1]
    files = [*sorted((root / "artifacts" / "vocab").glob("*.txt")), *sorted(KB_SMALL.glob("*.txt"))]
    assert files
    for path in files:
        read_vocabulary(path, kind="verbs" if "verb" in path.name else "objects")


# --- craft install / installed ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def signed(kb_a: FixtureKB, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """(package of the fixture KB, its signer's public key, the private key)."""
    root = tmp_path_factory.mktemp("signed")
    pair = keygen(root / "keys")
    return pack_bundle(kb_a.bundle, pair.private_key, root / "kb.craft").out, pair.public_key, pair.private_key


def test_a_junk_trusted_key_is_bad_input_not_a_private_key(
    tmp_path: Path, signed: tuple[Path, Path, Path]
) -> None:
    package, _, private = signed
    junk = tmp_path / "bad.key"
    junk.write_text("garbage\n")
    result = craft("install", package, "--into", tmp_path / "i", "--trusted-key", junk)
    assert result.exit_code == 2, result.output
    assert f"{junk}: not an Ed25519 public key file" in flat(result.output)
    assert "private" not in flat(result.output)
    result = craft("install", package, "--into", tmp_path / "i", "--trusted-key", private)
    assert result.exit_code == 2, result.output
    assert f"{private}: is a private signing key" in flat(result.output)
    assert "craft-signing.pub" in flat(result.output)
    assert not (tmp_path / "i").exists()


def test_install_refuses_a_bundle_folder_and_a_users_folder(
    kb_a: FixtureKB, tmp_path: Path, signed: tuple[Path, Path, Path]
) -> None:
    package, public, _ = signed
    bundle = Path(shutil.copytree(kb_a.bundle, tmp_path / "bundle"))
    users = tmp_path / "mine"
    users.mkdir()
    (users / "notes.txt").write_text("x")
    before = {p: tree(p) for p in (bundle, users)}
    result = craft("install", package, "--into", bundle, "--trusted-key", public)
    assert result.exit_code == 2, result.output
    assert f"{bundle}: is a KB bundle folder" in flat(result.output)
    result = craft("install", package, "--into", users, "--trusted-key", public)
    assert result.exit_code == 2, result.output
    assert f"{users}: is a folder with other content (notes.txt)" in flat(result.output)
    with pytest.raises(InstallError, match="is a KB bundle folder"):
        rollback(bundle)
    assert {p: tree(p) for p in (bundle, users)} == before  # not even a .lock


def test_install_accepts_new_empty_and_install_folders(
    tmp_path: Path, signed: tuple[Path, Path, Path]
) -> None:
    package, public, _ = signed
    empty = tmp_path / "empty"
    empty.mkdir()
    for into in (tmp_path / "new" / "kb", empty):
        install(package, into, [public])
        (into / "NOTES").write_text("an operator's note beside an install")
        install(package, into, [public])  # an install folder with a note is still one
        assert [v.is_current for v in installed(into)] == [True]
    with pytest.raises(InstallError, match="is empty"):
        install(package, "", [public])


def test_empty_into_is_a_usage_error(
    tmp_path: Path, signed: tuple[Path, Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    package, public, _ = signed
    monkeypatch.chdir(tmp_path)
    before = tree(tmp_path)
    for args in (("install", package, "--into", "", "--trusted-key", public),
                 ("installed", "--into", ""), ("rollback", "--into", "")):
        result = craft(*args)
        assert result.exit_code == 2, result.output
        assert "empty path" in flat(result.output)
    assert tree(tmp_path) == before


def test_installed_on_a_missing_folder_is_exit_2_like_rollback(tmp_path: Path) -> None:
    nowhere = tmp_path / "nowhere"
    for command in ("installed", "rollback"):
        result = craft(command, "--into", nowhere)
        assert result.exit_code == 2, (command, result.output)
        assert f"{nowhere}: no such install folder" in flat(result.output)
    assert not nowhere.exists()
    assert installed(nowhere) == []  # the Python API: nothing installed yet


def test_installed_on_a_bundle_folder_is_refused(kb_a: FixtureKB) -> None:
    result = craft("installed", "--into", kb_a.bundle)
    assert result.exit_code == 2, result.output
    assert "is a KB bundle folder" in flat(result.output)


def test_an_unreadable_trusted_key_says_so(tmp_path: Path, signed: tuple[Path, Path, Path],
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    package, public, _ = signed
    copy = tmp_path / "craft-signing.pub"
    shutil.copy(public, copy)
    real = Path.read_bytes

    def denied(self: Path) -> bytes:  # chmod 000 does not stop root (CI may be root): simulated
        if self == copy:
            raise PermissionError(13, "Permission denied", str(self))
        return real(self)

    monkeypatch.setattr(Path, "read_bytes", denied)
    result = craft("install", package, "--into", tmp_path / "i", "--trusted-key", copy)
    assert result.exit_code == 2, result.output
    assert "cannot read the trusted key" in flat(result.output)
