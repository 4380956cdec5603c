"""The mesh sampler (jointseg.io.formats.mesh.sample) against trimesh's ``sample_surface``.

Issue 69 asked whether the ~100 lines beside trimesh's sampler earn their place. Both sample a
gently waved 12 m x 12 m floor of about 200 k triangles (jittered grid, vertex colours and
labels) to 1 M points; each is timed (best of three), then judged on what the network sees:
how even the points are over its 4 cm grid (coefficient of variation of the points per cell),
and how many triangles get no point at all. The trimesh row adds what the reader needs on top
of ``sample_surface(..., return_barycentric=True)``: the ``Trimesh`` built, vertex colours
interpolated and each point's nearest-corner label.

    .venv/bin/python bench/mesh_sampling.py [--faces 200000] [--points 1000000]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import trimesh
from helpers.report import header

from jointseg.io.formats.mesh.sample import MeshPiece, PieceColour, sample_pieces

#: Side of the floor (m) and the network's grid (m) the evenness is measured on.
SIDE = 12.0
CELL = 0.04


def floor(faces: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A waved floor of about ``faces`` triangles: vertices, faces, vertex colours, labels."""
    rng = np.random.default_rng(seed)
    k = int(math.sqrt(faces / 2)) + 1
    x, y = np.meshgrid(np.linspace(0, SIDE, k), np.linspace(0, SIDE, k))
    z = 0.05 * np.sin(x * 3) * np.cos(y * 2)
    vertices = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    vertices[:, :2] += rng.normal(0, 0.3 * SIDE / k, (len(vertices), 2))
    idx = np.arange(k * k).reshape(k, k)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tri = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int64)
    colours = rng.integers(0, 255, (len(vertices), 3), dtype=np.uint8)
    labels = rng.integers(0, 13, len(vertices)).astype(np.int32)
    return vertices, tri, colours, labels


def best_of(fn: Callable[[], Any], reps: int = 3) -> tuple[float, Any]:
    """The fastest of ``reps`` runs and the last result."""
    times, out = [], None
    for _ in range(reps):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return min(times), out


def evenness(xyz: np.ndarray) -> tuple[float, int]:
    """CV of the points per 4 cm cell (a margin of 5 cells left out) and the empty cells."""
    key = np.floor(xyz[:, :2] / CELL).astype(np.int64)
    cells = int(SIDE / CELL)
    inside = (key >= 5).all(1) & (key < cells - 5).all(1)
    _, counts = np.unique(key[inside], axis=0, return_counts=True)
    return float(counts.std() / counts.mean()), (cells - 10) ** 2 - len(counts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--faces", type=int, default=200_000)
    parser.add_argument("--points", type=int, default=1_000_000)
    args = parser.parse_args()
    header("mesh sampling: jointseg's sampler vs trimesh.sample.sample_surface")
    vertices, faces, colours, labels = floor(args.faces)
    n = args.points
    print(f"{len(faces):,} triangles, {len(vertices):,} vertices, {n:,} points\n")
    piece = MeshPiece(vertices, faces, PieceColour("vertex", values=colours), labels=labels)
    bare = MeshPiece(vertices, faces, PieceColour())

    def with_trimesh() -> tuple[np.ndarray, np.ndarray]:
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        xyz, face, bary = trimesh.sample.sample_surface(mesh, n, return_barycentric=True, seed=1)
        corners = colours[faces[face]].astype(np.float32)
        rgb = np.einsum("kc,kcd->kd", bary.astype(np.float32), corners)
        _ = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
        _ = labels[faces[face, bary.argmax(1)]]
        return xyz, face

    t_bare, _ = best_of(lambda: sample_pieces([bare], n))
    t_own, own = best_of(lambda: sample_pieces([piece], n))
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    t_tm_bare, _ = best_of(lambda: trimesh.sample.sample_surface(mesh, n, seed=1))
    t_tm, (tm_xyz, tm_face) = best_of(with_trimesh)
    # the own sampler's triangle per point, recovered from its stratified positions
    areas = bare.areas()
    expected = areas / areas.sum() * n
    own_face = np.searchsorted(np.cumsum(areas), _own_where(n, areas), side="right")
    rows = (
        ("jointseg, xyz only", t_bare, own.xyz, own_face),
        ("jointseg, + colour and labels", t_own, own.xyz, own_face),
        ("trimesh sample_surface, xyz only", t_tm_bare, tm_xyz, tm_face),
        ("trimesh, + Trimesh, colour and labels", t_tm, tm_xyz, tm_face),
    )
    print(f"{'sampler':40} {'s':>6} {'CV/4cm':>7} {'empty':>6} {'bare tri':>9} {'max |dev|':>9}")
    for name, seconds, xyz, face in rows:
        cv, empty = evenness(xyz)
        count = np.bincount(np.minimum(face, len(faces) - 1), minlength=len(faces))
        dev = float(np.abs(count - expected).max())
        print(f"{name:40} {seconds:6.3f} {cv:7.3f} {empty:6d} {(count == 0).sum():9d} {dev:9.1f}")


def _own_where(n: int, areas: np.ndarray) -> np.ndarray:
    """The positions on the cumulative area :func:`sample_pieces` draws (same seed, same rng)."""
    from jointseg.io.formats.mesh.sample import SAMPLE_SEED

    rng = np.random.default_rng(SAMPLE_SEED)
    return (np.arange(n, dtype=np.float64) + rng.random(n)) * (float(areas.sum()) / n)


if __name__ == "__main__":
    main()
