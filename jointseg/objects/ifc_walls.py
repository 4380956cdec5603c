"""Walls, their openings, and the doors and windows that fill them, as BIM tools import them.

A wall is an ``IfcWall`` of the standard kind: a type per thickness holding an
``IfcMaterialLayerSet`` of that thickness, a layer-set usage on each wall, an axis and a body
swept from it. Two faces of one wall (:mod:`jointseg.objects.wall_shape`) are one wall, written
from the first face's record. Each door and window in a wall cuts an ``IfcOpeningElement``
through the whole wall (``IfcRelVoidsElement``) and fills it (``IfcRelFillsElement``), with
IfcOpenShell's parametric panel and lining bodies and a type (``IfcDoorType`` single swing,
``IfcWindowType`` single panel). Joined corners are ``IfcRelConnectsPathElements``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from jointseg.objects.records import OpeningRecord, WallRecord

#: The model being written (``jointseg.objects.ifc._Writer``; not imported: it imports this).
_Writer = Any

#: The opening stands out of both faces of its wall by this much, m (a cut, not a coincidence).
OPENING_MARGIN = 0.05
DOOR_OPERATION = "SINGLE_SWING_LEFT"
WINDOW_PARTITIONING = "SINGLE_PANEL"


@dataclass
class WallBody:
    """A written wall: its entity, placement (origin at floor level, x along the wall, y into
    its body), length, thickness, the face records it stands for and its openings' area."""

    entity: Any
    origin: np.ndarray
    x: np.ndarray
    y: np.ndarray
    length: float
    thickness: float
    records: list[int]
    reversed: bool
    opened: float = 0.0

    def along(self, point: np.ndarray) -> float:
        """A work-frame point's distance along the wall from its local origin."""
        return float((point[:2] - self.origin[:2]) @ self.x[:2])


def wall_body(w: _Writer, wall: WallRecord) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """Origin, x direction, length and whether it runs from the record's second corner: the
    profile is drawn to the left of x (local +y), so a wall whose body lies to the right of its
    face runs backwards."""
    c = w.work(wall.corners)
    run = c[1] - c[0]
    direction = run / max(float(np.hypot(run[0], run[1])), 1e-12)
    length = wall.length + wall.extends[0] + wall.extends[1]
    if wall.body_side >= 0:
        return c[0] - direction * wall.extends[0], direction, length, False
    return c[1] + direction * wall.extends[1], -direction, length, True


def write_walls(w: _Writer) -> dict[int, WallBody]:
    """Every wall (one per pair of faces), by each face record's id."""
    walls = w.layout.walls
    written: dict[int, WallBody] = {}
    types: dict[tuple[float, bool], Any] = {}
    for wall in walls:
        if wall.other_face is not None and wall.other_face < wall.id:
            continue  # the other face wrote this wall
        origin, x, length, backwards = wall_body(w, wall)
        entity = w.entity("IfcWall", f"Wall {wall.id + 1}")
        entity.PredefinedType = "STANDARD"
        rep = w.api.geometry.add_wall_representation(
            w.model, context=w.body, length=length, height=float(wall.height),
            thickness=wall.thickness,
        )  # fmt: skip
        axis = w.api.geometry.add_axis_representation(
            w.model, context=w.axis, axis=[(0.0, 0.0), (w.length(length), 0.0)]
        )
        w.api.geometry.assign_representation(w.model, product=entity, representation=axis)
        w.place(entity, rep, placement(origin, x))
        _assign_layers(w, entity, wall.thickness, wall.thickness_measured, types)
        y = np.array([-x[1], x[0], 0.0])
        records = [wall.id] + ([wall.other_face] if wall.other_face is not None else [])
        body = WallBody(entity, origin, x, y, length, wall.thickness, records, backwards)
        for r in records:
            written[r] = body
        w.contained.append(entity)
    return written


def _assign_layers(w: _Writer, wall: Any, thickness: float, measured: bool,
                   types: dict[tuple[float, bool], Any]) -> None:  # fmt: skip
    """The wall's type of its thickness (one material layer), and the layer-set usage that
    puts the layer on the wall's body."""
    key = (round(thickness, 3), measured)
    if key not in types:
        how = "measured" if measured else "declared"
        name = f"Wall {thickness * 1000:.0f} mm ({how})"
        material = w.api.material.add_material(w.model, name="Wall (scanned)")
        layers = w.api.material.add_material_set(w.model, name=name, set_type="IfcMaterialLayerSet")
        layer = w.api.material.add_layer(w.model, layer_set=layers, material=material)
        w.api.material.edit_layer(
            w.model, layer=layer, attributes={"LayerThickness": w.length(thickness)}
        )
        wall_type = w.api.root.create_entity(
            w.model, ifc_class="IfcWallType", name=name, predefined_type="STANDARD"
        )
        w.api.material.assign_material(
            w.model, products=[wall_type], type="IfcMaterialLayerSet", material=layers
        )
        types[key] = wall_type
    w.api.type.assign_type(
        w.model, related_objects=[wall], relating_type=types[key], should_map_representations=False
    )
    wall.PredefinedType = "STANDARD"
    w.api.material.assign_material(w.model, products=[wall], type="IfcMaterialLayerSetUsage")


def placement(origin: np.ndarray, x_axis: np.ndarray) -> np.ndarray:
    """A 4x4 placement at ``origin`` with its x along ``x_axis`` (horizontal) and z up."""
    x = np.array([x_axis[0], x_axis[1], 0.0])
    x /= max(float(np.linalg.norm(x)), 1e-12)
    z = np.array([0.0, 0.0, 1.0])
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, np.cross(z, x), z, origin
    return m


def opening_span(w: _Writer, host: WallBody, face: WallRecord, o: OpeningRecord) -> float:
    """Where the opening starts along the host wall's local x (the face it was measured on
    may be the wall's other face, or run the other way)."""
    c = w.work(face.corners)
    run = c[1] - c[0]
    direction = run / max(float(np.hypot(run[0], run[1])), 1e-12)
    start = c[0] + direction * o.offset
    end = start + direction * o.width
    return min(host.along(start), host.along(end))


def write_opening(w: _Writer, host: WallBody, face: WallRecord, o: OpeningRecord,
                  filling: Any) -> None:  # fmt: skip
    """The opening ``o`` through ``host``, voiding it, filled by ``filling`` (a door or window
    entity), which gets its body, type and placement in the opening."""
    lo = opening_span(w, host, face, o)
    base = host.origin + host.x * lo + np.array([0.0, 0.0, o.sill])
    opening = w.entity("IfcOpeningElement", f"Opening for {filling.Name}")
    opening.PredefinedType = "OPENING"
    rep = w.api.geometry.add_wall_representation(
        w.model, context=w.body, length=o.width, height=o.height,
        thickness=host.thickness + 2 * OPENING_MARGIN,
    )  # fmt: skip
    w.place(opening, rep, placement(base - host.y * OPENING_MARGIN, host.x))
    w.api.feature.add_feature(w.model, feature=opening, element=host.entity)
    if filling.is_a("IfcDoor"):
        body = w.api.geometry.add_door_representation(
            w.model, context=w.body, overall_height=w.length(o.height),
            overall_width=w.length(o.width), operation_type=DOOR_OPERATION,
            lining_properties={"LiningDepth": w.length(host.thickness)},
        )  # fmt: skip
    else:
        body = w.api.geometry.add_window_representation(
            w.model, context=w.body, overall_height=w.length(o.height),
            overall_width=w.length(o.width), partition_type=WINDOW_PARTITIONING,
            lining_properties={"LiningDepth": w.length(host.thickness)},
        )  # fmt: skip
    w.place(filling, body, placement(base, host.x))
    w.api.feature.add_filling(w.model, opening=opening, element=filling)
    host.opened += o.width * o.height


def element_type(w: _Writer, entity: Any, types: dict[str, Any]) -> None:
    """A door's or window's type: single swing door, single panel window."""
    door = entity.is_a("IfcDoor")
    key = "door" if door else "window"
    if key not in types:
        ifc_class = "IfcDoorType" if door else "IfcWindowType"
        name = "Door, single swing" if door else "Window, single panel"
        kind = w.api.root.create_entity(
            w.model, ifc_class=ifc_class, name=name, predefined_type="DOOR" if door else "WINDOW"
        )
        if door:
            kind.OperationType = DOOR_OPERATION
        else:
            kind.PartitioningType = WINDOW_PARTITIONING
        types[key] = kind
    w.api.type.assign_type(
        w.model, related_objects=[entity], relating_type=types[key],
        should_map_representations=False,
    )  # fmt: skip
    if door:
        entity.PredefinedType, entity.OperationType = "DOOR", DOOR_OPERATION
    else:
        entity.PredefinedType, entity.PartitioningType = "WINDOW", WINDOW_PARTITIONING


def connect_corners(w: _Writer, written: dict[int, WallBody]) -> None:
    """``IfcRelConnectsPathElements`` between walls joined at a corner, each at the end of its
    own path (its axis) that meets the other."""
    done: set[tuple[int, int]] = set()
    for wall in w.layout.walls:
        here = written.get(wall.id)
        for end, other in enumerate(wall.joined):
            there = written.get(other) if other is not None else None
            if here is None or there is None or here is there:
                continue
            a, b = here.entity.id(), there.entity.id()
            key = (min(a, b), max(a, b))
            if key in done:
                continue
            done.add(key)
            mine = "ATEND" if (end == 1) != here.reversed else "ATSTART"
            theirs = _end_near(there, w.work(wall.corners)[end])
            w.api.geometry.connect_path(
                w.model, relating_element=here.entity, related_element=there.entity,
                relating_connection=mine, related_connection=theirs,
            )  # fmt: skip


def _end_near(body: WallBody, point: np.ndarray) -> str:
    t = body.along(point)
    return "ATSTART" if t < body.length / 2 else "ATEND"
