"""An IFC4 model of a segmented scan, written with IfcOpenShell (a BIM library, not hand-made
STEP): IfcProject > IfcSite > IfcBuilding > IfcBuildingStorey, an IfcSpace per room, IfcWall
per wall plane, IfcSlab for each room's floor and ceiling, IfcDoor and IfcWindow from their
objects, IfcFurniture for tables, chairs, sofas and bookcases, IfcBuildingElementProxy for the
rest.

The model is in the levelled metric frame (z up), whatever the scan's own axes and units; the
layout's user coordinates are mapped back through ``to_user``. Its declared length unit is the
millimetre (IfcOpenShell's default, what BIM tools expect), areas square metres. Placements,
extrusions and profiles are given to IfcOpenShell's geometry API in metres, which converts
them; every length set directly (OverallWidth/OverallHeight, the storey's Elevation,
quantities) goes through :meth:`_Writer.length`, so none is left in metres by mistake.

Quantities BIM tools schedule from: ``Qto_SpaceBaseQuantities`` and ``Pset_SpaceCommon`` on
each space, ``Qto_WallBaseQuantities`` on walls, ``Qto_DoorBaseQuantities`` and
``Qto_WindowBaseQuantities`` on doors and windows, all taken from the layout's records (the
values ``objects.json`` holds).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.objects.ifc_walls import (
    WallBody,
    connect_corners,
    element_type,
    placement,
    write_opening,
    write_walls,
)
from jointseg.objects.params import ObjectParams
from jointseg.objects.records import (
    LayoutReport,
    ObjectRecord,
    OpeningRecord,
    RoomRecord,
)

log = logging.getLogger(__name__)

FURNITURE = {"table", "chair", "sofa", "bookcase"}
#: Height given to a room's space when its ceiling was not found, metres.
DEFAULT_ROOM_HEIGHT = 2.5


def build_model(
    layout: LayoutReport, params: ObjectParams | None = None, *, name: str = "scan"
) -> Any:
    """The IFC4 model (an ``ifcopenshell.file``) of ``layout``."""
    params = params or ObjectParams()
    writer = _Writer(layout, params, name)
    writer.rooms()
    writer.walls()
    writer.objects()
    writer.wall_quantities()
    connect_corners(writer, writer.written)
    writer.contain()
    return writer.model


class _Writer:
    """One model being built: the spatial tree, the body context, and what goes in the storey."""

    def __init__(self, layout: LayoutReport, params: ObjectParams, name: str) -> None:
        import ifcopenshell.api
        import ifcopenshell.api.aggregate
        import ifcopenshell.api.context
        import ifcopenshell.api.feature
        import ifcopenshell.api.geometry
        import ifcopenshell.api.material
        import ifcopenshell.api.project
        import ifcopenshell.api.pset
        import ifcopenshell.api.root
        import ifcopenshell.api.spatial
        import ifcopenshell.api.type
        import ifcopenshell.api.unit

        self.api = api = ifcopenshell.api
        self.layout, self.params = layout, params
        to_user = np.asarray(layout.to_user or np.eye(4).tolist(), dtype=np.float64)
        self.to_work = np.linalg.inv(to_user)
        self.floor_z = layout.floor_z or 0.0
        self.model = model = api.project.create_file(version="IFC4")
        project = api.root.create_entity(model, ifc_class="IfcProject", name=f"jointseg: {name}")
        api.unit.assign_unit(model)
        context = api.context.add_context(model, context_type="Model")
        self.body = api.context.add_context(
            model, context_type="Model", context_identifier="Body", target_view="MODEL_VIEW",
            parent=context,
        )  # fmt: skip
        self.axis = api.context.add_context(
            model, context_type="Model", context_identifier="Axis", target_view="GRAPH_VIEW",
            parent=context,
        )  # fmt: skip
        self.written: dict[int, WallBody] = {}
        self.element_types: dict[str, Any] = {}
        from ifcopenshell.util.unit import calculate_unit_scale

        # project units per SI unit: 1000 for millimetres, 1 for square metres
        self.per_metre = 1.0 / calculate_unit_scale(model, "LENGTHUNIT")
        self.per_square_metre = 1.0 / calculate_unit_scale(model, "AREAUNIT")
        self.storey = self.spatial_tree(project)
        self.contained: list[Any] = []

    def spatial_tree(self, project: Any) -> Any:
        """Site > building > storey under ``project``; the storey placed at the floor's level
        with that level as its Elevation (what a BIM tool makes its level from)."""
        aggregate = self.api.aggregate.assign_object
        site = self.entity("IfcSite", "Site")
        building = self.entity("IfcBuilding", "Building")
        storey = self.entity("IfcBuildingStorey", "Scanned storey")
        aggregate(self.model, products=[site], relating_object=project)
        aggregate(self.model, products=[building], relating_object=site)
        aggregate(self.model, products=[storey], relating_object=building)
        for product, z in ((site, 0.0), (building, 0.0), (storey, self.floor_z)):
            matrix = placement(np.array([0.0, 0.0, z]), np.array([1.0, 0.0]))
            self.api.geometry.edit_object_placement(self.model, product=product, matrix=matrix)
        storey.Elevation = self.length(self.floor_z)
        return storey

    def length(self, metres: float) -> float:
        """A length in the model's declared unit."""
        return float(metres) * self.per_metre

    def area(self, square_metres: float) -> float:
        """An area in the model's declared unit."""
        return float(square_metres) * self.per_square_metre

    def quantities(
        self,
        product: Any,
        name: str,
        lengths: dict[str, float | None],
        areas: dict[str, float | None] | None = None,
    ) -> None:
        """A quantity set on ``product`` from SI values (metres, m²), converted to the model's
        units; a value of None (not measured) is left out."""
        values: dict[str, Any] = {k: self.length(v) for k, v in lengths.items() if v is not None}
        values.update({k: self.area(v) for k, v in (areas or {}).items() if v is not None})
        qto = self.api.pset.add_qto(self.model, product=product, name=name)
        self.api.pset.edit_qto(self.model, qto=qto, properties=values)

    def work(self, points: Any) -> np.ndarray:
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        return p @ self.to_work[:3, :3].T + self.to_work[:3, 3]

    def place(self, product: Any, representation: Any, matrix: np.ndarray) -> None:
        geometry = self.api.geometry
        geometry.assign_representation(self.model, product=product, representation=representation)
        geometry.edit_object_placement(self.model, product=product, matrix=matrix)

    def entity(self, ifc_class: str, name: str) -> Any:
        return self.api.root.create_entity(self.model, ifc_class=ifc_class, name=name)

    def rooms(self) -> None:
        """An IfcSpace per room, extruded from its outline to its ceiling, with its quantities;
        a floor and a ceiling slab under and over it."""
        spaces, slab_depth = [], self.params.slab_thickness
        add_slab = self.api.geometry.add_slab_representation
        for room in self.layout.rooms:
            outline = [(float(x), float(y)) for x, y in room.footprint]
            height = room.ceiling_height or DEFAULT_ROOM_HEIGHT
            space = self.entity("IfcSpace", room.name)
            rep = add_slab(self.model, context=self.body, depth=height, polyline=outline)
            self.place(
                space, rep, placement(np.array([0.0, 0.0, self.floor_z]), np.array([1.0, 0.0]))
            )
            self.space_sets(space, room)
            spaces.append(space)
            for which, z in (
                ("floor", self.floor_z - slab_depth),
                ("ceiling", self.floor_z + height),
            ):
                slab = self.entity("IfcSlab", f"{room.name} {which}")
                slab.PredefinedType = "FLOOR" if which == "floor" else "ROOF"
                rep = add_slab(self.model, context=self.body, depth=slab_depth, polyline=outline)
                self.place(slab, rep, placement(np.array([0.0, 0.0, z]), np.array([1.0, 0.0])))
                self.contained.append(slab)
        if spaces:
            self.api.aggregate.assign_object(
                self.model, products=spaces, relating_object=self.storey
            )

    def space_sets(self, space: Any, room: RoomRecord) -> None:
        """``Pset_SpaceCommon`` (its kind as Reference, interior) and
        ``Qto_SpaceBaseQuantities`` (floor area, perimeter, and heights where the ceiling
        was found) from the room's record."""
        pset = self.api.pset.add_pset(self.model, product=space, name="Pset_SpaceCommon")
        self.api.pset.edit_pset(
            self.model, pset=pset, properties={"Reference": room.kind, "IsExternal": False}
        )
        self.quantities(
            space,
            "Qto_SpaceBaseQuantities",
            {
                "Height": room.ceiling_height,
                "FinishCeilingHeight": room.ceiling_height,
                "GrossPerimeter": footprint_perimeter(room.footprint),
            },
            {
                "NetFloorArea": footprint_area(room.footprint),
                "GrossFloorArea": footprint_area(room.footprint),
            },
        )

    def walls(self) -> None:
        """An IfcWall per wall (one for both faces of a wall seen from two rooms), of its
        measured or declared thickness (:mod:`jointseg.objects.ifc_walls`)."""
        self.written = write_walls(self)

    def wall_quantities(self) -> None:
        """``Qto_WallBaseQuantities`` of each wall written, from its first face's record: the
        net side area is the gross less the openings really cut in it."""
        for wall in self.layout.walls:
            body = self.written.get(wall.id)
            if body is None or body.records[0] != wall.id:
                continue
            self.quantities(
                body.entity,
                "Qto_WallBaseQuantities",
                {"Length": wall.length, "Height": wall.height, "Width": wall.thickness},
                {
                    "GrossSideArea": wall.area,
                    "NetSideArea": round(max(wall.area - body.opened, 0.0), 3),
                },
            )

    def objects(self) -> None:
        """Doors and windows in the openings they fill; furniture and proxies as boxes of
        their room-aligned size. A door or window in no wall, or of no door's or window's
        size, is a proxy named as set aside (the layout's ``set_aside`` says why)."""
        hosted = {
            o.object: (wall, o)
            for wall in self.layout.walls
            if wall.id in self.written
            for o in wall.openings
        }
        for obj in self.layout.objects:
            ifc_class = {"door": "IfcDoor", "window": "IfcWindow"}.get(obj.cls)
            if ifc_class is None:
                ifc_class = "IfcFurniture" if obj.cls in FURNITURE else "IfcBuildingElementProxy"
            name = f"{obj.cls} {obj.id}"
            if obj.id in hosted:  # fills an opening of its kind's size (a fragment may)
                pass
            elif not obj.plausible:  # a fragment: not a door, a window or furniture
                ifc_class, name = "IfcBuildingElementProxy", f"{obj.cls} fragment {obj.id}"
            elif ifc_class in ("IfcDoor", "IfcWindow"):
                ifc_class, name = "IfcBuildingElementProxy", f"{obj.cls} set aside {obj.id}"
            entity = self.entity(ifc_class, name)
            if ifc_class in ("IfcDoor", "IfcWindow"):
                face, opening = hosted[obj.id]
                self.opening_sizes(entity, opening)
                element_type(self, entity, self.element_types)
                write_opening(self, self.written[face.id], face, opening, entity)
            else:
                self.box(entity, obj)
            self.contained.append(entity)

    def box(self, entity: Any, obj: ObjectRecord) -> None:
        """The body of an object that fills no opening: its room-aligned box."""
        corners = self.work(obj.box)
        x_axis, y_axis = corners[1] - corners[0], corners[3] - corners[0]
        sx, sy = float(np.hypot(*x_axis[:2])), float(np.hypot(*y_axis[:2]))
        sz = float(corners[4, 2] - corners[0, 2])
        # a box: a "wall" profile of the object's length, depth and height
        rep = self.api.geometry.add_wall_representation(
            self.model, context=self.body, length=max(sx, 0.01), height=max(sz, 0.01),
            thickness=max(sy, 0.01),
        )  # fmt: skip
        direction = x_axis if sx > 1e-6 else np.array([1.0, 0.0])
        # the profile runs from its axis to the left of it (local +y): start on the box's
        # side that keeps the box there
        left = np.array([-direction[1], direction[0]])
        origin = corners[0] if float(y_axis[:2] @ left) >= 0 else corners[3]
        self.place(entity, rep, placement(origin, direction))

    def opening_sizes(self, entity: Any, opening: OpeningRecord) -> None:
        """A door's or window's OverallWidth/OverallHeight and base quantities: the opening it
        fills in its wall (the size the wall's net area lost)."""
        width, height = opening.width, opening.height
        entity.OverallWidth, entity.OverallHeight = self.length(width), self.length(height)
        name = "Qto_DoorBaseQuantities" if entity.is_a("IfcDoor") else "Qto_WindowBaseQuantities"
        self.quantities(entity, name, {"Width": width, "Height": height}, {"Area": width * height})

    def contain(self) -> None:
        if self.contained:
            self.api.spatial.assign_container(
                self.model, products=self.contained, relating_structure=self.storey
            )


def footprint_perimeter(footprint: list[tuple[float, float]]) -> float:
    """The length of a closed outline (its last corner joined back to its first), metres."""
    xy = np.asarray(footprint, dtype=np.float64).reshape(-1, 2)
    if len(xy) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(np.vstack([xy, xy[:1]]), axis=0), axis=1).sum())


def footprint_area(footprint: list[tuple[float, float]]) -> float:
    """The area inside a closed outline (the shoelace formula), m²."""
    xy = np.asarray(footprint, dtype=np.float64).reshape(-1, 2)
    if len(xy) < 3:
        return 0.0
    x, y = xy[:, 0], xy[:, 1]
    return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2.0)


def write_ifc(
    layout: LayoutReport, path: Path, params: ObjectParams | None = None, *, name: str = "scan"
) -> dict[str, int]:
    """Write the model to ``path`` (atomically) after IfcOpenShell's validator passed it;
    return the count of each entity class written.

    Raises
    ------
    ConfigError
        When the validator finds an error (nothing is written then).
    """
    model = build_model(layout, params, name=name)
    errors = validation_errors(model)
    if errors:
        raise ConfigError(f"the IFC model does not validate: {errors[0]}")
    from jointseg.io.atomic import atomic_open

    with atomic_open(path) as fh:
        fh.write(model.to_string().encode())
    return entity_counts(model)


def validation_errors(model: Any) -> list[str]:
    """What IfcOpenShell's own validator finds wrong with ``model`` (empty: valid)."""
    import ifcopenshell.validate

    logger = ifcopenshell.validate.json_logger()
    ifcopenshell.validate.validate(model, logger, express_rules=True)
    return [str(s.get("message", s)) for s in logger.statements if s.get("level") == "ERROR"]


def entity_counts(model: Any) -> dict[str, int]:
    """Entities per class of interest in an IFC model."""
    kinds = ("IfcSpace", "IfcWall", "IfcSlab", "IfcDoor", "IfcWindow", "IfcOpeningElement",
             "IfcFurniture", "IfcBuildingElementProxy")  # fmt: skip
    return {k: len(model.by_type(k)) for k in kinds}
