"""Choosing the network for a scan (jointseg.network.choice): the colour-free one for a scan
without colour, loaded once per process (the bounded cache itself: tests/test_lru.py)."""

from __future__ import annotations

import pytest

from jointseg.network.choice import Choice, colour_free_if_needed
from jointseg.network.registry import load, resolve_weights


@pytest.mark.parametrize(
    ("mode", "usable", "user_weights", "colour_free"),
    [
        ("auto", True, False, False),
        ("auto", False, False, True),
        ("auto", False, True, False),  # the user's own weights are kept
        ("on", True, False, True),
        ("off", False, False, False),
    ],
)
def test_the_colour_free_network_is_taken_when_asked_for(
    mode: str, usable: bool, user_weights: bool, colour_free: bool
) -> None:
    predictor = load("randlanet")
    weights = resolve_weights("randlanet", None) if user_weights else None
    choice = Choice(colour_free=mode, weights=weights)  # type: ignore[arg-type]
    chosen = colour_free_if_needed(predictor, choice, usable)
    assert (chosen.card.get("colour") is False) == colour_free
    assert (chosen is predictor) == (not colour_free)
    if colour_free:  # loaded once per process
        assert colour_free_if_needed(predictor, choice, usable) is chosen
