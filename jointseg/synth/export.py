"""A synthetic room as the mesh a phone scanning app would deliver: GLB, OBJ or PLY with faces.

:func:`room_mesh` gives the very triangles :func:`jointseg.synth.make_room` scans for the same
seed (the same code builds them), placed as its points are, with each triangle's class and base
colour. :func:`write_room_mesh` writes them the way the apps do: GLB turned to y up (glTF's
convention), OBJ and PLY z up. So a mesh input can be checked against the point cloud of the
same room, and the mesh readers against known geometry.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.io.atomic import atomic_open
from jointseg.synth.params import check_seed, check_yaw
from jointseg.synth.render import split_quota, turn_about_centre
from jointseg.synth.room import RoomScene, build_room

log = logging.getLogger(__name__)

#: From the synthetic rooms' z-up frame to glTF's y up: (x, y, z) -> (x, z, -y).
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: The formats :func:`write_room_mesh` writes, by extension.
MESH_EXTENSIONS = (".glb", ".obj", ".ply")


@dataclass(frozen=True)
class RoomMesh:
    """The triangles of a synthetic room with a class and a colour each.

    Attributes
    ----------
    vertices : ndarray (V, 3) float64
        Metres, z up, placed as :func:`jointseg.synth.make_room`'s points for the same seed,
        shape and yaw.
    faces : ndarray (F, 3) int64
    rgb : ndarray (F, 3) uint8
        Each triangle's base colour (before the texture and lighting the scanner model adds).
    labels : ndarray (F,) int32
        Each triangle's S3DIS class.
    seed : int
        The seed it was built from (written into the files' comments).
    """

    vertices: np.ndarray
    faces: np.ndarray
    rgb: np.ndarray
    labels: np.ndarray
    seed: int

    def unshared(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vertices, faces and per-vertex colours with three vertices of its own per triangle,
        so a vertex colour is its triangle's colour exactly (formats without face colours)."""
        vertices = self.vertices[self.faces].reshape(-1, 3)
        faces = np.arange(vertices.shape[0], dtype=np.int64).reshape(-1, 3)
        return vertices, faces, np.repeat(self.rgb, 3, axis=0)


def room_mesh(
    seed: int,
    *,
    shape: Literal["box", "L"] = "box",
    yaw: float | None = None,
    seen_only: bool = False,
) -> RoomMesh:
    """The mesh of the room :func:`jointseg.synth.make_room` scans for ``seed``.

    Parameters
    ----------
    seed : int
    shape : {"box", "L"}
    yaw : float, optional
        Degrees about the vertical through the room's centre; None: the one the seed draws
        (as ``make_room``).
    seen_only : bool
        Keep only the triangles that ``make_room``'s scanner positions see (1 M rays cast
        from them), as a scanning app's mesh holds only the surfaces its camera saw; by
        default every triangle the room is built of, also those nothing inside sees (the
        outer faces of the walls, the tops of the slabs, hidden sides of furniture).

    Returns
    -------
    RoomMesh

    Raises
    ------
    ConfigError
        On a bad ``seed``, ``shape`` or ``yaw``.
    """
    seed = check_seed(seed)
    yaw = check_yaw(yaw)
    if shape not in ("box", "L"):
        raise ConfigError(f"shape must be 'box' or 'L', got {shape!r}")
    room = build_room(seed, shape)
    mesh = room.mesh
    keep = _seen(room, seed) if seen_only else np.ones(mesh.n_triangles, dtype=bool)
    vertices = mesh.vertices.astype(np.float64)
    vertices = turn_about_centre(vertices, room.plan, room.drawn_yaw if yaw is None else yaw)
    rgb = np.clip(np.rint(mesh.colour * 255.0), 0, 255).astype(np.uint8)
    return RoomMesh(
        vertices=vertices,
        faces=mesh.triangles.astype(np.int64)[keep],
        rgb=rgb[keep],
        labels=mesh.label.astype(np.int32)[keep],
        seed=seed,
    )


#: Rays cast to find the triangles the scanner positions see (``seen_only``).
SEEN_RAYS = 1_000_000


def _seen(room: RoomScene, seed: int) -> np.ndarray:
    """Which triangles rays from ``make_room``'s scanner positions hit (the drawn count, the
    same positions)."""
    from jointseg.synth.scanner import cast, make_scene, scanner_positions

    origins = scanner_positions(
        room.plan.spaces[0],
        room.occupancy,
        room.drawn_scanners,
        np.random.default_rng([seed, 1]),
    )
    quotas = split_quota(SEEN_RAYS, np.ones(len(origins)))
    hits = cast(make_scene(room.mesh), origins, quotas, np.random.default_rng([seed, 3]))
    seen = np.zeros(room.mesh.n_triangles, dtype=bool)
    seen[hits.triangle] = True
    return seen


def _trimesh(vertices: np.ndarray, faces: np.ndarray, **colours: Any) -> Any:
    import trimesh

    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False, **colours)


def _ply_bytes(mesh: RoomMesh, comment: str) -> bytes:
    """Binary PLY with faces and face colours, and our comment in the header."""
    from trimesh.exchange.ply import export_ply

    data = export_ply(_trimesh(mesh.vertices, mesh.faces, face_colors=mesh.rgb))
    head, sep, body = data.partition(b"\n")  # "ply", then the format line
    fmt, sep2, rest = body.partition(b"\n")
    return head + sep + fmt + sep2 + f"comment {comment}\n".encode("ascii") + rest


def write_room_mesh(mesh: RoomMesh, path: str | Path) -> Path:
    """Write ``mesh`` as a GLB (turned to y up), an OBJ or a PLY with faces (both z up).

    Parameters
    ----------
    mesh : RoomMesh
    path : str or Path
        ``.glb``: y up, as glTF requires ((x, y, z) -> (x, z, -y)), colours per vertex.
        ``.obj``: z up, colours per vertex (``v x y z r g b``). ``.ply``: binary, z up, colours
        per face. Written atomically.

    Returns
    -------
    Path

    Raises
    ------
    ConfigError
        For another extension or a missing folder.
    """
    from trimesh.exchange.obj import export_obj

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_EXTENSIONS:
        raise ConfigError(f"{path}: a room mesh is written as {', '.join(MESH_EXTENSIONS)}")
    if not path.parent.is_dir():
        raise ConfigError(f"{path}: folder {path.parent} does not exist")
    comment = f"jointseg synthetic room, seed {mesh.seed}"
    vertices, faces, colours = mesh.unshared()
    if suffix == ".glb":
        turned = _trimesh(vertices @ Z_UP_TO_Y_UP.T, faces, vertex_colors=colours)
        data = turned.export(file_type="glb")
    elif suffix == ".obj":
        text = export_obj(_trimesh(vertices, faces, vertex_colors=colours), header=comment)
        data = text.encode("utf-8")
    else:
        data = _ply_bytes(mesh, comment)
    with atomic_open(path) as fh:
        fh.write(data)
    log.info("wrote %s: %d triangles", path, len(mesh.faces))
    return path
