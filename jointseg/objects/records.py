"""The records of objects, rooms and walls: plain pydantic models, so the report, ``objects.json``,
the job API and the IFC writer share one shape without importing the geometry code."""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import BaseModel, Field

from jointseg.exceptions import JobStateError

Vec = tuple[float, float, float]


def user_coords(matrix: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Work-frame points to the user's coordinates through a 4x4 matrix."""
    return np.asarray(xyz, dtype=np.float64) @ matrix[:3, :3].T + matrix[:3, 3]


def vec(v: np.ndarray) -> Vec:
    """A record's 3-vector from an array's first three values."""
    return (float(v[0]), float(v[1]), float(v[2]))


class ObjectRecord(BaseModel):
    """One object: a group of touching points of one class."""

    id: int
    cls: str = Field(description="S3DIS class name.")
    points: int
    confidence: float = Field(description="Mean fused confidence of its points.")
    centroid: Vec = Field(description="User coordinates.")
    box: list[Vec] = Field(description="8 corners of a box aligned with the room, user coords.")
    size: Vec = Field(description="Box size along the room's axes and up, metres.")
    height_above_floor: float = Field(description="Lowest point above the floor, metres.")
    room: int | None = None
    plausible: bool = Field(
        True,
        description="Its box has its class's shape (jointseg.objects.shapes); False: a "
        "fragment the labels gave that class, left out of counts and modelled as a proxy.",
    )


class OpeningRecord(BaseModel):
    """A door or window in a wall: the opening it fills, measured in the wall's plane."""

    object: int
    kind: str
    width: float
    height: float
    sill: float = Field(description="Bottom above the floor, metres.")
    offset: float = Field(
        0.0, description="Start of the opening along the wall from its first corner, metres."
    )


class SetAside(BaseModel):
    """A door or window found in the labels but not modelled as one, and why (no door has
    that size, a window touching the floor, ...)."""

    object: int
    kind: str
    reason: str


class WallRecord(BaseModel):
    """A planar wall: a vertical rectangle."""

    id: int
    corners: list[Vec] = Field(description="4 corners (bottom, bottom, top, top), user coords.")
    length: float
    height: float
    area: float = Field(description="Gross area, m².")
    net_area: float = Field(description="Area less its doors and windows, m².")
    rooms: list[int] = Field(default_factory=list)
    openings: list[OpeningRecord] = Field(default_factory=list)
    thickness: float = Field(0.2, description="Wall thickness, metres.")
    thickness_measured: bool = Field(
        False,
        description="True: measured between this face and the wall's other face (other_face); "
        "False: the declared default (LayoutReport.wall_thickness).",
    )
    other_face: int | None = Field(
        None, description="The wall record of the same wall's other face."
    )
    extends: tuple[float, float] = Field(
        (0.0, 0.0),
        description="How far the wall's body runs on beyond the face at its first and second "
        "corner (into the body of the wall it meets there), metres.",
    )
    joined: tuple[int | None, int | None] = Field(
        (None, None), description="The wall record met at the first and at the second corner."
    )
    body_side: int = Field(
        1,
        description="Which side of the face the wall's body lies on, seen from the first corner "
        "to the second in the work frame's plan: +1 left, -1 right.",
    )


class RoomRecord(BaseModel):
    """A room: a region of the floor plan closed by walls."""

    id: int
    name: str
    kind: str = Field(description="'room', or 'corridor' for a long narrow one.")
    floor_area: float = Field(description="m², floor under furniture included.")
    ceiling_height: float | None = Field(description="Floor to ceiling, metres.")
    footprint: list[tuple[float, float]] = Field(description="Outline in the plan, work frame.")
    walls: list[int] = Field(default_factory=list)
    objects: list[int] = Field(default_factory=list)


class LayoutReport(BaseModel):
    """The report's ``objects`` and ``rooms`` sections, and what the IFC writer needs."""

    objects: list[ObjectRecord] = Field(default_factory=list)
    rooms: list[RoomRecord] = Field(default_factory=list)
    walls: list[WallRecord] = Field(default_factory=list)
    floor_z: float | None = Field(None, description="Floor height in the work frame, metres.")
    yaw: float = Field(0.0, description="Walls' direction in the work frame, degrees.")
    to_user: list[list[float]] | None = Field(None, description="4x4 work -> user matrix.")
    reason: str | None = Field(None, description="Why a section is empty, when it is.")
    wall_thickness: float | None = Field(
        None,
        description="The declared thickness (metres) of the walls whose two faces were not both "
        "seen (ObjectParams.wall_thickness); null when no wall was found.",
    )
    set_aside: list[SetAside] = Field(
        default_factory=list,
        description="Doors and windows not modelled as such, and why.",
    )

    def counts(self) -> dict[str, int]:
        """Objects per class (those of their class's shape), fragments (the rest), rooms and
        walls: what a summary line shows."""
        out: dict[str, int] = {}
        for o in self.objects:
            key = o.cls if o.plausible else "fragments"
            out[key] = out.get(key, 0) + 1
        out["rooms"] = len(self.rooms)
        out["walls"] = len(self.walls)
        return out

    @classmethod
    def from_report(cls, body: dict[str, Any]) -> LayoutReport:
        """The layout a run's report holds (its ``objects`` and ``rooms`` sections).

        Raises
        ------
        JobStateError
            When the run found no objects or rooms (a tiled run, or the stage switched off).
        """
        if body.get("rooms") is None:
            raise JobStateError(
                "this run has no objects or rooms: objects.enabled was off in its config, or "
                "it ran before jointseg found them; run `jointseg objects` on its result"
            )
        return cls(objects=body["objects"], **body["rooms"])


def report_sections(layout: LayoutReport | None) -> dict[str, Any]:
    """The report's ``objects`` (object records) and ``rooms`` (rooms, walls, floor height,
    reason) sections; both null when the stage did not run."""
    if layout is None:
        return {"objects": None, "rooms": None}
    body = layout.model_dump(mode="json")
    return {"objects": body.pop("objects"), "rooms": body}
