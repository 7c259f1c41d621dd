"""``craft sim demo`` says plainly whether the episode succeeded, and where it failed."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from craft_e.runtime.sim.figures import choice_error_sentence, descent_sentence, verdict
from craft_e.runtime.sim.pipeline import Failure


def _result(failure: Failure, chosen_body: int | None = 7) -> Any:
    outcome = SimpleNamespace(success=failure is Failure.SUCCESS, failure=failure,
                              chosen_body=chosen_body, chosen_roi=2)
    return SimpleNamespace(outcomes={"m": outcome}, body_assets={7: "knife", 9: "blue_cup"},
                           spec=SimpleNamespace(verb="cut", target="knife"))


def test_success_is_called_a_success() -> None:
    ok, sentence = verdict(_result(Failure.SUCCESS), "m")
    assert ok and sentence.startswith("SUCCESS") and "knife" in sentence


@pytest.mark.parametrize(
    ("failure", "words"),
    [
        (Failure.MISSED, "missed it"),
        (Failure.LIFT_FAILED, "lost it while lifting"),
        (Failure.SLIP_DURING_TRANSPORT, "dropped it on the way"),
        (Failure.NO_GRASP, "no usable grasp"),
    ],
)
def test_every_failure_is_called_a_failure(failure: Failure, words: str) -> None:
    ok, sentence = verdict(_result(failure), "m")
    assert not ok and sentence.startswith("FAILED") and words in sentence


def test_a_wrong_choice_names_what_was_chosen() -> None:
    ok, sentence = verdict(_result(Failure.WRONG_OBJECT, chosen_body=9), "m")
    assert not ok and "blue cup" in sentence and "not the knife" in sentence


def test_the_descent_says_where_the_hand_stopped_and_on_what() -> None:
    """The README demo's miss: the Franka hand rests on the cracker box 14 cm above the knife."""
    assert descent_sentence(0.139, ("cracker_box",)) == (
        "end of the descent: the hand stopped 13.9 cm above its grasp, touching the cracker box")
    assert descent_sentence(0.002, ("wood_block",)) == (
        "end of the descent: the hand reached its grasp, touching the wood block")


def test_a_wrong_choice_says_whether_perception_knowledge_or_energies_lost_it() -> None:
    assert choice_error_sentence(None, "wipe", "sponge", None) == ""
    perception = choice_error_sentence("perception", "wipe", "sponge", 1)
    assert "picks the sponge" in perception and "not recognised" in perception
    assert "ground truth" in perception  # never mistaken for something the robot knows
    assert "prefers another object for 'wipe'" in choice_error_sentence("knowledge", "wipe", "sponge", 0)
    energies = choice_error_sentence("energies", "wipe", "sponge", 0)
    assert "ranks the sponge first" in energies and "put roi0 ahead" in energies
