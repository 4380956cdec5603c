"""Model cards without the paths of the machine that trained the weights.

A card travels with the weights to every user (``jointseg models list``, every job's report as
``trained_on``), so a folder of the development machine (``/work/shared/data/s3dis_area6``,
``../shared/data``) says nothing to its reader and tells where someone's files lie. Every path in
a card is written as its last part, the data set's folder or the file's name
(``s3dis_area6``, ``randlanet_area6_gpu.pt``); relative paths inside a project
(``runs/cpu_bg/nocolour.pt``) stay as they are.
"""

from __future__ import annotations

import re
from typing import Any

#: An absolute or home path, or one that climbs out of its folder (``../``), where a path
#: starts: after a space, ``=``, a bracket or a quote, never inside a word (``r/255``), a URL
#: (``https://``) or another path.
MACHINE_PATH = re.compile(r"(?<![\w.:/~\\-])(?:/|~/|(?:\.\./)+)[\w.*+@%-][\w./*+@%-]*")


def portable_text(text: str) -> str:
    """``text`` with every machine path replaced by its last part (a trailing ``/`` dropped)."""

    def last_part(match: re.Match[str]) -> str:
        parts = [p for p in match.group(0).split("/") if p not in ("", "..", "~")]
        return parts[-1] if parts else ""

    return MACHINE_PATH.sub(last_part, text)


def portable_card(card: Any) -> Any:
    """A copy of ``card`` (nested dicts, lists and strings) with :func:`portable_text` applied to
    every string, keys included; other values unchanged."""
    if isinstance(card, str):
        return portable_text(card)
    if isinstance(card, dict):
        return {portable_card(k): portable_card(v) for k, v in card.items()}
    if isinstance(card, list | tuple):
        return type(card)(portable_card(v) for v in card)
    return card


def machine_paths(card: Any) -> list[str]:
    """Every machine path in ``card``'s strings and keys, in the order found (none for a card
    :func:`portable_card` wrote)."""
    if isinstance(card, str):
        return [m.group(0) for m in MACHINE_PATH.finditer(card)]
    if isinstance(card, dict):
        return [p for k, v in card.items() for p in (*machine_paths(k), *machine_paths(v))]
    if isinstance(card, list | tuple):
        return [p for v in card for p in machine_paths(v)]
    return []
