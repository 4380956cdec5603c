"""Points sampled on the triangles of a mesh, with the colour the mesh gives each spot.

The network was trained on scans whose points lie a few millimetres to a few centimetres apart
and sub-samples every input to its 4 cm grid (:mod:`jointseg.network.randlanet.params`), so a
mesh is turned into points clearly finer than that grid: a mean spacing of
:data:`SAMPLE_SPACING`. Sampling is area-weighted and stratified (every triangle gets its share
of the points give or take one) and seeded, so the same file always gives the same points.
A piece whose vertices carry labels or other values (a PLY mesh's vertex properties) hands
each point those of its triangle's nearest corner (the largest barycentric weight). Pure
numpy: the trimesh side (reading files, materials) is in :mod:`jointseg.io.formats.mesh.core`.

Why not trimesh's ``trimesh.sample.sample_surface`` (issue 69, measured by
``bench/mesh_sampling.py``: a 200 k-triangle floor, 1 M points, 2 shared cores): trimesh draws
each point's triangle independently, so the points clump and gap (coefficient of variation of
the points per 4 cm network cell 0.31 against 0.23 here; up to 14 points off a triangle's share
against fewer than 2 here; 14,835 triangles left bare against 6,571); it samples one
``Trimesh``, so a scene's pieces would be concatenated first; and with the barycentric weights
asked for and the colours and labels carried on top it took 0.50 s against 0.20 s here (0.33 s
against 0.12 s for coordinates alone; about 2.5 times on every run). Both are seeded. What is
kept is this stratified draw and the colour, label and field carrying that trimesh does not do
(its ``sample_color`` covers textures and face colours only).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from jointseg.classes import UNLABELLED

logger = logging.getLogger(__name__)

#: Mean distance between sampled points (file units, metres for glTF): about a third of the
#: network's 4 cm grid, so every grid cell on a surface holds several points, as in a real scan.
SAMPLE_SPACING = 0.012
#: The seed of every mesh sampling: the same file gives the same points.
SAMPLE_SEED = 20_241_041

ColourKind = Literal["vertex", "face", "texture", "material", "none"]
#: Colour of triangles that have none when others in the same file do (trimesh's default grey).
NO_COLOUR = np.array([102, 102, 102], dtype=np.uint8)


@dataclass(frozen=True)
class PieceColour:
    """How one piece of a mesh is coloured.

    Attributes
    ----------
    kind : {"vertex", "face", "texture", "material", "none"}
    values : ndarray of uint8, optional
        (V, 3) per vertex, (F, 3) per face, or (3,) for the whole piece (material).
    uv : ndarray (V, 2) float, optional
        Texture coordinates per vertex (``texture``).
    image : ndarray (H, W, 3) uint8, optional
        The texture (``texture``).
    factor : ndarray (3,) float, optional
        Multiplies the texture's colour (glTF's ``baseColorFactor``).
    """

    kind: ColourKind = "none"
    values: np.ndarray | None = None
    uv: np.ndarray | None = None
    image: np.ndarray | None = None
    factor: np.ndarray | None = None

    def at(self, faces: np.ndarray, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """The 8-bit RGB at sampled points (``face`` per point, ``bary`` (k, 3) weights)."""
        if self.kind == "vertex" and self.values is not None:
            corners = self.values[faces[face]].astype(np.float32)
            return _to_u8(np.einsum("kc,kcd->kd", bary.astype(np.float32), corners))
        if self.kind == "face" and self.values is not None:
            return self.values[face]
        if self.kind == "texture" and self.uv is not None and self.image is not None:
            uv = np.einsum("kc,kcd->kd", bary, self.uv[faces[face]])
            rgb = texel(self.image, uv)
            return rgb if self.factor is None else _to_u8(rgb * self.factor)
        if self.kind == "material" and self.values is not None:
            return np.broadcast_to(self.values, (face.size, 3))
        return np.broadcast_to(NO_COLOUR, (face.size, 3))


def _to_u8(values: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(values), 0, 255).astype(np.uint8)


def texel(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The nearest texel at each UV (glTF/OBJ convention: v = 0 at the image's bottom row;
    coordinates outside [0, 1] repeat, as the default sampler wraps)."""
    height, width = image.shape[:2]
    x = np.rint((uv[:, 0] % 1.0) * (width - 1)).astype(np.int64)
    y = np.rint((1.0 - uv[:, 1] % 1.0) * (height - 1)).astype(np.int64)
    return image[np.clip(y, 0, height - 1), np.clip(x, 0, width - 1), :3]


@dataclass(frozen=True)
class MeshPiece:
    """One triangle mesh of a file, in the file's frame (node transforms applied).

    Attributes
    ----------
    vertices : ndarray (V, 3) float64
    faces : ndarray (F, 3) int64
        Checked to index ``vertices``.
    colour : PieceColour
    labels : ndarray (V,) int32, optional
        Ground-truth label of each vertex (S3DIS classes, -1 unlabelled).
    fields : dict of str to ndarray (V,) or (V, k)
        Other values of each vertex, carried to the points like ``labels``.
    """

    vertices: np.ndarray
    faces: np.ndarray
    colour: PieceColour
    labels: np.ndarray | None = None
    fields: dict[str, np.ndarray] = field(default_factory=dict)

    def areas(self) -> np.ndarray:
        """Area of each triangle."""
        tri = self.vertices[self.faces]
        return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


@dataclass(frozen=True)
class SamplePlan:
    """How many points a mesh gets and how far apart they are on average.

    Attributes
    ----------
    points : int
        Points to sample: area / spacing², at most ``max_points``.
    spacing : float
        Mean spacing those points have (:data:`SAMPLE_SPACING`, or coarser when capped).
    area : float
        Total area of the triangles (file units squared).
    """

    points: int
    spacing: float
    area: float


def plan_samples(area: float, max_points: int, path: Path) -> SamplePlan:
    """Points for a mesh of total ``area``: :data:`SAMPLE_SPACING` apart, capped by
    ``max_points`` (the spacing then grows, and the log says so)."""
    wanted = max(1, math.ceil(area / SAMPLE_SPACING**2))
    if wanted <= max_points:
        return SamplePlan(wanted, SAMPLE_SPACING, area)
    spacing = math.sqrt(area / max_points)
    logger.warning(
        "%s: the mesh's %.4g units² would take %d points at a %.3g spacing, more than "
        "max_points=%d; sampling %d points at a %.3g spacing instead",
        path,
        area,
        wanted,
        SAMPLE_SPACING,
        max_points,
        max_points,
        spacing,
    )
    return SamplePlan(max_points, spacing, area)


@dataclass(frozen=True)
class MeshSamples:
    """Points sampled on a mesh and what each point carries.

    Attributes
    ----------
    xyz : ndarray (n, 3) float64
    rgb : ndarray (n, 3) uint8, optional
        None when no piece has colour.
    labels : ndarray (n,) int32, optional
        The label of each point's nearest triangle corner; None when no piece has labels
        (points of a piece without labels are -1).
    fields : dict of str to ndarray
        The fields every piece carries (:func:`carried_fields`), nearest corner's value.
    """

    xyz: np.ndarray
    rgb: np.ndarray | None = None
    labels: np.ndarray | None = None
    fields: dict[str, np.ndarray] = field(default_factory=dict)


def carried_fields(pieces: list[MeshPiece]) -> dict[str, np.ndarray]:
    """The vertex fields sampled points carry: those every piece has, with one shape per row.

    Returns
    -------
    dict of str to ndarray
        Name to an empty array of the points' dtype and row shape, in the first piece's order.
    """
    if not pieces:
        return {}
    carried: dict[str, np.ndarray] = {}
    for name, values in pieces[0].fields.items():
        columns = [piece.fields.get(name) for piece in pieces]
        if any(c is None or c.shape[1:] != values.shape[1:] for c in columns):
            continue
        dtype = np.result_type(*[c.dtype for c in columns if c is not None])
        carried[name] = np.empty((0, *values.shape[1:]), dtype=dtype)
    return carried


def _carry(
    pieces: list[MeshPiece], corner: list[np.ndarray], runs: list[slice], n: int
) -> tuple[np.ndarray | None, dict[str, np.ndarray]]:
    """Labels and fields of the points: each from the vertex ``corner`` names in its piece.

    Parameters
    ----------
    pieces : list of MeshPiece
    corner : list of ndarray of int64
        Per piece, the vertex (of that piece) nearest to each of its points.
    runs : list of slice
        Per piece, where its points are among the ``n``.
    n : int
        All points.
    """
    labels = None
    if any(piece.labels is not None for piece in pieces):
        labels = np.full(n, UNLABELLED, dtype=np.int32)
    fields = {
        name: np.empty((n, *like.shape[1:]), like.dtype)
        for name, like in carried_fields(pieces).items()
    }
    for piece, vertex, run in zip(pieces, corner, runs, strict=True):
        if labels is not None and piece.labels is not None:
            labels[run] = piece.labels[vertex]
        for name, values in fields.items():
            values[run] = piece.fields[name][vertex]
    return labels, fields


def sample_pieces(pieces: list[MeshPiece], n: int, *, seed: int = SAMPLE_SEED) -> MeshSamples:
    """``n`` points on the pieces' triangles, area-weighted and stratified, with their colours,
    and the labels and fields of the pieces' vertices (nearest corner).

    The points are stratified along the triangles in file order (point k falls at a jittered
    position k + u of n on the cumulative area), so every triangle gets its share of ``n``
    give or take one, and points come out grouped by triangle.

    Parameters
    ----------
    pieces : list of MeshPiece
        With at least one triangle of non-zero area among them.
    n : int
        Points to sample (≥ 1).
    seed : int
        The sampling's randomness.

    Returns
    -------
    MeshSamples
    """
    rng = np.random.default_rng(seed)
    areas = [piece.areas() for piece in pieces]
    cumulative = np.cumsum(np.concatenate(areas))
    total = float(cumulative[-1])
    where = (np.arange(n, dtype=np.float64) + rng.random(n)) * (total / n)
    face = np.minimum(np.searchsorted(cumulative, where, side="right"), cumulative.size - 1)
    r1, r2 = rng.random(n), rng.random(n)
    root = np.sqrt(r1)
    bary = np.stack([1.0 - root, root * (1.0 - r2), root * r2], axis=1)
    nearest = bary.argmax(axis=1)  # the corner with the largest weight is the nearest one
    offsets = np.cumsum([0] + [a.size for a in areas])
    bounds = np.searchsorted(face, offsets)  # samples are sorted by face, so pieces are runs
    xyz = np.empty((n, 3), dtype=np.float64)
    coloured = any(piece.colour.kind != "none" for piece in pieces)
    rgb = np.empty((n, 3), dtype=np.uint8) if coloured else None
    runs = [slice(int(bounds[i]), int(bounds[i + 1])) for i in range(len(pieces))]
    corner: list[np.ndarray] = []
    for i, (piece, run) in enumerate(zip(pieces, runs, strict=True)):
        local = face[run] - offsets[i]
        corners = piece.vertices[piece.faces[local]]
        xyz[run] = np.einsum("kc,kcd->kd", bary[run], corners)
        corner.append(piece.faces[local, nearest[run]])
        if rgb is not None:
            rgb[run] = piece.colour.at(piece.faces, local, bary[run])
    labels, fields = _carry(pieces, corner, runs, n)
    return MeshSamples(xyz, rgb, labels, fields)


def main_colour_kind(pieces: list[MeshPiece]) -> ColourKind:
    """The colour kind of the pieces covering the most area (``none`` when none has colour)."""
    share: dict[ColourKind, float] = {}
    for piece in pieces:
        if piece.colour.kind != "none":
            share[piece.colour.kind] = share.get(piece.colour.kind, 0.0) + float(
                piece.areas().sum()
            )
    return max(share, key=lambda kind: share[kind]) if share else "none"
