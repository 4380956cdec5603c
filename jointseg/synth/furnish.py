"""Furnishing one space by room type: what goes where, without objects interpenetrating.

A room type (office, conference, classroom, lounge, storage, corridor) fixes the mix of
furniture; every piece is placed by rejection sampling against the space's
:class:`~jointseg.synth.layout.Occupancy` with a clearance of about 10 cm, so objects stay
separated the way Euclidean clustering of a real scan expects, while things that really touch
(items on a table, books on a shelf, a bookcase backed onto a wall) still do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jointseg.synth.clutter import make_cabinet, make_floor_item, make_table_item, make_wall_item
from jointseg.synth.fixtures import (
    add_beams,
    add_board,
    add_columns,
    add_lamps,
    add_radiators,
    pick_face,
)
from jointseg.synth.furniture import Item, Surface, make_bookcase, make_chair, make_sofa, make_table
from jointseg.synth.layout import Occupancy, Plan, Space, keepouts_for
from jointseg.synth.meshes import MeshBuilder, Pose
from jointseg.synth.structure import Ids, SpaceLook

GAP = 0.1  # clearance kept between free-standing objects


def _overlap(a: tuple[float, ...], b: tuple[float, ...], margin: float) -> bool:
    """Whether 2D rectangles (x0, y0, x1, y1) come closer than ``margin``."""
    return (
        a[0] < b[2] + margin
        and a[2] > b[0] - margin
        and a[1] < b[3] + margin
        and a[3] > b[1] - margin
    )


@dataclass
class Flags:
    """Which optional classes a room gets (windows are decided with the floor plan)."""

    board: bool
    beam: bool
    column: bool
    sofa: bool


def draw_flags(rng: np.random.Generator, kind: str, at_least: int = 0) -> Flags:
    """Draw the optional classes of a room, forcing at least ``at_least`` of them on."""
    p = {"board": 0.35, "beam": 0.35, "column": 0.35, "sofa": 0.08}
    if kind in ("conference", "classroom"):
        p["board"] = 1.0
    if kind == "lounge":
        p["sofa"] = 1.0
    if kind == "corridor":
        p = {"board": 0.5, "beam": 0.25, "column": 0.2, "sofa": 0.05}
    on = {k: bool(rng.random() < v) for k, v in p.items()}
    off = [k for k in ("beam", "column") if not on[k]]
    rng.shuffle(off)
    # Forced last: boards and sofas are the rarer classes in S3DIS.
    off = [k for k in ("sofa", "board") if not on[k]] + off
    while sum(on.values()) < at_least and off:
        on[off.pop()] = True
    return Flags(**on)


class Furnisher:
    """Places items in one space and builds them into the scene mesh."""

    def __init__(
        self, space: Space, plan: Plan, mb: MeshBuilder, ids: Ids, rng: np.random.Generator
    ) -> None:
        self.space, self.plan, self.mb, self.ids, self.rng = space, plan, mb, ids, rng
        self.occ = Occupancy(space)
        self.surfaces: list[Surface] = []
        self.counts: dict[str, int] = {}
        for o in plan.openings:
            if space.index in (o.face.space, o.face.other):
                box = keepouts_for(o, space, plan.height)
                if box is not None:
                    self.occ.add(box, solid=False)

    def put(self, item: Item, pose: Pose, margin: float = GAP, wall_margin: float = 0.08) -> bool:
        """Build ``item`` at ``pose`` if it clears other objects by ``margin`` and the walls
        by ``wall_margin``; remember table tops."""
        box = item.aabb(pose)
        if not self.occ.fits(box, margin=margin, wall_margin=wall_margin):
            return False
        surface = item.build(self.mb, pose, self.ids)
        self.occ.add(box)
        self.counts[item.kind] = self.counts.get(item.kind, 0) + 1
        if surface is not None:
            self.surfaces.append(surface)
        return True

    def against_wall(self, item: Item, gap: float | None = None, tries: int = 40) -> Pose | None:
        """Back ``item`` onto a random wall face (local +y into the room), ``gap`` metres off
        it (None: 3.5-7 cm, the skirting board; enough to leave the wall plane on its own)."""
        for _ in range(tries):
            off = float(self.rng.uniform(0.035, 0.07)) if gap is None else gap
            face = pick_face(self.space, self.rng, item.w + 0.1)
            if face is None:
                return None
            u = float(self.rng.uniform(face.u0 + item.w / 2 + 0.02, face.u1 - item.w / 2 - 0.02))
            p = face.point(u, off + item.d / 2)
            pose = Pose(float(p[0]), float(p[1]), face.yaw)
            if self.put(item, pose, wall_margin=0.0):
                return pose
        return None

    def free(self, item: Item, wall_margin: float = 0.6, tries: int = 40) -> Pose | None:
        """Stand ``item`` somewhere in the open, axis aligned give or take a few degrees."""
        x0, y0, x1, y1 = self.space.bbox
        for _ in range(tries):
            yaw = self.rng.integers(0, 4) * math.pi / 2 + self.rng.normal(0.0, 0.04)
            pose = Pose(float(self.rng.uniform(x0, x1)), float(self.rng.uniform(y0, y1)), yaw)
            box = item.aabb(pose)
            if not self.occ.fits(box, margin=GAP, wall_margin=wall_margin):
                continue
            if self.put(item, pose):
                return pose
        return None

    def chair_at(
        self, table: Pose, local_xy: tuple[float, float], facing_table_sign: float
    ) -> bool:
        """A chair next to a table: at ``local_xy`` in the table frame, facing the table."""
        chair = make_chair(self.rng)
        x, y = local_xy
        y += facing_table_sign * (chair.d / 2 + self.rng.uniform(0.08, 0.3))
        p = table.world([[x + self.rng.normal(0, 0.04), y, 0.0]])[0]
        yaw = table.yaw + (math.pi if facing_table_sign > 0 else 0.0) + self.rng.normal(0, 0.2)
        return self.put(chair, Pose(float(p[0]), float(p[1]), float(yaw)), margin=0.06)

    def chairs_around(self, table: Pose, item: Item, ends: bool) -> int:
        """Seat chairs along the long sides (and maybe the ends) of a table."""
        n = max(1, int((item.w - 0.2) // 0.72))
        xs = (np.arange(n) - (n - 1) / 2) * 0.72
        placed = 0
        for side in (1.0, -1.0):
            for x in xs:
                placed += self.chair_at(table, (float(x), side * item.d / 2), side)
        if ends:
            for side in (1.0, -1.0):
                rot = Pose(table.x, table.y, table.yaw + math.pi / 2)
                placed += self.chair_at(rot, (0.0, side * item.w / 2), side)
        return placed

    def desk_with_chair(self, style: str = "desk", at_wall: bool | None = None) -> bool:
        """A desk (against a wall or free-standing) with its chair in front."""
        desk = make_table(self.rng, style)
        if at_wall is None:
            at_wall = bool(self.rng.random() < 0.65)
        pose = self.against_wall(desk, gap=None) if at_wall else self.free(desk)
        if pose is None:
            return False
        self.chair_at(pose, (float(self.rng.uniform(-0.2, 0.2)), desk.d / 2), 1.0)
        if desk.w > 1.4 and self.rng.random() < 0.4:
            self.chair_at(pose, (desk.w / 2 - 0.3, desk.d / 2), 1.0)
        return True

    def ensure_basics(self, bookcase: bool = True) -> None:
        """Make sure the room has a table, a chair (and a bookcase), shrinking them if needed."""
        rng = self.rng
        for _ in range(8):
            if self.counts.get("table", 0):
                break
            table = make_table(rng, "desk" if rng.random() < 0.5 else "round")
            pose = self.against_wall(table, tries=10) or self.free(table, wall_margin=0.3)
            if pose is not None:
                self.chair_at(pose, (0.0, table.d / 2), 1.0)
        for _ in range(8):
            if self.counts.get("chair", 0):
                break
            chair = make_chair(rng)
            self.against_wall(chair, gap=0.1, tries=10) or self.free(chair, wall_margin=0.3)
        for _ in range(8 if bookcase else 0):
            if self.counts.get("bookcase", 0):
                break
            self.against_wall(make_bookcase(rng, low=bool(rng.random() < 0.5)), gap=None)

    def dress_surfaces(self, per_m2: float = 5.0, monitors: bool = True) -> None:
        """Put small clutter on every table top with a few cm between items."""
        for s in self.surfaces:
            n = int(self.rng.poisson(per_m2 * s.w * s.d)) + (1 if monitors else 0)
            taken: list[tuple[float, float, float, float]] = []
            for k in range(n):
                item = make_table_item(self.rng)
                if k == 0 and monitors and item.kind != "monitor" and s.w > 1.0:
                    item = make_table_item(self.rng)
                for _ in range(12):
                    hw, hd = s.w / 2 - item.w / 2 - 0.03, s.d / 2 - item.d / 2 - 0.03
                    if hw <= 0 or hd <= 0:
                        break
                    x, y = float(self.rng.uniform(-hw, hw)), float(self.rng.uniform(-hd, hd))
                    r = (x - item.w / 2, y - item.d / 2, x + item.w / 2, y + item.d / 2)
                    if any(_overlap(r, t, 0.03) for t in taken):
                        continue
                    taken.append(r)
                    p = s.pose.world([[x, y, 0.0]])[0]
                    pose = Pose(float(p[0]), float(p[1]), s.pose.yaw, s.z)
                    item.build(self.mb, pose, self.ids)
                    self.occ.add(item.aabb(pose))
                    break

    def wall_items(self, n: int) -> None:
        """Pictures, posters, TVs, clocks on free wall stretches."""
        for _ in range(n):
            item, z = make_wall_item(self.rng, self.plan.height)
            for _ in range(15):
                face = pick_face(self.space, self.rng, item.w + 0.2)
                if face is None:
                    return
                u = float(
                    self.rng.uniform(face.u0 + item.w / 2 + 0.05, face.u1 - item.w / 2 - 0.05)
                )
                p = face.point(u, item.d / 2 + 0.004)
                pose = Pose(float(p[0]), float(p[1]), face.yaw, z)
                x0, y0, z0, x1, y1, z1 = item.aabb(pose)
                padded = (x0, y0, z0 - 0.05, x1, y1, z1 + 0.05)  # keep a gap above and below
                if self.occ.fits(padded, margin=0.05):
                    item.build(self.mb, pose, self.ids)
                    self.occ.add(padded)
                    break


def _tables_and_chairs(f: Furnisher, kind: str, area: float) -> None:
    """The room type's working furniture: desks, a meeting table, rows or round tables."""
    rng, space = f.rng, f.space
    if kind == "conference":
        table = make_table(rng, "conference")
        x0, y0, x1, y1 = max(space.rects, key=lambda r: (r[2] - r[0]) * (r[3] - r[1]))
        yaw = 0.0 if (x1 - x0) >= (y1 - y0) else math.pi / 2
        for _ in range(20):
            pose = Pose((x0 + x1) / 2 + rng.normal(0, 0.3), (y0 + y1) / 2 + rng.normal(0, 0.3), yaw)
            if f.put(table, pose):
                f.chairs_around(pose, table, ends=bool(rng.random() < 0.7))
                for _ in range(int(rng.integers(2, 9))):
                    f.against_wall(make_chair(rng), gap=0.1)
                break
            table = make_table(rng, "conference" if rng.random() < 0.5 else "desk")
        if area > 45:
            for _ in range(int(rng.integers(0, 3))):
                f.desk_with_chair("desk", at_wall=True)
    elif kind == "classroom":
        for _ in range(max(3, int(area / 3.5))):
            table = make_table(rng, "training")
            at = f.free(table, wall_margin=0.7)
            if at is not None:
                for x in (-table.w / 4, table.w / 4) if table.w > 1.3 else (0.0,):
                    f.chair_at(at, (x, table.d / 2), 1.0)
    elif kind == "lounge":
        for _ in range(int(rng.integers(1, 4))):
            table = make_table(rng, "round")
            at = f.free(table)
            if at is not None:
                for k in range(int(rng.integers(2, 5))):
                    rot = Pose(at.x, at.y, at.yaw + k * math.pi / 2)
                    f.chair_at(rot, (0.0, table.d / 2), 1.0)
        if rng.random() < 0.6:
            f.desk_with_chair("desk", at_wall=True)
    else:
        per = rng.uniform(3.5, 6.0) if kind == "office" else rng.uniform(10.0, 20.0)
        for _ in range(min(12, max(1, round(area / per)))):
            f.desk_with_chair()
    for _ in range(int(rng.integers(2, 7))):  # visitor chairs, a chair left in the open
        f.free(make_chair(rng), wall_margin=0.4, tries=15)


def furnish(
    space: Space,
    plan: Plan,
    mb: MeshBuilder,
    ids: Ids,
    rng: np.random.Generator,
    look: SpaceLook,
    flags: Flags,
) -> Occupancy:
    """Build fixtures and furniture of ``space`` by its kind; returns its occupancy."""
    f = Furnisher(space, plan, mb, ids, rng)
    area, kind = space.area, space.kind
    perimeter = sum(fc.length for fc in space.faces)
    if flags.beam:
        add_beams(space, plan, mb, ids, rng, f.occ, look)
    space.lights = add_lamps(space, plan, mb, ids, rng, f.occ)
    if flags.column:
        n = int(rng.choice([1, 2, 3], p=[0.5, 0.35, 0.15]))
        if add_columns(space, plan, mb, ids, rng, f.occ, look, n) == 0:
            add_columns(space, plan, mb, ids, rng, f.occ, look, 1)
    add_radiators(space, plan, mb, ids, rng, f.occ)
    if flags.board:
        n_boards = 1 + int(kind in ("conference", "classroom") and rng.random() < 0.4)
        for _ in range(n_boards):
            add_board(space, plan, mb, ids, rng, f.occ) or add_board(
                space, plan, mb, ids, rng, f.occ
            )
    if kind == "corridor":
        for _ in range(int(rng.integers(0, 3))):
            f.against_wall(make_cabinet(rng) if rng.random() < 0.5 else make_bookcase(rng, True))
        for _ in range(int(rng.poisson(area / 6))):
            f.against_wall(make_floor_item(rng) if rng.random() < 0.6 else make_chair(rng))
        f.wall_items(int(rng.poisson(perimeter / 5)))
        return f.occ
    if flags.sofa:
        for i in range(1 + int(kind == "lounge") * int(rng.integers(0, 3))):
            sofa = make_sofa(rng)
            pose = f.against_wall(sofa, gap=None) or f.free(sofa)
            if pose is None and i == 0:
                pose = f.against_wall(make_sofa(rng, armchair=True), gap=None)
            if pose is not None and kind == "lounge":
                table = make_table(rng, "coffee")
                p = pose.world([[0.0, sofa.d / 2 + GAP + 0.25 + table.d / 2, 0.0]])[0]
                f.put(table, Pose(float(p[0]), float(p[1]), pose.yaw))
    _tables_and_chairs(f, kind, area)
    f.ensure_basics(bookcase=False)
    n_book = {"storage": 5.0, "office": 3.0, "lounge": 2.0}.get(kind, 1.5)
    for _ in range(max(1, int(rng.poisson(n_book + area / 15)))):
        low = rng.random() < 0.2
        pose = f.against_wall(make_bookcase(rng, low), gap=None)
        if pose is not None and rng.random() < 0.3:  # a second unit right next to the first
            f.against_wall(make_bookcase(rng, low), gap=None)
    n_cab = int(rng.poisson({"storage": 4.0, "office": 3.0}.get(kind, 2.0) + area / 20))
    for _ in range(n_cab):
        f.against_wall(make_cabinet(rng), gap=None)
    f.ensure_basics()
    f.dress_surfaces(
        per_m2=8.0 if kind in ("office", "storage") else 5.0,
        monitors=kind in ("office", "classroom") and rng.random() < 0.8,
    )
    n_floor = int(rng.poisson(area / (2.0 if kind == "storage" else 2.8))) + 2
    for _ in range(n_floor):
        item = make_floor_item(rng)
        if f.against_wall(item, gap=None, tries=10) is None:
            f.free(item, wall_margin=0.3, tries=10)
    f.wall_items(int(rng.poisson(perimeter / 2.5)))
    return f.occ
