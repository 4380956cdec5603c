"""Which network labels a scan: the one loaded, the colour-free RandLA-Net for a scan without
colour, or every installed network averaged (an ensemble).

The pipeline, the tiled runner and the CLI all choose through here, from a :class:`Choice` (the
pipeline config's network section as plain values, so this package needs nothing of the
pipeline's). The extra networks a choice needs are loaded once per process and kept in a
small cache of bounded size, so a worker that meets every kind of scan does not grow without
end.
"""

from __future__ import annotations

import logging
from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from jointseg.lru import LRUCache
from jointseg.network.backends import Predictor
from jointseg.network.pending import resolve
from jointseg.network.registry import REGISTRY, installed_backends, load

log = logging.getLogger(__name__)

#: Extra networks kept loaded per process (colour-free and ensemble members, per device).
CACHE_SIZE = 4


@dataclass(frozen=True)
class Choice:
    """What the user asked for (``PipelineConfig.network``)."""

    name: str = "randlanet"
    weights: Path | None = None
    device: str | None = None
    batch_size: int | None = None
    colour_free: Literal["auto", "on", "off"] = "auto"
    ensemble: bool = False
    #: Each backend's options (its config section), by backend name.
    params: Mapping[str, Any] = field(default_factory=dict)


#: The extra networks loaded in this process (:mod:`jointseg.lru`: bounded, shared by threads).
LOADED: LRUCache[Hashable, Predictor] = LRUCache(CACHE_SIZE)


def _where(predictor: Predictor) -> str:
    return str(predictor.device)


def colour_free_if_needed(predictor: Predictor, choice: Choice, usable_colour: bool) -> Predictor:
    """The colour-free RandLA-Net instead of the colour one for a scan without usable colour
    (``colour_free``: auto), or always (on); ``predictor`` itself otherwise."""
    from jointseg.network.randlanet.backend import COLOUR_FREE_WEIGHTS

    mode = choice.colour_free
    if mode == "auto" and (usable_colour or choice.name != "randlanet"):
        return predictor  # first: it needs no card, so a network still loading is not waited for
    if mode == "off" or predictor.card.get("colour") is False:
        return predictor
    if mode == "auto" and choice.weights is not None:
        return predictor  # the user chose these weights
    where = _where(predictor)
    batch = predictor.batch_size or choice.batch_size

    def loader() -> Predictor:
        params = choice.params.get("randlanet")
        return load("randlanet", COLOUR_FREE_WEIGHTS, device=where, batch_size=batch, params=params)

    log.info("no usable colour: using the colour-free network %s", COLOUR_FREE_WEIGHTS.name)
    return LOADED.get_or_load(("colour-free", where, batch or 0), loader)


def ensemble_of(predictor: Predictor, choice: Choice, usable_colour: bool = True) -> Predictor:
    """``predictor`` with every other backend whose weights are on this machine, averaged
    (:class:`~jointseg.network.ensemble.EnsemblePredictor`); itself when there is none. On a
    scan without usable colour only colour-free networks join: a network trained with colour
    and fed none pulls the mean down (best on y-up millimetre scans without colour: 51.40 ->
    48.11 fused on three Area_6 rooms)."""
    from jointseg.network.ensemble import EnsemblePredictor

    where = _where(predictor)
    members = [predictor]
    for name in installed_backends():
        if name == predictor.name:
            continue
        params = choice.params.get(name) if REGISTRY[name].params is not None else None
        member = LOADED.get_or_load(
            ("member", name, where),
            lambda name=name, params=params: load(  # type: ignore[misc]
                name, None, device=where, batch_size=None, params=params
            ),
        )
        if not usable_colour and member.card.get("colour", True) is not False:
            log.info("ensemble: %s needs colour and the scan has none; left out", name)
            continue
        members.append(member)
    if len(members) == 1:
        log.info("ensemble: no other network has weights here; %s alone", predictor.name)
        return predictor
    return EnsemblePredictor(members)


def network_for(predictor: Predictor, choice: Choice, usable_colour: bool) -> Predictor:
    """The network a scan is labelled with: the colour-free one for a scan without colour
    (:func:`colour_free_if_needed`), with every installed network averaged in when
    ``choice.ensemble`` (:func:`ensemble_of`)."""
    chosen = colour_free_if_needed(predictor, choice, usable_colour)
    return ensemble_of(resolve(chosen), choice, usable_colour) if choice.ensemble else chosen
