"""Commands run outside the checkout's root: the default ``artifacts`` folder is read from the
current directory, so there it holds nothing. Each "not found" about a default path says so
(``paths.artifacts_hint``), and an evaluation none of whose methods can run exits 2 before any
episode instead of spending its run and writing a table of skips (``NoMethodToRunError``)."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

import craft_e.paths as paths
from craft_e.compiler.vocab import VocabError, read_vocabulary
from craft_e.runtime.cli.main import app
from craft_e.runtime.evaluation.methods import (
    MethodSpec,
    NoMethodToRunError,
    load_methods,
    select_methods,
)
from craft_e.runtime.evaluation.sim_eval import LabelsError, load_sim_labels
from craft_e.runtime.kb.bundle import BundleError, load_bundle

REPO = Path(__file__).resolve().parents[1]
HINT = "run from the checkout's root, or set CRAFT_ARTIFACTS"


@pytest.fixture
def elsewhere(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A shell in a folder that is not the checkout, with the default (relative) artifacts path."""
    monkeypatch.delenv("CRAFT_ARTIFACTS", raising=False)
    monkeypatch.setattr(paths, "ARTIFACTS_DIR", Path("artifacts"))
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_the_hint_names_the_current_directory_only_where_it_applies(
        elsewhere: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    hint = paths.artifacts_hint(Path("artifacts/kb/craft-e-default"))
    assert HINT in hint and str(elsewhere) in hint
    assert paths.artifacts_hint(Path("my_labels.csv")) == ""  # not under artifacts/: the user's own path
    assert paths.artifacts_hint(elsewhere / "artifacts" / "kb") == ""  # absolute: sought where it says
    (elsewhere / "artifacts" / "vocab").mkdir(parents=True)
    (elsewhere / "artifacts" / "labels").mkdir()
    # a checkout's own artifacts folder: the file is missing from it, not sought in the wrong place
    assert paths.artifacts_hint(Path("artifacts/kb/craft-e-default")) == ""
    (elsewhere / "artifacts" / "labels").rmdir()
    monkeypatch.setenv("CRAFT_ARTIFACTS", "artifacts")
    assert paths.artifacts_hint(Path("artifacts/kb/x")) == ""  # configured on purpose


def test_default_paths_not_found_say_where_they_were_sought(elsewhere: Path) -> None:
    with pytest.raises(BundleError, match=HINT):
        load_bundle(Path("artifacts/kb/craft-e-default"))
    with pytest.raises(LabelsError, match="labels file not found.*" + HINT):
        load_sim_labels(Path("artifacts/labels/sim_dev_labels.csv"))
    with pytest.raises(VocabError, match=HINT):
        read_vocabulary(Path("artifacts/vocab/union_objects.txt"), kind="objects")
    with pytest.raises(LabelsError) as own:
        load_sim_labels(Path("mine.csv"))
    assert "CRAFT_ARTIFACTS" not in str(own.value)  # the user's own path: no hint


def test_an_evaluation_none_of_whose_methods_can_run_fails_naming_each(elsewhere: Path) -> None:
    with pytest.raises(NoMethodToRunError) as info:
        load_methods(select_methods(kb_dir=Path("artifacts/kb")))  # the default, as the CLI resolves it
    message = str(info.value)
    # the two methods of one bundle are named together, and the hint is said once
    assert message.startswith("no method can run: CRAFT-E, alignment-only: bundle unavailable: "
                              "artifacts/kb/craft-e-default: not a bundle folder")
    assert "CRAFT: bundle unavailable: artifacts/kb/conceptnet" in message
    assert "direct-LLM: bundle unavailable: artifacts/kb/direct-llm" in message
    assert message.count(HINT) == 1 and message.endswith(")")
    # one method that loads is enough: the others are skipped with their reasons, as before
    good = MethodSpec("CRAFT-E", "shipped", REPO / "artifacts" / "kb" / "craft-e-default")
    runnable, skipped = load_methods([good, *select_methods(["CRAFT"], kb_dir=Path("artifacts/kb"))])
    assert [s.name for s, _ in runnable] == ["CRAFT-E"] and [s.name for s in skipped] == ["CRAFT"]


def test_craft_eval_sim_with_no_bundle_exits_2_and_writes_nothing(tmp_path: Path) -> None:
    labels = tmp_path / "labels.csv"
    labels.write_text("verb,object\ncut,knife\n", encoding="utf-8")
    (tmp_path / "no_bundles").mkdir()
    out = tmp_path / "out.json"
    result = CliRunner().invoke(app, ["eval", "sim", "--labels", str(labels), "--kb-dir",
                                      str(tmp_path / "no_bundles"), "--json", str(out)])
    assert result.exit_code == 2, result.output
    assert "no method can run: CRAFT-E, alignment-only: bundle unavailable" in result.output
    assert not out.exists()


def test_evaluations_refuse_before_building_the_encoder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Building the default encoder loads its weights and writes its class-name cache under the
    artifacts folder: a run that cannot ground must not get that far."""
    from craft_e.runtime.evaluation import pickability, sim_eval, static_eval

    def built(*_: object, **__: object) -> None:
        raise AssertionError("the encoder was built before the methods were checked")

    for module in (sim_eval, static_eval, pickability):
        monkeypatch.setattr(module, "default_encoder", built)
    labels = tmp_path / "labels.csv"
    labels.write_text("verb,object\ncut,knife\n", encoding="utf-8")
    missing = select_methods(kb_dir=tmp_path / "no_bundles")
    with pytest.raises(NoMethodToRunError):
        sim_eval.evaluate_sim(labels, methods=missing)
    with pytest.raises(NoMethodToRunError):
        static_eval.evaluate_static(labels, methods=missing)
    with pytest.raises(NoMethodToRunError):
        pickability.evaluate_pickability(["banana"], method=missing[0])


def test_craft_eval_kb_with_no_bundle_that_loads_exits_2(elsewhere: Path) -> None:
    """Its chance and oracle rows alone would make a table that compares nothing."""
    from craft_e.runtime.evaluation.kb_eval import evaluate_kbs

    with pytest.raises(NoMethodToRunError, match="no method can run: artifacts/kb/direct-llm: bundle unavailable") as info:
        evaluate_kbs([Path("artifacts/kb/direct-llm")], ["zhu"])
    assert str(info.value).count(HINT) == 1
