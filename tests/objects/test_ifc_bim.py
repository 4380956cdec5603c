"""The IFC model as a BIM engineer opens it (issue 67): doors and windows fill openings cut in
their walls, only door- and window-sized ones are modelled, walls have a measured or declared
thickness, reach the ceiling and meet at the corners, and the quantities agree with the
geometry written.

The scan is a synthetic floor (``make_floor(3, rooms=3)``): three rooms and a corridor, walls
0.20 m thick and 2.84 m high, doors in the corridor's walls, windows in the outer walls; the
rooms on both sides of an inner wall are scanned, so its two faces are seen."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from jointseg.cli.objects_command import write_layout
from jointseg.objects.ifc import validation_errors
from jointseg.objects.layout import find_layout
from jointseg.objects.openings import opening_problem
from jointseg.objects.records import OpeningRecord
from jointseg.spacing import estimate_spacing
from jointseg.synth import make_room
from jointseg.synth.floor import floor_layout, make_floor

ifcopenshell = pytest.importorskip("ifcopenshell")
geom = pytest.importorskip("ifcopenshell.geom")
from ifcopenshell.util.element import get_material, get_psets, get_type  # noqa: E402
from ifcopenshell.util.unit import calculate_unit_scale  # noqa: E402

SEED = 3


@pytest.fixture(scope="module")
def floor(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Any]:
    """(objects.json, the IFC model read back) of the synthetic floor."""
    scan = make_floor(SEED, rooms=3, points=400_000)
    assert scan.labels is not None
    layout = find_layout(scan.xyz, scan.labels, None, estimate_spacing(scan.xyz))
    folder = tmp_path_factory.mktemp("bim")
    write_layout(layout.report, folder / "objects.json", folder / "model.ifc", "floor")
    body = json.loads((folder / "objects.json").read_text())
    return body, ifcopenshell.open(str(folder / "model.ifc"))


def _metres(model: Any) -> float:
    return float(calculate_unit_scale(model, "LENGTHUNIT"))


def _extent(entity: Any, *, world: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The box of an entity's body in metres: in the world, or in its own placement's axes."""
    settings = geom.settings()
    settings.set("use-world-coords", world)
    verts = np.asarray(geom.create_shape(settings, entity).geometry.verts)
    verts = verts.reshape(-1, 3)
    return verts.min(axis=0), verts.max(axis=0)


def _qto(entity: Any, name: str) -> dict[str, float]:
    return get_psets(entity, qtos_only=True)[name]


def test_every_door_and_window_fills_an_opening_that_voids_its_wall(floor) -> None:
    body, model = floor
    fillings = model.by_type("IfcDoor") + model.by_type("IfcWindow")
    assert len(model.by_type("IfcDoor")) >= 2 and len(model.by_type("IfcWindow")) >= 2
    assert len(model.by_type("IfcOpeningElement")) == len(fillings)
    metres = _metres(model)
    for element in fillings:
        (fills,) = element.FillsVoids
        opening = fills.RelatingOpeningElement
        (voids,) = opening.VoidsElements
        wall = voids.RelatingBuildingElement
        assert wall.is_a("IfcWall")
        # the opening's body (in its own axes: along the wall, across it, up) is the
        # element's size, and goes through the wall
        size = np.subtract(*_extent(opening, world=False)[::-1])
        width, height = element.OverallWidth * metres, element.OverallHeight * metres
        assert size[0] == pytest.approx(width, abs=1e-3)
        assert size[2] == pytest.approx(height, abs=1e-3)
        thickness = _qto(wall, "Qto_WallBaseQuantities")["Width"] * metres
        assert size[1] > thickness  # cut through both faces
        lo, hi = _extent(opening)
        wall_lo, wall_hi = _extent(wall)
        assert np.all(lo[:2] >= wall_lo[:2] - 0.1) and np.all(hi[:2] <= wall_hi[:2] + 0.1)
        assert lo[2] >= wall_lo[2] - 1e-6 and hi[2] <= wall_hi[2] + 0.05
        # the element stands in its opening (its casing may lie on the wall's faces)
        e_lo, e_hi = _extent(element)
        assert np.all(e_lo >= lo - 0.08) and np.all(e_hi <= hi + 0.08)


def test_doors_and_windows_have_their_type_and_operation(floor) -> None:
    _, model = floor
    for door in model.by_type("IfcDoor"):
        kind = get_type(door)
        assert kind is not None and kind.is_a("IfcDoorType")
        assert kind.PredefinedType == "DOOR" and kind.OperationType == "SINGLE_SWING_LEFT"
        # a panel and lining body, not a box: several solids
        (rep,) = [
            r for r in door.Representation.Representations if r.RepresentationIdentifier == "Body"
        ]
        assert len(rep.Items) >= 2
    for window in model.by_type("IfcWindow"):
        kind = get_type(window)
        assert kind is not None and kind.is_a("IfcWindowType")
        assert kind.PartitioningType == "SINGLE_PANEL"


def test_doors_are_door_sized(floor) -> None:
    _, model = floor
    metres = _metres(model)
    for door in model.by_type("IfcDoor"):
        width, height = door.OverallWidth * metres, door.OverallHeight * metres
        assert 0.6 <= width <= 1.8 and 1.8 <= height <= 2.6 and width < height


@pytest.mark.parametrize(
    ("kind", "width", "height", "sill", "reason"),
    [
        ("door", 2.05, 1.71, 0.0, "wider"),
        ("door", 0.61, 0.13, 0.0, "wider"),
        ("door", 0.9, 1.61, 0.0, "1.61 m high"),
        ("door", 1.95, 2.2, 0.0, "1.95 m wide"),
        ("door", 0.5, 2.0, 0.0, "0.50 m wide"),
        ("window", 1.2, 1.4, 0.02, "touches the floor"),
        ("window", 1.2, 2.0, 1.0, "above its wall"),
        ("window", 0.1, 1.0, 1.0, "too small"),
    ],
)
def test_a_door_or_window_of_no_such_size_is_set_aside_with_its_reason(
    kind: str, width: float, height: float, sill: float, reason: str
) -> None:
    problem = opening_problem(
        OpeningRecord(object=1, kind=kind, width=width, height=height, sill=sill), 2.8
    )
    assert problem is not None and reason in problem


@pytest.mark.parametrize(
    ("kind", "width", "height", "sill"),
    [("door", 0.9, 2.05, 0.0), ("door", 1.6, 2.1, 0.0), ("window", 1.5, 1.2, 0.9)],
)
def test_doors_and_windows_of_their_size_are_kept(
    kind: str, width: float, height: float, sill: float
) -> None:
    assert (
        opening_problem(
            OpeningRecord(object=1, kind=kind, width=width, height=height, sill=sill), 2.8
        )
        is None
    )


def test_a_door_cut_short_by_the_scan_is_set_aside_and_written_as_a_proxy(tmp_path) -> None:
    """A room whose door points stop 1.7 m up (a scan that missed its top; ScanNet's door of
    1.71 m): objects.json says why it was left out, and the model holds it as a proxy, with
    no opening for it."""
    scan = make_room(12, points=200_000, shape="L")
    assert scan.labels is not None
    z = scan.xyz[:, 2]
    keep = ~((scan.labels == 6) & (z > np.quantile(z, 0.02) + 1.7))
    xyz, labels = scan.xyz[keep], scan.labels[keep]
    layout = find_layout(xyz, labels, None, estimate_spacing(xyz))
    write_layout(layout.report, tmp_path / "objects.json", tmp_path / "model.ifc", "short")
    body = json.loads((tmp_path / "objects.json").read_text())
    doors = {a["object"]: a["reason"] for a in body["set_aside"] if a["kind"] == "door"}
    assert doors and all("high" in r for r in doors.values()), body["set_aside"]
    model = ifcopenshell.open(str(tmp_path / "model.ifc"))
    assert not model.by_type("IfcDoor")
    proxies = {e.Name for e in model.by_type("IfcBuildingElementProxy")}
    assert {f"door set aside {d}" for d in doors} <= proxies
    assert not any(o["kind"] == "door" for w in body["walls"] for o in w["openings"])


def test_walls_seen_from_both_rooms_have_their_measured_thickness(floor) -> None:
    body, model = floor
    plan = floor_layout(SEED, rooms=3)
    walls = body["walls"]
    pairs = [w for w in walls if w["other_face"] is not None]
    assert len(pairs) >= 4  # the corridor's walls and the wall between the two small rooms
    for w in pairs:
        other = walls[w["other_face"]]
        assert other["other_face"] == w["id"]
        assert w["thickness_measured"] and w["thickness"] == pytest.approx(plan.thickness, abs=0.02)
    single = [w for w in walls if w["other_face"] is None]
    assert single and all(not w["thickness_measured"] for w in single)
    assert all(w["thickness"] == body["wall_thickness"] == 0.2 for w in single)
    # one wall per pair of faces, each with a layer set of its thickness
    assert len(model.by_type("IfcWall")) == len(walls) - len(pairs) // 2
    records = {f"Wall {w['id'] + 1}": w for w in walls}
    for entity in model.by_type("IfcWall"):
        record = records[entity.Name]
        how = "measured" if record["thickness_measured"] else "declared"
        assert how in get_type(entity).Name
        usage = get_material(entity, should_skip_usage=False)
        assert usage is not None and usage.is_a("IfcMaterialLayerSetUsage")
        (layer,) = usage.ForLayerSet.MaterialLayers
        width = _qto(entity, "Qto_WallBaseQuantities")["Width"]
        assert layer.LayerThickness == pytest.approx(width, abs=1e-6)


def test_walls_reach_the_ceiling_of_their_rooms(floor) -> None:
    body, model = floor
    ceilings = {r["id"]: r["ceiling_height"] for r in body["rooms"]}
    walls = {e.Name: e for e in model.by_type("IfcWall")}
    for w in body["walls"]:
        heights = [ceilings[r] for r in w["rooms"] if ceilings.get(r) is not None]
        assert heights, w
        assert w["height"] == pytest.approx(max(heights), abs=0.05)
        if f"Wall {w['id'] + 1}" in walls:
            lo, hi = _extent(walls[f"Wall {w['id'] + 1}"])
            assert hi[2] == pytest.approx(body["floor_z"] + max(heights), abs=0.05)


def test_wall_base_lines_meet_at_the_corners(floor) -> None:
    """The outer walls' faces meet corner to corner, and each inner wall runs to the face it
    abuts: every end of every face is joined, so the model closes."""
    body, model = floor
    walls = body["walls"]
    for w in walls:
        assert None not in w["joined"], w
        for end, other in enumerate(w["joined"]):
            them = np.asarray(walls[other]["corners"])[:2, :2]
            mine = np.asarray(w["corners"])[end, :2]
            # the end lies on the other face's base line
            d = them[1] - them[0]
            off = abs(float(np.cross(d / np.linalg.norm(d), mine - them[0])))
            assert off < 0.01, (w["id"], other, off)
    links = model.by_type("IfcRelConnectsPathElements")
    assert len(links) >= 4


def test_net_side_areas_are_gross_less_the_openings_cut_in_each_wall(floor) -> None:
    _, model = floor
    metres = _metres(model)
    area = float(calculate_unit_scale(model, "AREAUNIT"))
    cut = 0
    for wall in model.by_type("IfcWall"):
        qto = _qto(wall, "Qto_WallBaseQuantities")
        openings = [rel.RelatedOpeningElement for rel in wall.HasOpenings]
        taken = 0.0
        for opening in openings:
            (fill,) = opening.HasFillings
            element = fill.RelatedBuildingElement
            taken += element.OverallWidth * element.OverallHeight * metres**2
        cut += len(openings)
        gross, net = qto["GrossSideArea"] * area, qto["NetSideArea"] * area
        assert net == pytest.approx(gross - taken, rel=0.01, abs=0.01)
    assert cut >= 4


def test_spaces_take_area_and_perimeter_from_their_outline(floor) -> None:
    body, model = floor
    spaces = {s.Name: s for s in model.by_type("IfcSpace")}
    for room in body["rooms"]:
        xy = np.asarray(room["footprint"])
        x, y = xy[:, 0], xy[:, 1]
        area = abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2
        perimeter = float(np.hypot(*(np.roll(xy, -1, axis=0) - xy).T).sum())
        qto = _qto(spaces[room["name"]], "Qto_SpaceBaseQuantities")
        assert qto["NetFloorArea"] == pytest.approx(area, rel=1e-9)
        assert qto["GrossPerimeter"] * _metres(model) == pytest.approx(perimeter, rel=1e-9)


def test_the_model_passes_the_validator_with_its_rules(floor) -> None:
    _, model = floor
    assert validation_errors(model) == []
