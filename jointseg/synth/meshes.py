"""Triangle-soup builder that keeps class, instance, colour and material per triangle.

Every surface of a synthetic scene is a box, a prism or a blob; the builder turns batches of them
into one vertex/triangle array pair plus per-triangle attribute arrays, so that a ray hit's
``primitive_id`` is all that is needed to look up what was hit. All builders are vectorised over
the batch: a bookcase's hundred books are one call.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

#: Unit-cube corners, index = bx + 2 * by + 4 * bz.
_CORNERS = np.array([[(i & 1) - 0.5, ((i >> 1) & 1) - 0.5, ((i >> 2) & 1) - 0.5] for i in range(8)])
#: Outward-wound triangles of the unit cube, two per face in the order +x, -x, +y, -y, +z, -z.
_BOX_TRIS = np.array(
    [
        [1, 3, 7],
        [1, 7, 5],
        [0, 4, 6],
        [0, 6, 2],
        [2, 6, 7],
        [2, 7, 3],
        [0, 1, 5],
        [0, 5, 4],
        [4, 5, 7],
        [4, 7, 6],
        [0, 2, 3],
        [0, 3, 1],
    ],
    dtype=np.int64,
)
#: Face index (0..5 = +x, -x, +y, -y, +z, -z) of each box triangle.
BOX_TRI_FACE = np.repeat(np.arange(6), 2)
#: Outward unit normal of each box face in the box's own frame.
BOX_FACE_NORMALS = np.array(
    [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64
)


def _uv_sphere(n_lat: int = 7, n_lon: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Unit UV sphere (vertices, outward-wound triangles) used as the template for blobs."""
    lat = np.pi * (np.arange(1, n_lat) / n_lat)
    lon = 2 * np.pi * np.arange(n_lon) / n_lon
    sl, cl = np.sin(lat)[:, None], np.cos(lat)[:, None]
    ring = np.stack(
        [sl * np.cos(lon)[None], sl * np.sin(lon)[None], cl * np.ones_like(lon)[None]], axis=-1
    ).reshape(-1, 3)
    unit = np.concatenate([[[0.0, 0.0, 1.0]], ring, [[0.0, 0.0, -1.0]]])
    last = unit.shape[0] - 1
    tris = [[0, 1 + b, 1 + (b + 1) % n_lon] for b in range(n_lon)]
    for a in range(n_lat - 2):
        for b in range(n_lon):
            p, q = 1 + a * n_lon + b, 1 + a * n_lon + (b + 1) % n_lon
            tris.append([p, p + n_lon, q + n_lon])
            tris.append([p, q + n_lon, q])
    base = 1 + (n_lat - 2) * n_lon
    tris += [[base + b, last, base + (b + 1) % n_lon] for b in range(n_lon)]
    return unit, np.asarray(tris, dtype=np.int64)


_SPHERE = _uv_sphere()


@dataclass(frozen=True)
class SceneMesh:
    """All triangles of a scene with the attributes a ray hit needs.

    Attributes
    ----------
    vertices : ndarray (V, 3) float32
    triangles : ndarray (T, 3) uint32
    label : ndarray (T,) int32
        S3DIS class per triangle.
    instance : ndarray (T,) int32
        Object id per triangle.
    colour : ndarray (T, 3) float32
        Base colour in [0, 1] before texture and lighting.
    material : ndarray (T,) uint8
        Texture kind (see :mod:`jointseg.synth.appearance`).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    label: np.ndarray
    instance: np.ndarray
    colour: np.ndarray
    material: np.ndarray

    @property
    def n_triangles(self) -> int:
        """Number of triangles."""
        return int(self.triangles.shape[0])


@dataclass(frozen=True)
class Pose:
    """Placement of an object: position of its local origin on the floor and yaw (radians).

    Local frame convention: +y is the object's front (a chair faces +y, a bookcase opens to
    +y); objects backed onto a wall use the wall's inward normal as local +y.
    """

    x: float
    y: float
    yaw: float = 0.0
    z: float = 0.0

    def world(self, local: ArrayLike) -> np.ndarray:
        """Map local points (k, 3) to scene coordinates."""
        local = np.atleast_2d(np.asarray(local, dtype=np.float64))
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        out = np.empty_like(local)
        out[:, 0] = self.x + c * local[:, 0] - s * local[:, 1]
        out[:, 1] = self.y + s * local[:, 0] + c * local[:, 1]
        out[:, 2] = self.z + local[:, 2]
        return out

    def aabb(
        self, x0: float, y0: float, x1: float, y1: float, z0: float, z1: float
    ) -> tuple[float, float, float, float, float, float]:
        """Scene axis-aligned box around the local box [x0, x1] x [y0, y1] x [z0, z1]."""
        corners = np.array([[x0, y0, z0], [x1, y0, z0], [x0, y1, z0], [x1, y1, z0]])
        w = self.world(corners)
        return (
            float(w[:, 0].min()),
            float(w[:, 1].min()),
            self.z + z0,
            float(w[:, 0].max()),
            float(w[:, 1].max()),
            self.z + z1,
        )


def _per_item(value: ArrayLike, k: int, width: int | None = None) -> np.ndarray:
    """Broadcast a scalar / per-item attribute to ``k`` rows."""
    arr = np.asarray(value, dtype=np.float64)
    shape = (k,) if width is None else (k, width)
    return np.broadcast_to(arr, shape)


class MeshBuilder:
    """Collect boxes, prisms and blobs with attributes, then emit one :class:`SceneMesh`.

    Attribute arguments (``label``, ``instance``, ``colour``, ``material``) are either one value
    for the whole batch or one value per item.
    """

    def __init__(self) -> None:
        self._verts: list[np.ndarray] = []
        self._tris: list[np.ndarray] = []
        self._label: list[np.ndarray] = []
        self._instance: list[np.ndarray] = []
        self._colour: list[np.ndarray] = []
        self._material: list[np.ndarray] = []
        self._n_verts = 0

    def _append(
        self,
        verts: np.ndarray,
        tris: np.ndarray,
        label: np.ndarray,
        instance: np.ndarray,
        colour: ArrayLike,
        material: np.ndarray,
    ) -> None:
        self._verts.append(verts.reshape(-1, 3))
        self._tris.append(tris.reshape(-1, 3) + self._n_verts)
        self._label.append(np.asarray(label, dtype=np.int32).reshape(-1))
        self._instance.append(np.asarray(instance, dtype=np.int32).reshape(-1))
        self._colour.append(np.asarray(colour, dtype=np.float32).reshape(-1, 3))
        self._material.append(np.asarray(material, dtype=np.uint8).reshape(-1))
        self._n_verts += verts.reshape(-1, 3).shape[0]

    def add_boxes(
        self,
        centers: ArrayLike,
        sizes: ArrayLike,
        yaws: ArrayLike = 0.0,
        *,
        label: ArrayLike,
        instance: ArrayLike,
        colour: ArrayLike,
        material: ArrayLike = 0,
        face_instance: ArrayLike | None = None,
        face_colour: ArrayLike | None = None,
        face_mask: ArrayLike | None = None,
    ) -> None:
        """Add ``k`` boxes rotated by ``yaws`` (radians) about their vertical axis.

        Parameters
        ----------
        centers, sizes : array (k, 3)
        yaws : float or array (k,)
        face_instance : array (k, 6), optional
            Instance per face (+x, -x, +y, -y, +z, -z), overriding ``instance``.
        face_colour : array (k, 6, 3), optional
            Colour per face, overriding ``colour``.
        face_mask : bool array (k, 6), optional
            Faces to emit; hidden faces can be left out.
        """
        centers = np.atleast_2d(np.asarray(centers, dtype=np.float64))
        k = centers.shape[0]
        if k == 0:
            return
        sizes = _per_item(sizes, k, 3)
        yaws = _per_item(yaws, k)
        c, s = np.cos(yaws), np.sin(yaws)
        local = _CORNERS[None, :, :] * sizes[:, None, :]
        verts = np.empty_like(local)
        verts[..., 0] = c[:, None] * local[..., 0] - s[:, None] * local[..., 1]
        verts[..., 1] = s[:, None] * local[..., 0] + c[:, None] * local[..., 1]
        verts[..., 2] = local[..., 2]
        verts += centers[:, None, :]
        tris = _BOX_TRIS[None, :, :] + 8 * np.arange(k)[:, None, None]
        lab = np.repeat(_per_item(label, k), 12).reshape(k, 12)
        if face_instance is not None:
            inst = np.asarray(face_instance)[:, BOX_TRI_FACE]
        else:
            inst = np.repeat(_per_item(instance, k), 12).reshape(k, 12)
        if face_colour is not None:
            col = np.asarray(face_colour)[:, BOX_TRI_FACE, :]
        else:
            col = np.repeat(_per_item(colour, k, 3), 12, axis=0).reshape(k, 12, 3)
        mat = np.repeat(_per_item(material, k), 12).reshape(k, 12)
        if face_mask is not None:
            keep = np.asarray(face_mask, dtype=bool)[:, BOX_TRI_FACE]
            tris, lab, inst, col, mat = tris[keep], lab[keep], inst[keep], col[keep], mat[keep]
        self._append(verts, tris, lab, inst, col, mat)

    def add_local_boxes(
        self,
        pose: Pose,
        centers: ArrayLike,
        sizes: ArrayLike,
        yaws: ArrayLike = 0.0,
        **attrs: Any,
    ) -> None:
        """Add boxes given in the local frame of ``pose`` (see :meth:`add_boxes`)."""
        self.add_boxes(pose.world(centers), sizes, np.asarray(yaws) + pose.yaw, **attrs)

    def add_prisms(
        self,
        bottoms: ArrayLike,
        radii: ArrayLike,
        heights: ArrayLike,
        *,
        sides: int = 12,
        label: ArrayLike,
        instance: ArrayLike,
        colour: ArrayLike,
        material: ArrayLike = 0,
        top_radii: ArrayLike | None = None,
    ) -> None:
        """Add ``k`` vertical n-gon prisms (cylinders, cones, bins) standing on ``bottoms``."""
        bottoms = np.atleast_2d(np.asarray(bottoms, dtype=np.float64))
        k = bottoms.shape[0]
        if k == 0:
            return
        r0 = _per_item(radii, k)
        r1 = r0 if top_radii is None else _per_item(top_radii, k)
        h = _per_item(heights, k)
        ang = 2 * np.pi * np.arange(sides) / sides
        ring = np.stack([np.cos(ang), np.sin(ang)], axis=1)
        verts = np.zeros((k, 2 * sides + 2, 3))
        verts[:, :sides, :2] = ring[None] * r0[:, None, None]
        verts[:, sides : 2 * sides, :2] = ring[None] * r1[:, None, None]
        verts[:, sides : 2 * sides, 2] = h[:, None]
        verts[:, 2 * sides + 1, 2] = h
        verts += bottoms[:, None, :]
        i = np.arange(sides)
        j = (i + 1) % sides
        side_a = np.stack([i, j, sides + j], axis=1)
        side_b = np.stack([i, sides + j, sides + i], axis=1)
        bottom = np.stack([np.full(sides, 2 * sides), j, i], axis=1)
        top = np.stack([np.full(sides, 2 * sides + 1), sides + i, sides + j], axis=1)
        one = np.concatenate([side_a, side_b, bottom, top])
        nt = one.shape[0]
        tris = one[None] + (2 * sides + 2) * np.arange(k)[:, None, None]
        self._append(
            verts,
            tris,
            np.repeat(_per_item(label, k), nt),
            np.repeat(_per_item(instance, k), nt),
            np.repeat(_per_item(colour, k, 3), nt, axis=0),
            np.repeat(_per_item(material, k), nt),
        )

    def add_blob(
        self,
        center: ArrayLike,
        radii: ArrayLike,
        rng: np.random.Generator,
        *,
        roughness: float = 0.25,
        label: int,
        instance: int,
        colour: ArrayLike,
        material: int = 0,
    ) -> None:
        """Add one lumpy ellipsoid (plant foliage, a bag): a UV sphere with radial noise."""
        unit, tri = _SPHERE
        scale = 1.0 + roughness * np.asarray(rng.uniform(-1.0, 1.0, unit.shape[0]))
        verts = unit * scale[:, None] * np.asarray(radii)[None] + np.asarray(center)[None]
        nt = tri.shape[0]
        self._append(
            verts,
            tri,
            np.full(nt, label),
            np.full(nt, instance),
            np.broadcast_to(np.asarray(colour), (nt, 3)),
            np.full(nt, material),
        )

    def build(self) -> SceneMesh:
        """Concatenate everything added so far into one :class:`SceneMesh`."""
        if not self._verts:
            raise ValueError("the scene has no geometry")
        return SceneMesh(
            vertices=np.concatenate(self._verts).astype(np.float32),
            triangles=np.concatenate(self._tris).astype(np.uint32),
            label=np.concatenate(self._label),
            instance=np.concatenate(self._instance),
            colour=np.concatenate(self._colour),
            material=np.concatenate(self._material),
        )
