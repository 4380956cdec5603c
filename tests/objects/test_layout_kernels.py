"""The objects stage's vectorised steps give what the per-object and per-room loops they
replaced give, bit for bit: object ids, object records, cell counts, rooms under points,
ceiling heights, room outlines, and the records measured again after a door's pieces join."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.geometry.alignment import rotation_z
from jointseg.grouping import rows_by_id
from jointseg.objects import instances as inst
from jointseg.objects import layout, outline, rooms
from jointseg.objects.params import THING_CLASSES, ObjectParams
from jointseg.objects.records import ObjectRecord, user_coords, vec
from jointseg.objects.shapes import fits_class
from jointseg.spacing import estimate_spacing
from jointseg.synth import make_room


def reference_instances(xyz: np.ndarray, labels: np.ndarray, spacing: float) -> np.ndarray:
    """Object ids as first written: np.unique of the cell keys, ufunc.at boxes, a loop of
    parts over objects."""
    params = ObjectParams()
    out = np.full(len(xyz), -1, dtype=np.int64)
    size = max(params.contact * spacing, params.min_contact)
    next_id = 0
    for cls in THING_CLASSES:
        members = np.flatnonzero(labels == cls)
        if members.size < params.min_points:
            continue
        cell = np.floor(xyz[members] / size).astype(np.int64)
        cell -= cell.min(axis=0)
        dims = cell.max(axis=0) + 1
        key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
        _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        comp = reference_components(cell[first])[inverse.reshape(-1)]
        comp = reference_join(xyz[members], comp)
        counts = np.bincount(comp)
        keep = np.flatnonzero(counts >= params.min_points)
        keep = keep[np.argsort(-counts[keep], kind="stable")]
        new = np.full(counts.size, -1, dtype=np.int64)
        new[keep] = np.arange(next_id, next_id + keep.size)
        out[members] = new[comp]
        next_id += keep.size
    return out


def reference_components(cells: np.ndarray) -> np.ndarray:
    """Touching cells (26-neighbourhood) by brute force over all pairs."""
    touch = np.abs(cells[:, None, :] - cells[None, :, :]).max(axis=2) <= 1
    s, d = np.nonzero(touch)
    graph = coo_matrix((np.ones(len(s), np.int8), (s, d)), shape=(len(cells),) * 2).tocsr()
    return connected_components(graph, directed=False)[1].astype(np.int64)


def reference_join(xyz: np.ndarray, comp: np.ndarray) -> np.ndarray:
    n = int(comp.max()) + 1 if comp.size else 0
    if n < 2:
        return comp
    counts = np.bincount(comp, minlength=n)
    lo = np.full((n, 2), np.inf)
    hi = np.full((n, 2), -np.inf)
    np.minimum.at(lo, comp, xyz[:, :2])
    np.maximum.at(hi, comp, xyz[:, :2])
    target = np.arange(n)
    for small in np.argsort(counts, kind="stable"):
        big = np.flatnonzero(
            (counts * inst.PART_SHARE >= counts[small])
            & np.all(lo - inst.PART_MARGIN <= lo[small], axis=1)
            & np.all(hi + inst.PART_MARGIN >= hi[small], axis=1)
        )
        if big.size:
            target[small] = big[np.argmax(counts[big])]
    for _ in range(4):
        target = target[target]
    return target[comp]


def things(seed: int, n: int = 6000) -> tuple[np.ndarray, np.ndarray]:
    """Clumps of thing-class points (and some structure) with legs under tops and crumbs."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform([0, 0, 0], [6, 5, 2], (25, 3))
    which = rng.integers(0, len(centres), n)
    xyz = centres[which] + rng.normal(0, rng.uniform(0.05, 0.4, len(centres))[which, None], (n, 3))
    labels = np.asarray(THING_CLASSES)[rng.integers(0, 4, len(centres))][which]
    labels[rng.random(n) < 0.05] = rng.integers(0, 3)  # structure: no object
    return np.round(xyz, 3), labels


@pytest.mark.parametrize("seed", range(8))
def test_object_ids_are_the_plain_codes(seed: int) -> None:
    xyz, labels = things(seed)
    for spacing in (0.01, 0.05):
        assert np.array_equal(
            inst.find_instances(xyz, labels, spacing), reference_instances(xyz, labels, spacing)
        )


@pytest.mark.parametrize("seed", range(5))
def test_parts_join_the_objects_the_loop_joins(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 400))
    comp = rng.integers(0, n, 5000)
    comp = np.unique(comp, return_inverse=True)[1].reshape(-1)  # every group present
    xyz = rng.uniform(0, 4, (5000, 3)) * rng.uniform(0.05, 1, (comp.max() + 1, 1))[comp]
    assert np.array_equal(inst._join_parts(xyz, comp), reference_join(xyz, comp))


def test_rows_by_group_are_rows_by_id() -> None:
    rng = np.random.default_rng(1)
    for high in (1, 40, 70_000):
        ids = rng.integers(-3, high, 20_000)
        got, expected = inst.rows_by_group(ids), rows_by_id(ids)
        assert len(got) == len(expected)
        assert all(np.array_equal(a, b) for a, b in zip(got, expected, strict=True))
    assert inst.rows_by_group(np.full(5, -1)) == []


def reference_objects(xyz, labels, conf, instances, matrix, yaw, floor_z, grid):
    """The object records as first written: one object at a time."""
    out = []
    helper = grid or rooms.RoomGrid(np.zeros((0, 0), np.int64), np.zeros(2), 1.0, yaw)
    for rows in rows_by_id(instances):
        p = xyz[rows]
        plan = helper.plan_xy(p)
        lo = np.r_[plan.min(axis=0), p[:, 2].min()]
        hi = np.r_[plan.max(axis=0), p[:, 2].max()]
        corners_plan = np.array(
            [[x, y, z] for z in (lo[2], hi[2]) for x, y in
             ((lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1]))]
        )  # fmt: skip
        corners = np.c_[helper.work_xy(corners_plan[:, :2]), corners_plan[:, 2]]
        cls = int(np.bincount(labels[rows], minlength=NUM_CLASSES).argmax())
        centroid = p.mean(axis=0)
        room = None
        if grid is not None and grid.labels.size:
            r = int(grid.room_of(centroid[None])[0])
            room = r if r >= 0 else None
        out.append(
            ObjectRecord(
                id=int(instances[rows[0]]),
                cls=CLASS_NAMES[cls],
                points=int(rows.size),
                confidence=round(float(conf[rows].mean()), 4),
                centroid=vec(user_coords(matrix, centroid)),
                box=[vec(c) for c in user_coords(matrix, corners)],
                size=vec(hi - lo),
                height_above_floor=round(float(lo[2] - (floor_z or 0.0)), 4),
                room=room,
                plausible=floor_z is None
                or fits_class(CLASS_NAMES[cls], vec(hi - lo), float(lo[2] - floor_z)),
            )
        )
    return out


@pytest.mark.parametrize("seed", range(4))
def test_object_records_are_the_per_object_loops(seed: int) -> None:
    rng = np.random.default_rng(seed)
    xyz, labels = things(seed)
    xyz = xyz + rng.normal(0, 1e-4, xyz.shape)  # full mantissas: the means' order shows
    ids = inst.find_instances(xyz, labels, 0.02)
    conf = rng.random(len(xyz)).astype(np.float32)
    yaw = float(rng.uniform(-45, 45))
    grid = rooms.RoomGrid(rng.integers(-1, 3, (40, 50)), np.array([-1.0, -0.5]), 0.2, yaw)
    matrix = np.eye(4)
    matrix[:3, :3] = rotation_z(30.0) * 0.5
    matrix[:3, 3] = rng.normal(0, 10, 3)
    plan = grid.plan_xy(xyz)
    for g, floor_z in ((grid, 0.1), (None, None)):
        expected = reference_objects(
            xyz, labels, conf.astype(np.float64), ids, matrix, yaw, floor_z, g
        )
        got = layout._objects(xyz, labels, conf, ids, matrix, yaw, floor_z, g, plan)
        assert [o.model_dump() for o in got] == [o.model_dump() for o in expected]
    # only some objects: their records, the same
    some = np.array([1, 3, 4])
    got = layout._objects(xyz, labels, None, ids, matrix, yaw, 0.1, grid, plan, only=some)
    expected = reference_objects(xyz, labels, np.ones(len(xyz)), ids, matrix, yaw, 0.1, grid)
    assert [o.model_dump() for o in got] == [o.model_dump() for o in expected if o.id in some]


def test_rooms_under_points_and_cell_counts_are_the_plain_codes() -> None:
    rng = np.random.default_rng(2)
    grid = rooms.RoomGrid(rng.integers(-1, 4, (30, 45)), np.array([-2.0, 1.0]), 0.1, 17.0)
    xyz = rng.uniform(-4, 6, (20_000, 3))
    plan = grid.plan_xy(xyz)
    ij = np.floor((plan - grid.origin) / grid.cell).astype(np.int64)
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < 30) & (ij[:, 1] >= 0) & (ij[:, 1] < 45)
    expected = np.full(len(xyz), -1)
    expected[inside] = grid.labels[ij[inside, 0], ij[inside, 1]]
    assert np.array_equal(grid.room_of(xyz), expected)
    empty = rooms.RoomGrid(np.zeros((0, 0), np.int64), np.zeros(2), 0.1, 0.0)
    assert (empty.room_of(xyz) == -1).all()
    a = np.radians(-17.0)
    assert np.array_equal(
        plan, np.c_[np.cos(a) * xyz[:, 0] - np.sin(a) * xyz[:, 1],
                    np.sin(a) * xyz[:, 0] + np.cos(a) * xyz[:, 1]]
    )  # fmt: skip
    cells = rooms._Cells(plan, np.array([-3.0, -1.0]), 0.25, (20, 30))
    mask = rng.random(len(xyz)) < 0.5
    ij = np.floor((plan[mask] - np.array([-3.0, -1.0])) / 0.25).astype(np.int64)
    ok = (ij >= 0).all(axis=1) & (ij[:, 0] < 20) & (ij[:, 1] < 30)
    flat = np.ravel_multi_index((ij[ok, 0], ij[ok, 1]), (20, 30))
    assert np.array_equal(cells.count(mask), np.bincount(flat, minlength=600).reshape(20, 30))


def test_ceiling_heights_are_the_per_room_loops() -> None:
    rng = np.random.default_rng(3)
    n, n_rooms = 30_000, 6
    xyz = rng.uniform(0, 3, (n, 3))
    labels = rng.integers(0, 13, n)
    room = rng.integers(-1, n_rooms + 1, n)  # a room id past the last is no room
    structure = rng.choice([-1, 0, 1, 2], n, p=[0.7, 0.002, 0.1, 0.198])
    for s in (structure, None):
        expected = np.full(n_rooms, np.nan)
        for r in range(n_rooms):
            inside = room == r
            if s is not None:
                planes = xyz[inside & (s == 0), 2]
                if planes.size >= rooms.MIN_CEILING_POINTS:
                    expected[r] = float(np.median(planes)) - 0.1
                    continue
            ceiling = xyz[inside & (labels == 0), 2]
            if ceiling.size >= 20:
                expected[r] = float(np.median(ceiling)) - 0.1
                continue
            walls = xyz[inside & (labels == 2), 2]
            if walls.size >= 20:
                expected[r] = float(np.quantile(walls, 0.99)) - 0.1
        got = rooms.ceiling_heights(xyz, labels, room, 0.1, n_rooms, s)
        assert np.array_equal(got, expected, equal_nan=True)


def test_room_outlines_are_the_row_by_row_boxes() -> None:
    from scipy import ndimage
    from shapely.geometry import Polygon, box
    from shapely.ops import unary_union

    def expected(mask: np.ndarray, simplify: float) -> np.ndarray | None:
        rects = []
        for i in np.flatnonzero(mask.any(axis=1)):
            edges = np.flatnonzero(np.diff(np.r_[False, mask[i], False].astype(np.int8)))
            rects += [box(i, a, i + 1, b) for a, b in zip(edges[::2], edges[1::2], strict=True)]
        if not rects:
            return None
        shape = unary_union(rects)
        if shape.geom_type == "MultiPolygon":
            shape = max(shape.geoms, key=lambda g: g.area)
        ring = np.asarray(Polygon(shape.exterior).simplify(simplify).exterior.coords)[:-1]
        return ring.astype(np.float64) if len(ring) >= 3 else None

    rng = np.random.default_rng(4)
    for k in range(40):
        mask = rng.random((rng.integers(1, 30), rng.integers(1, 30))) < rng.uniform(0.3, 0.95)
        if k % 2:
            mask = ndimage.binary_closing(mask, iterations=2)
        for simplify in (0.0, 0.5):
            a, b = outline._cell_ring(mask, simplify=simplify), expected(mask, simplify)
            if a is None or b is None:
                assert a is None and b is None
            else:
                assert np.array_equal(a, b)


@pytest.fixture(scope="module")
def room_scan():
    return make_room(11, points=80_000)


def test_a_layout_with_its_plan_given_or_not_and_its_joined_doors_measured_again(
    room_scan, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The room grid from every point's plan coordinates is the one from its own points; the
    objects measured again after a door's pieces join are those all measured afresh."""
    scan = room_scan
    spacing = estimate_spacing(scan.xyz)
    found = layout.find_layout(scan.xyz, scan.labels, None, spacing)
    report = found.report
    assert report.floor_z is not None
    grid = rooms.RoomGrid(np.zeros((0, 0), np.int64), np.zeros(2), 1.0, report.yaw)
    plan = grid.plan_xy(scan.xyz)
    fresh = layout._objects(
        scan.xyz, scan.labels, None, found.instances, np.eye(4), report.yaw, report.floor_z,
        None, plan,
    )  # fmt: skip
    assert [o.model_dump(exclude={"room"}) for o in fresh] == [
        o.model_dump(exclude={"room"}) for o in report.objects
    ]
    a = rooms.room_grid(scan.xyz, scan.labels, report.yaw, report.floor_z, ObjectParams())
    b = rooms.room_grid(
        scan.xyz, scan.labels, report.yaw, report.floor_z, ObjectParams(), plan=plan
    )
    assert np.array_equal(a.labels, b.labels) and np.array_equal(a.origin, b.origin)
    # a join that changes a door makes the records of that door, and only it, again
    calls: list[object] = []
    measure = layout._objects

    def spy(*args, **kwargs):
        calls.append(kwargs.get("only"))
        return measure(*args, **kwargs)

    monkeypatch.setattr(layout, "_objects", spy)
    monkeypatch.setattr(
        layout, "join_door_pieces", lambda instances, labels, *a, **k: _merge(instances, labels)
    )
    joined = layout.find_layout(scan.xyz, scan.labels, None, spacing)
    assert calls[0] is None and len(calls) == 2 and calls[1] is not None
    monkeypatch.setattr(layout, "_objects", measure)
    again = measure(
        scan.xyz, scan.labels, None, joined.instances, np.asarray(joined.report.to_user),
        joined.report.yaw, joined.report.floor_z,
        rooms.RoomGrid(np.zeros((0, 0), np.int64), np.zeros(2), 1.0, joined.report.yaw), plan,
    )  # fmt: skip
    assert [o.model_dump(exclude={"room"}) for o in again] == [
        o.model_dump(exclude={"room"}) for o in joined.report.objects
    ]


def _merge(instances: np.ndarray, labels: np.ndarray) -> int:
    """A stand-in join that changes door rows only, as the join does: every second point of
    the first door object becomes a crumb."""
    door = (labels == 6) & (instances >= 0)
    if not door.any():
        pytest.skip("the room has no door object")
    rows = np.flatnonzero(door & (instances == instances[door].min()))
    instances[rows[::2]] = -1
    return 1
