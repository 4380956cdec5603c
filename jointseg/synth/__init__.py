"""Synthetic indoor scans with S3DIS ground truth: test data and training data for jointseg.

Rooms and whole floors are built as triangle meshes (walls with door and window openings,
beams, columns, boards, furniture, clutter), coloured with class-plausible materials and
lighting, and scanned by ray casting from tripod positions, so occlusion, range noise and the
fall of density with range look like a real terrestrial scan. A room's mesh itself can be
written as a phone app would deliver it (GLB, OBJ, PLY with faces): :func:`room_mesh`,
:func:`write_room_mesh`.
"""

from jointseg.synth.export import RoomMesh, room_mesh, write_room_mesh
from jointseg.synth.floor import floor_layout, make_floor
from jointseg.synth.room import make_room, room_layout

__all__ = [
    "RoomMesh",
    "floor_layout",
    "make_floor",
    "make_room",
    "room_layout",
    "room_mesh",
    "write_room_mesh",
]
