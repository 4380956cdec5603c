"""A synthetic room's mesh (issue 41): the triangles make_room scans, placed as its points, and
written as GLB (y up), OBJ and PLY (z up) that jointseg.io reads back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from jointseg.exceptions import ConfigError
from jointseg.io import read_scan
from jointseg.synth import make_room, room_mesh, write_room_mesh
from jointseg.synth.export import Z_UP_TO_Y_UP


def _closest(mesh, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from each point to the mesh, and the triangle it is closest to."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(mesh.vertices.astype(np.float32)),
        o3d.core.Tensor(mesh.faces.astype(np.uint32)),
    )
    query = o3d.core.Tensor(points.astype(np.float32))
    closest = scene.compute_closest_points(query)
    distance = scene.compute_distance(query).numpy()
    return distance, closest["primitive_ids"].numpy().astype(np.int64)


@pytest.mark.parametrize(("shape", "yaw"), [("box", None), ("L", 30.0)])
def test_the_scanned_points_lie_on_the_rooms_mesh(shape: str, yaw: float | None) -> None:
    scan = make_room(4, points=5_000, shape=shape, yaw=yaw)
    mesh = room_mesh(4, shape=shape, yaw=yaw)
    assert mesh.faces.shape[1] == 3 and mesh.rgb.shape == (len(mesh.faces), 3)
    assert mesh.labels.shape == (len(mesh.faces),) and set(np.unique(mesh.labels)) <= set(range(13))
    # within the scanner model's range noise (a few mm) of the very triangles make_room scanned,
    # and each point's class is that of its nearest triangle
    distance, face = _closest(mesh, scan.xyz)
    assert np.quantile(distance, 0.99) < 0.02
    assert np.mean(mesh.labels[face] == scan.labels) > 0.97


def test_seen_only_keeps_the_triangles_the_scanners_see() -> None:
    every = room_mesh(4, yaw=0.0)
    seen = room_mesh(4, yaw=0.0, seen_only=True)
    assert 0 < len(seen.faces) < len(every.faces)
    scan = make_room(4, points=5_000, yaw=0.0)
    assert np.quantile(_closest(seen, scan.xyz)[0], 0.99) < 0.02


def test_written_meshes_read_back_in_their_frames(tmp_path: Path) -> None:
    mesh = room_mesh(4, yaw=0.0)
    scans = {
        ext: read_scan(write_room_mesh(mesh, tmp_path / f"room.{ext}"), max_points=100_000)
        for ext in ("glb", "obj", "ply")
    }
    # the same sampling in all three: GLB turned to y up, OBJ and PLY z up as the room (GLB
    # stores float32 vertices, which may move a rare point to the next triangle)
    same = np.abs(scans["glb"].xyz @ Z_UP_TO_Y_UP - scans["obj"].xyz).max(axis=1) < 1e-5
    assert same.mean() > 0.999
    np.testing.assert_allclose(scans["ply"].xyz, scans["obj"].xyz, atol=1e-5)
    assert scans["glb"].meta["up_convention"]["axis"] == "+y"
    height = scans["glb"].xyz[:, 1].max() - scans["glb"].xyz[:, 1].min()
    assert 2.5 < height < 4.5  # the storey height is along glTF's y
    for ext, scan in scans.items():
        assert scan.source_format == ext
        assert scan.meta["mesh"]["faces"] == len(mesh.faces)
        assert scan.rgb is not None
        assert {tuple(c) for c in np.unique(scan.rgb, axis=0)} <= {tuple(c) for c in mesh.rgb}
    assert scans["ply"].meta["mesh"]["colour"] == "face"
    assert scans["obj"].meta["mesh"]["colour"] == "vertex"
    assert "jointseg synthetic room, seed 4" in scans["obj"].meta["comments"]
    assert "jointseg synthetic room, seed 4" in scans["ply"].meta["comments"]


def test_bad_arguments() -> None:
    with pytest.raises(ConfigError, match="shape"):
        room_mesh(1, shape="round")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="seed"):
        room_mesh(-1)
    with pytest.raises(ConfigError, match=".glb, .obj, .ply"):
        write_room_mesh(room_mesh(1), "room.stl")
