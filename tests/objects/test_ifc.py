"""The IFC model read back the way a BIM tool reads it: every length in the model's declared
unit, and the quantity sets holding the values ``objects.json`` holds.

The room is synthetic (``make_room(12)``: an L-shaped room with two doors and two windows),
handed over as a scan in millimetres, turned 30° and its floor 3.2 m up, so a length written in
the scan's units or in metres instead of the model's unit is off by a factor of 1000."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from jointseg.cli.objects_command import write_layout
from jointseg.objects.layout import find_layout
from jointseg.spacing import estimate_spacing
from jointseg.synth import make_room

ifcopenshell = pytest.importorskip("ifcopenshell")
from ifcopenshell.util.element import get_psets  # noqa: E402
from ifcopenshell.util.placement import get_local_placement  # noqa: E402
from ifcopenshell.util.unit import calculate_unit_scale  # noqa: E402

FLOOR_Z = 3.2
TIGHT = 1e-9  # metres: the records are written as they are, only the unit changes


def _to_user() -> np.ndarray:
    """Work frame (metres) to a user frame in millimetres, turned 30° and shifted."""
    turn = np.radians(30.0)
    m = np.eye(4)
    m[:2, :2] = [[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]]
    m[:3, :3] *= 1000.0
    m[:3, 3] = (125_000.0, -48_000.0, 50.0)
    return m


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Any]:
    """(objects.json, the IFC model read back) as ``jointseg objects`` writes them."""
    scan = make_room(12, points=200_000, shape="L")
    xyz = scan.xyz + np.array([0.0, 0.0, FLOOR_Z])
    assert scan.labels is not None
    layout = find_layout(xyz, scan.labels, None, estimate_spacing(xyz), to_user=_to_user())
    folder = tmp_path_factory.mktemp("ifc")
    write_layout(layout.report, folder / "objects.json", folder / "model.ifc", "synth12")
    body = json.loads((folder / "objects.json").read_text())
    return body, ifcopenshell.open(str(folder / "model.ifc"))


def _metres(model: Any) -> float:
    return float(calculate_unit_scale(model, "LENGTHUNIT"))


def _square_metres(model: Any) -> float:
    return float(calculate_unit_scale(model, "AREAUNIT"))


def _work(body: dict[str, Any], points: Any) -> np.ndarray:
    """User coordinates of ``objects.json`` back in the work frame (the model's frame)."""
    to_work = np.linalg.inv(np.asarray(body["to_user"]))
    return np.asarray(points, dtype=np.float64) @ to_work[:3, :3].T + to_work[:3, 3]


def _by_name(model: Any, ifc_class: str) -> dict[str, Any]:
    return {e.Name: e for e in model.by_type(ifc_class)}


def _qto(entity: Any, name: str, model: Any) -> dict[str, float]:
    """A quantity set in SI units: lengths in metres, areas in m²."""
    qto = get_psets(entity, qtos_only=True)[name]
    areas = {q.Name for q in model.by_type("IfcQuantityArea")}
    return {
        k: v * (_square_metres(model) if k in areas else _metres(model))
        for k, v in qto.items()
        if k != "id"
    }


@pytest.mark.slow
def test_the_model_declares_millimetres_and_square_metres_and_validates(run) -> None:
    from jointseg.objects.ifc import validation_errors

    body, model = run
    assert _metres(model) == 0.001 and _square_metres(model) == 1.0
    assert validation_errors(model) == []
    assert body["floor_z"] == pytest.approx(FLOOR_Z, abs=0.02)
    assert len(body["rooms"]) == 1 and body["walls"]


def test_doors_and_windows_are_as_wide_and_high_as_their_openings(run) -> None:
    """OverallWidth/OverallHeight and the base quantities in the model's unit: a 0.84 m door
    reads 0.84 m, not 0.84 mm."""
    body, model = run
    openings = {o["object"]: o for w in body["walls"] for o in w["openings"]}
    boxes = {o["id"]: o for o in body["objects"]}
    found = 0
    for cls, ifc_class in (("door", "IfcDoor"), ("window", "IfcWindow")):
        for name, entity in _by_name(model, ifc_class).items():
            obj = boxes[int(name.split()[-1])]
            assert obj["cls"] == cls
            record = openings.get(obj["id"])
            if record is None:  # not in a wall: its box
                width, height = max(obj["size"][:2]), obj["size"][2]
            else:
                width, height = record["width"], record["height"]
                found += 1
            assert entity.OverallWidth * _metres(model) == pytest.approx(width, abs=TIGHT)
            assert entity.OverallHeight * _metres(model) == pytest.approx(height, abs=TIGHT)
            qto = _qto(entity, f"Qto_{ifc_class[3:]}BaseQuantities", model)
            assert qto == pytest.approx(
                {"Width": width, "Height": height, "Area": width * height}, abs=TIGHT
            )
            assert 0.5 < width < 2.0 and 0.5 < height < 2.5  # metres, as a door or window is
    assert found == 4  # the two doors and two windows all stand in walls


def test_spaces_carry_their_rooms_quantities_and_common_properties(run) -> None:
    body, model = run
    spaces = _by_name(model, "IfcSpace")
    assert set(spaces) == {r["name"] for r in body["rooms"]}
    for room in body["rooms"]:
        space = spaces[room["name"]]
        common = get_psets(space, psets_only=True)["Pset_SpaceCommon"]
        assert common["IsExternal"] is False and common["Reference"] == room["kind"]
        xy = np.asarray(room["footprint"])
        perimeter = float(np.hypot(*(np.roll(xy, -1, axis=0) - xy).T).sum())
        x, y = xy[:, 0], xy[:, 1]
        area = abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2
        assert area == pytest.approx(room["floor_area"], rel=0.01)
        assert _qto(space, "Qto_SpaceBaseQuantities", model) == pytest.approx(
            {
                "NetFloorArea": area,
                "GrossFloorArea": area,
                "Height": room["ceiling_height"],
                "FinishCeilingHeight": room["ceiling_height"],
                "GrossPerimeter": perimeter,
            },
            abs=TIGHT,
        )


def test_walls_carry_their_length_height_width_and_areas(run) -> None:
    body, model = run
    walls = _by_name(model, "IfcWall")
    assert len(walls) == len(body["walls"])  # one room: no wall seen from both sides
    for wall in body["walls"]:
        qto = _qto(walls[f"Wall {wall['id'] + 1}"], "Qto_WallBaseQuantities", model)
        assert wall["thickness"] == body["wall_thickness"] == 0.2
        assert not wall["thickness_measured"]
        assert qto == pytest.approx(
            {
                "Length": wall["length"],
                "Height": wall["height"],
                "Width": wall["thickness"],
                "GrossSideArea": wall["area"],
                "NetSideArea": wall["net_area"],
            },
            abs=TIGHT,
        )
    assert any(w["net_area"] < w["area"] for w in body["walls"])  # openings were taken off


def test_the_storey_stands_at_the_floors_level(run) -> None:
    body, model = run
    (storey,) = model.by_type("IfcBuildingStorey")
    assert storey.Elevation * _metres(model) == pytest.approx(body["floor_z"], abs=TIGHT)
    z = get_local_placement(storey.ObjectPlacement)[2, 3] * _metres(model)
    assert z == pytest.approx(body["floor_z"], abs=TIGHT)


def _extent(model: Any, entity: Any) -> tuple[np.ndarray, np.ndarray]:
    """The world bounding box of an entity's body, in metres (IfcOpenShell's geometry kernel
    reads the placements, extrusions and profiles in the declared unit and answers in SI)."""
    import ifcopenshell.geom

    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    shape: Any = ifcopenshell.geom.create_shape(settings, entity)
    verts = np.asarray(shape.geometry.verts)
    verts = verts.reshape(-1, 3)
    return verts.min(axis=0), verts.max(axis=0)


def test_every_body_stands_where_the_records_say_in_metres(run) -> None:
    """Placements, extrusion depths and profiles of spaces, slabs, walls and objects, read
    back through the geometry kernel, match the records to a millimetre."""
    body, model = run
    floor = body["floor_z"]
    for room in body["rooms"]:
        lo, hi = _extent(model, _by_name(model, "IfcSpace")[room["name"]])
        xy = np.asarray(room["footprint"])
        np.testing.assert_allclose(lo, [*xy.min(axis=0), floor], atol=1e-3)
        np.testing.assert_allclose(hi, [*xy.max(axis=0), floor + room["ceiling_height"]], atol=1e-3)
        slabs = _by_name(model, "IfcSlab")
        lo, hi = _extent(model, slabs[f"{room['name']} floor"])
        assert (lo[2], hi[2]) == pytest.approx((floor - 0.2, floor), abs=1e-3)
        lo, hi = _extent(model, slabs[f"{room['name']} ceiling"])
        top = floor + room["ceiling_height"]
        assert (lo[2], hi[2]) == pytest.approx((top, top + 0.2), abs=1e-3)
    for wall in body["walls"]:
        corners = _work(body, wall["corners"])
        lo, hi = _extent(model, _by_name(model, "IfcWall")[f"Wall {wall['id'] + 1}"])
        assert (lo[2], hi[2]) == pytest.approx((corners[:, 2].min(), corners[:, 2].max()), abs=1e-3)
        axis = (corners[1] - corners[0])[:2] / wall["length"]
        reach = np.array([[lo[0], lo[1]], [hi[0], hi[1]]]) - corners[0, :2]
        # the face, its body running on into the walls it meets, and its thickness
        longest = wall["length"] + sum(wall["extends"]) + wall["thickness"]
        assert np.abs(reach @ axis).max() <= longest + 1e-3
        assert np.hypot(*(hi - lo)[:2]) >= wall["length"] - 1e-3
    elements = _by_name(model, "IfcElement")
    hosted = {o["object"] for w in body["walls"] for o in w["openings"]}
    for obj in body["objects"]:
        if obj["id"] in hosted:
            continue  # fills its opening: tests/objects/test_ifc_bim.py
        kind = obj["cls"] if obj["plausible"] else f"{obj['cls']} fragment"
        if obj["plausible"] and obj["cls"] in ("door", "window"):
            kind = f"{obj['cls']} set aside"
        entity = elements[f"{kind} {obj['id']}"]
        box = _work(body, obj["box"])
        lo, hi = _extent(model, entity)
        np.testing.assert_allclose(lo, box.min(axis=0), atol=1e-3)
        np.testing.assert_allclose(
            hi, np.maximum(box.max(axis=0), box.min(axis=0) + 0.01), atol=1e-3
        )


def test_no_quantity_or_size_is_left_in_metres(run) -> None:
    """Every length quantity, door and window size and extrusion of the model, converted to
    metres, is of a room's scale: one written in metres would read as millimetres."""
    _, model = run
    metres = _metres(model)
    lengths = [q.LengthValue for q in model.by_type("IfcQuantityLength")]
    lengths += [e.OverallWidth for e in model.by_type("IfcDoor") + model.by_type("IfcWindow")]
    lengths += [e.OverallHeight for e in model.by_type("IfcDoor") + model.by_type("IfcWindow")]
    lengths += [s.Depth for s in model.by_type("IfcExtrudedAreaSolid")]
    assert lengths and all(0.005 <= v * metres <= 60.0 for v in lengths), sorted(lengths)[:3]
    areas = [q.AreaValue * _square_metres(model) for q in model.by_type("IfcQuantityArea")]
    assert areas and all(0.05 <= a <= 500.0 for a in areas), sorted(areas)[:3]
