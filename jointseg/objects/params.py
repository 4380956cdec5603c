"""What the objects-and-rooms stage may be told: contact distances, sizes and thicknesses.

Distances that depend on the scan's density are multiples of its point spacing; the rest are
metres, the building's own scale (the stage runs in the frame stage's levelled metric frame).
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

#: Classes whose points form objects (S3DIS order): beam, column, window, door, table, chair,
#: sofa, bookcase, board, clutter. Ceiling, floor and wall are structure.
THING_CLASSES: tuple[int, ...] = (3, 4, 5, 6, 7, 8, 9, 10, 11, 12)
CEILING, FLOOR, WALL, WINDOW, DOOR, CLUTTER = 0, 1, 2, 5, 6, 12


class ObjectParams(BaseModel):
    """Settings of :func:`jointseg.objects.find_layout`, validated once at the edge."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    enabled: bool = Field(True, description="Find objects and rooms (report sections).")
    contact: float = Field(
        2.5, gt=0, le=20, description="Points of one class closer than this x spacing touch."
    )
    min_contact: float = Field(
        0.12, gt=0, description="Least contact distance, metres (occlusion gaps within one object)."
    )
    min_points: int = Field(30, ge=1, description="Fewer points than this are not an object.")
    room_cell: float = Field(0.05, gt=0.005, le=0.5, description="Room grid cell, metres.")
    min_room_area: float = Field(1.5, ge=0, description="Smaller floor regions are no room, m².")
    min_wall_length: float = Field(0.5, gt=0, description="Shorter wall planes are dropped, m.")
    wall_thickness: float = Field(0.2, gt=0, le=2, description="IFC wall thickness, metres.")
    slab_thickness: float = Field(0.2, gt=0, le=2, description="IFC slab thickness, metres.")
