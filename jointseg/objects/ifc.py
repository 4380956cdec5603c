"""An IFC4 model of a segmented scan, written with IfcOpenShell (a BIM library, not hand-made
STEP): IfcProject > IfcSite > IfcBuilding > IfcBuildingStorey, an IfcSpace per room, IfcWall
per wall plane, IfcSlab for each room's floor and ceiling, IfcDoor and IfcWindow from their
objects, IfcFurniture for tables, chairs, sofas and bookcases, IfcBuildingElementProxy for the
rest.

The model is in the levelled metric frame (z up, metres), as IFC expects, whatever the scan's
own axes and units; the layout's user coordinates are mapped back through ``to_user``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.objects.params import ObjectParams
from jointseg.objects.records import LayoutReport

log = logging.getLogger(__name__)

FURNITURE = {"table", "chair", "sofa", "bookcase"}


def _placement(origin: np.ndarray, x_axis: np.ndarray) -> np.ndarray:
    """A 4x4 placement at ``origin`` with its x along ``x_axis`` (horizontal) and z up."""
    x = np.array([x_axis[0], x_axis[1], 0.0])
    x /= max(float(np.linalg.norm(x)), 1e-12)
    z = np.array([0.0, 0.0, 1.0])
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, np.cross(z, x), z, origin
    return m


def build_model(
    layout: LayoutReport, params: ObjectParams | None = None, *, name: str = "scan"
) -> Any:
    """The IFC4 model (an ``ifcopenshell.file``) of ``layout``."""
    params = params or ObjectParams()
    writer = _Writer(layout, params, name)
    writer.rooms()
    writer.walls()
    writer.objects()
    writer.contain()
    return writer.model


class _Writer:
    """One model being built: the spatial tree, the body context, and what goes in the storey."""

    def __init__(self, layout: LayoutReport, params: ObjectParams, name: str) -> None:
        import ifcopenshell.api
        import ifcopenshell.api.aggregate
        import ifcopenshell.api.context
        import ifcopenshell.api.geometry
        import ifcopenshell.api.project
        import ifcopenshell.api.root
        import ifcopenshell.api.spatial
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
        site = api.root.create_entity(model, ifc_class="IfcSite", name="Site")
        building = api.root.create_entity(model, ifc_class="IfcBuilding", name="Building")
        self.storey = api.root.create_entity(
            model, ifc_class="IfcBuildingStorey", name="Scanned storey"
        )
        api.aggregate.assign_object(model, products=[site], relating_object=project)
        api.aggregate.assign_object(model, products=[building], relating_object=site)
        api.aggregate.assign_object(model, products=[self.storey], relating_object=building)
        self.contained: list[Any] = []

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
        """An IfcSpace per room, extruded from its outline to its ceiling; a floor and a
        ceiling slab under and over it."""
        spaces, slab_depth = [], self.params.slab_thickness
        add_slab = self.api.geometry.add_slab_representation
        for room in self.layout.rooms:
            outline = [(float(x), float(y)) for x, y in room.footprint]
            height = room.ceiling_height or 2.5
            space = self.entity("IfcSpace", room.name)
            rep = add_slab(self.model, context=self.body, depth=height, polyline=outline)
            self.place(space, rep, _placement(np.array([0.0, 0.0, self.floor_z]), np.ones(2)))
            spaces.append(space)
            for which, z in (
                ("floor", self.floor_z - slab_depth),
                ("ceiling", self.floor_z + height),
            ):
                slab = self.entity("IfcSlab", f"{room.name} {which}")
                slab.PredefinedType = "FLOOR" if which == "floor" else "ROOF"
                rep = add_slab(self.model, context=self.body, depth=slab_depth, polyline=outline)
                self.place(slab, rep, _placement(np.array([0.0, 0.0, z]), np.array([1.0, 0.0])))
                self.contained.append(slab)
        if spaces:
            self.api.aggregate.assign_object(
                self.model, products=spaces, relating_object=self.storey
            )

    def walls(self) -> None:
        """An IfcWall per wall plane, of the default thickness."""
        for wall in self.layout.walls:
            c = self.work(wall.corners)
            axis = c[1] - c[0]
            entity = self.entity("IfcWall", f"Wall {wall.id + 1}")
            rep = self.api.geometry.add_wall_representation(
                self.model, context=self.body, length=float(np.hypot(axis[0], axis[1])),
                height=float(wall.height), thickness=self.params.wall_thickness,
            )  # fmt: skip
            self.place(entity, rep, _placement(c[0], axis))
            self.contained.append(entity)

    def objects(self) -> None:
        """Doors, windows, furniture and proxies as boxes of their room-aligned size."""
        for obj in self.layout.objects:
            corners = self.work(obj.box)
            x_axis, y_axis = corners[1] - corners[0], corners[3] - corners[0]
            sx, sy = float(np.hypot(*x_axis[:2])), float(np.hypot(*y_axis[:2]))
            sz = float(corners[4, 2] - corners[0, 2])
            ifc_class = {"door": "IfcDoor", "window": "IfcWindow"}.get(obj.cls)
            if ifc_class is None:
                ifc_class = "IfcFurniture" if obj.cls in FURNITURE else "IfcBuildingElementProxy"
            name = f"{obj.cls} {obj.id}"
            if not obj.plausible:  # a fragment: not a door, a window or furniture
                ifc_class, name = "IfcBuildingElementProxy", f"{obj.cls} fragment {obj.id}"
            entity = self.entity(ifc_class, name)
            if ifc_class in ("IfcDoor", "IfcWindow"):
                entity.OverallWidth, entity.OverallHeight = max(sx, sy), sz
            # a box: a "wall" profile of the object's length, depth and height
            rep = self.api.geometry.add_wall_representation(
                self.model, context=self.body, length=max(sx, 0.01), height=max(sz, 0.01),
                thickness=max(sy, 0.01),
            )  # fmt: skip
            origin = corners[0] + 0.5 * y_axis  # the wall profile is centred on its axis
            direction = x_axis if sx > 1e-6 else np.array([1.0, 0.0])
            self.place(entity, rep, _placement(origin, direction))
            self.contained.append(entity)

    def contain(self) -> None:
        if self.contained:
            self.api.spatial.assign_container(
                self.model, products=self.contained, relating_structure=self.storey
            )


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
    ifcopenshell.validate.validate(model, logger)
    return [str(s.get("message", s)) for s in logger.statements if s.get("level") == "ERROR"]


def entity_counts(model: Any) -> dict[str, int]:
    """Entities per class of interest in an IFC model."""
    kinds = ("IfcSpace", "IfcWall", "IfcSlab", "IfcDoor", "IfcWindow", "IfcFurniture",
             "IfcBuildingElementProxy")  # fmt: skip
    return {k: len(model.by_type(k)) for k in kinds}
