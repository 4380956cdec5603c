"""Which columns of a file hold colour and labels, so every format accepts the same spellings."""

from __future__ import annotations

#: Property / column names (lower case) read as ground-truth labels, in order of preference.
LABEL_NAMES: tuple[str, ...] = (
    "label",
    "class",
    "classification",
    "scalar_classification",
    "scalar_label",
)

#: Accepted spellings of the three colour channels (lower case), in order of preference.
COLOUR_NAMES: tuple[tuple[str, str, str], ...] = (
    ("red", "green", "blue"),
    ("r", "g", "b"),
    ("diffuse_red", "diffuse_green", "diffuse_blue"),
)


def pick_name(names: list[str], candidates: tuple[str, ...]) -> str | None:
    """Return the first of ``names`` matching ``candidates`` case-insensitively, by preference."""
    lower = {n.lower(): n for n in reversed(names)}
    for cand in candidates:
        if cand in lower:
            return lower[cand]
    return None


def pick_colour_names(names: list[str]) -> tuple[str, str, str] | None:
    """Find the three colour channel names among ``names`` (case-insensitive), or None."""
    lower = {n.lower(): n for n in reversed(names)}
    for triple in COLOUR_NAMES:
        if all(c in lower for c in triple):
            return (lower[triple[0]], lower[triple[1]], lower[triple[2]])
    return None
