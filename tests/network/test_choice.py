"""Choosing the network for a scan (jointseg.network.choice): the colour-free one for a scan
without colour, extra networks loaded once and kept in a bounded cache."""

from __future__ import annotations

import pytest

from jointseg.network.choice import Choice, LoadedNetworks, colour_free_if_needed
from jointseg.network.registry import load, resolve_weights


class Counting:
    """Loaders that count their calls and hand out a distinct object each time."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self) -> object:
        self.calls += 1
        return object()


def test_a_loaded_network_is_reused_and_the_oldest_dropped_beyond_the_size() -> None:
    cache = LoadedNetworks(size=2)
    loader = Counting()
    a = cache.get("a", loader)  # type: ignore[arg-type]
    assert cache.get("a", loader) is a and loader.calls == 1  # type: ignore[arg-type]
    cache.get("b", loader)  # type: ignore[arg-type]
    cache.get("a", loader)  # type: ignore[arg-type]  # a is now the most recent
    cache.get("c", loader)  # type: ignore[arg-type]  # b, the least recent, goes
    assert len(cache) == 2 and loader.calls == 3
    assert cache.get("a", loader) is a and loader.calls == 3  # type: ignore[arg-type]
    cache.get("b", loader)  # type: ignore[arg-type]
    assert loader.calls == 4  # b was loaded again


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
