"""Whether an object's box has the shape of its class: a door reaches from the floor to about
2 m, a table's top stands at desk height, a chair is no longer than a sofa.

Labels from a network leave fragments: a strip of a wall read as door, the seat of a chair
read as table. They stay objects (every point of a thing class keeps an object id), but
they are not counted as that class's inventory, nor modelled as doors or furniture in IFC.
The ranges are in metres and generous (tall doors, bar tables, wall-hung shelves); they were
set on the tuning scans of ``bench/objects.py`` (synthetic seeds 1-8, ScanNet tuning scans).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Shape:
    """The box a class's objects fit: top above the floor, height, longer horizontal side,
    and how high above the floor its bottom may be."""

    top: tuple[float, float] = (0.0, 100.0)
    min_height: float = 0.0
    long: tuple[float, float] = (0.0, 100.0)
    max_bottom: float = 100.0


#: Classes without an entry (beam, column, board, clutter) take any shape.
SHAPES: dict[str, Shape] = {
    "door": Shape(top=(1.5, 3.2), min_height=1.2, long=(0.4, 100.0), max_bottom=0.3),
    "window": Shape(min_height=0.3, long=(0.3, 100.0)),
    "table": Shape(top=(0.4, 1.4), long=(0.4, 100.0)),
    "chair": Shape(top=(0.4, 1.6), long=(0.25, 2.2), max_bottom=0.4),  # two touching: one
    "sofa": Shape(top=(0.4, 1.4), long=(0.7, 100.0), max_bottom=0.4),
    "bookcase": Shape(min_height=0.4, long=(0.3, 100.0)),
}


def fits_class(cls: str, size: tuple[float, float, float], bottom: float) -> bool:
    """Whether a box of ``size`` (room-aligned x, y and height, m) whose bottom stands
    ``bottom`` m above the floor has the shape of class ``cls``."""
    shape = SHAPES.get(cls)
    if shape is None:
        return True
    long, height = max(size[0], size[1]), size[2]
    top = bottom + height
    return (
        shape.top[0] <= top <= shape.top[1]
        and height >= shape.min_height
        and shape.long[0] <= long <= shape.long[1]
        and bottom <= shape.max_bottom
    )
