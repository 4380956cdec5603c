"""Objects and rooms in the viewer: box edges to draw, the list beside them, a point's room.

Everything comes from the report's ``objects`` and ``rooms`` sections (issue 33): object boxes
are in the file's coordinates and go through the scene's own transform (levelled, centred);
room outlines are in the levelled work frame.
"""

from __future__ import annotations

from collections.abc import Callable
from html import escape
from typing import Any

import numpy as np

from jointseg.classes import CLASS_NAMES, PALETTE
from web.legend import swatch
from web.scene import SceneData

#: Edges of a box whose corners are ordered bottom 0-3, top 4-7 (as the report writes them).
EDGES = np.array(
    [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
)
#: The class of an object whose class name is not one of jointseg's.
CLUTTER = CLASS_NAMES.index("clutter")
_TABLE = 'style="width:100%;border-collapse:collapse;font-size:0.8em"'
_CELL = 'style="padding:1px 4px;text-align:right"'
_LEFT = 'style="padding:1px 4px;text-align:left"'


def objects_of(data: SceneData) -> list[dict[str, Any]]:
    """The report's object records (empty when the result has none)."""
    items = (data.report or {}).get("objects")
    return items if isinstance(items, list) else []


def rooms_of(data: SceneData) -> list[dict[str, Any]]:
    """The report's room records (empty when the result has none)."""
    section = (data.report or {}).get("rooms")
    rooms = section.get("rooms") if isinstance(section, dict) else None
    return rooms if isinstance(rooms, list) else []


def box_segments(
    data: SceneData, keep: Callable[[np.ndarray], bool] | None = None
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Every object's 12 box edges in scene coordinates, (E, 2, 3) float32, and their class
    colour, (E, 2, 3) uint8, by class: one node per class, so that hiding a class hides its
    boxes with its points. An object of a class jointseg does not know counts as clutter.
    ``keep``: whether a box (its 8 corners, scene coordinates) is drawn (the clip box)."""
    boxes: dict[int, list[np.ndarray]] = {}
    for obj in objects_of(data):
        corners = data.shown_xyz(np.asarray(obj["box"], dtype=np.float64))
        if keep is not None and not keep(corners):
            continue
        cls = CLASS_NAMES.index(obj["cls"]) if obj["cls"] in CLASS_NAMES else CLUTTER
        boxes.setdefault(cls, []).append(corners[EDGES])
    return {
        cls: (
            np.concatenate(edges).astype(np.float32),
            np.broadcast_to(PALETTE[cls], (12 * len(edges), 2, 3)).astype(np.uint8),
        )
        for cls, edges in sorted(boxes.items())
    }


def objects_html(data: SceneData) -> str | None:
    """Objects counted by class (fragments apart), then the rooms with their area and height;
    None without."""
    objects, rooms = objects_of(data), rooms_of(data)
    if not objects and not rooms:
        return None
    counts: dict[str, int] = {}
    fragments = 0
    for obj in objects:
        if obj.get("plausible", True):
            counts[obj["cls"]] = counts.get(obj["cls"], 0) + 1
        else:
            fragments += 1
    rows = []
    for name in sorted(counts, key=lambda n: CLASS_NAMES.index(n) if n in CLASS_NAMES else 99):
        cls = CLASS_NAMES.index(name) if name in CLASS_NAMES else -1
        rows.append(
            f"<tr><td {_LEFT}>{swatch(cls)} {escape(name)}</td><td {_CELL}>{counts[name]}</td></tr>"
        )
    if fragments:  # pieces whose shape is not their class's: boxes drawn, not counted
        rows.append(f"<tr><td {_LEFT}>fragments</td><td {_CELL}>{fragments}</td></tr>")
    head = f"<tr><th {_LEFT}>objects</th><th {_CELL}>count</th></tr>"
    table = f"<table {_TABLE}>{head}{''.join(rows)}</table>"
    room_rows = []
    for room in rooms:
        height = room.get("ceiling_height")
        room_rows.append(
            f"<tr><td {_LEFT}>{escape(str(room['name']))}</td>"
            f"<td {_CELL}>{float(room['floor_area']):.1f} m²</td>"
            f"<td {_CELL}>{'-' if height is None else f'{float(height):.2f} m'}</td></tr>"
        )
    rooms_table = (
        f"<table {_TABLE}><tr><th {_LEFT}>room</th><th {_CELL}>floor area</th>"
        f"<th {_CELL}>height</th></tr>{''.join(room_rows)}</table>"
        if room_rows
        else ""
    )
    return table + rooms_table


def room_at(data: SceneData, shown: np.ndarray) -> str | None:
    """The name of the room whose outline holds a shown point (scene coordinates)."""
    work = np.asarray(shown, dtype=np.float64) + data.centre
    for room in rooms_of(data):
        outline = np.asarray(room.get("footprint") or [], dtype=np.float64)
        if len(outline) >= 3 and inside(outline, work[:2]):
            return str(room["name"])
    return None


def inside(polygon: np.ndarray, point: np.ndarray) -> bool:
    """Whether a 2D point lies inside a polygon (even-odd rule)."""
    x, y = float(point[0]), float(point[1])
    a, b = polygon, np.roll(polygon, -1, axis=0)
    crosses = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        at = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return bool(np.count_nonzero(crosses & (x < at)) % 2)


def object_name(data: SceneData, index: int) -> str | None:
    """``"chair 12"`` for a shown point of an object, None for structure or without ids."""
    if data.instance is None or data.instance[index] < 0:
        return None
    obj_id = int(data.instance[index])
    cls = next((o["cls"] for o in objects_of(data) if o.get("id") == obj_id), "object")
    return f"{cls} {obj_id}"
