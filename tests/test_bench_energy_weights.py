"""The leave-one-verb-out selection of ``benchmarks/bench_energy_weights.py`` (no images needed)."""

from __future__ import annotations

from types import ModuleType

import pytest
from script_loader import load_benchmark


def _script() -> ModuleType:
    return load_benchmark("bench_energy_weights")


def test_each_held_out_verb_is_scored_with_the_weights_the_other_verbs_chose() -> None:
    low, paper = (1.0, 0.5), (1.0, 1.0)
    lvo = _script().leave_one_verb_out({
        low: {"a": 1.0, "b": 0.0, "c": 0.5},
        paper: {"a": 0.5, "b": 0.5, "c": 0.5},
    })
    # holding out a: b and c prefer the paper's (0.5 vs 0.25), which scores a at 0.5; holding out
    # b: a and c prefer gamma 0.5 (0.75 vs 0.5), b scores 0.0; holding out c: a and b tie at 0.5,
    # and a tie goes to the paper's (1, 1), c scores 0.5
    assert lvo["chosen"] == {"a": paper, "b": low, "c": paper}
    assert lvo["held_out_mean"] == pytest.approx((0.5 + 0.0 + 0.5) / 3)
    assert lvo["fixed_mean"] == {low: pytest.approx(0.5), paper: pytest.approx(0.5)}


def test_a_verb_that_alone_favours_a_weight_does_not_choose_it_for_itself() -> None:
    beta3, paper = (3.0, 0.5), (1.0, 1.0)
    lvo = _script().leave_one_verb_out({
        beta3: {"cut": 0.9, "hit": 0.8, "eat": 0.9},
        paper: {"cut": 0.5, "hit": 0.9, "eat": 0.95},
    })
    assert lvo["chosen"]["cut"] == paper  # hit and eat prefer it; cut's own 0.9 at beta 3 is not seen
    assert lvo["chosen"]["hit"] == beta3  # cut and eat: 0.9 against 0.725
    assert lvo["held_out_mean"] == pytest.approx((0.5 + 0.8 + 0.9) / 3)
    swing = lvo["largest_swing"]
    assert swing["unit"] == "cut"  # moves 0.4 with the weights; hit 0.1, eat 0.05
    assert swing["fixed_mean_without"] == {beta3: pytest.approx(0.85), paper: pytest.approx(0.925)}
    written = _script().lvo_as_json(lvo)  # JSON keys cannot be tuples
    assert written["chosen"]["hit"] == [3.0, 0.5]
    assert written["fixed_mean"]["beta 3, gamma 0.5"] == pytest.approx(0.8666666)


def test_a_missing_static_labels_file_fails_before_any_work(monkeypatch: pytest.MonkeyPatch,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr("sys.argv", ["bench_energy_weights.py", "--static-labels", "no-such-labels.csv"])
    with pytest.raises(SystemExit) as stopped:
        _script().main()
    assert stopped.value.code == 2
    assert "--static-labels no-such-labels.csv: no such labels file" in capsys.readouterr().err


def test_each_e_aff_scaling_is_its_own_row_set(monkeypatch: pytest.MonkeyPatch,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    script = _script()
    assert script._variant("craft-e-default", "none") == "craft-e-default"  # unscaled rows keep their names
    assert script._variant("craft-e-default", "verb-best") == "craft-e-default + verb-best"
    assert script._norm_of("craft-e-default + verb-best") == "verb-best"
    assert script._norm_of("craft-e-default") == "none"
    monkeypatch.setattr("sys.argv", ["bench_energy_weights.py", "--aff-norm", "max"])
    with pytest.raises(SystemExit) as stopped:
        script.main()
    assert stopped.value.code == 2
    assert "invalid choice: 'max'" in capsys.readouterr().err
