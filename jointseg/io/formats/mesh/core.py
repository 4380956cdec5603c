"""Meshes as scans: GLB/glTF, OBJ and PLY with faces, read through trimesh and sampled to points.

Phone scanning apps (Polycam, Scaniverse, 3D Scanner App, Record3D, ARKit exports) deliver
textured triangle meshes more often than point clouds. The network needs points at a real
scan's density, so each mesh is flattened to one frame (node transforms applied, several
meshes joined) and sampled on its triangles (:mod:`jointseg.io.formats.mesh.sample`), coloured by
its vertex colours, face colours, texture or material. The points stay in the file's own
coordinates: glTF's y-up convention and metre unit are recorded in ``Scan.meta`` for the frame
stage, never applied here.

A PLY mesh whose vertex element has labels (``label``, ``class``, ... as :func:`read_ply
<jointseg.io.formats.ply.core.read_ply>` recognises them; e.g. ScanNet's
``*_vh_clean_2.labels.ply``) keeps them: each sampled point takes the label of its triangle's
nearest vertex, and so the values of the vertex's other scalar properties as fields (coordinates,
colours and normals aside).

``Scan.meta`` of a mesh holds ``comments`` (PLY ``comment``/``obj_info`` lines, the OBJ's
leading ``#`` lines, glTF's ``generator``/``copyright``), ``mesh`` (vertices, faces, area,
sampled points, spacing, colour kind, and ``labels: "nearest vertex"`` when labels were
carried) and, for glTF, ``up_convention``, ``units`` and ``units_source``. A file with vertices
but no triangles (an OBJ point cloud) is read as points.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.exceptions import ScanFormatError, library_reason
from jointseg.io.build import build_scan
from jointseg.io.formats.mesh.gltf import GltfFacts, check_neighbours, embedded_only, gltf_facts
from jointseg.io.formats.mesh.sample import (
    MeshPiece,
    MeshSamples,
    PieceColour,
    SamplePlan,
    carried_fields,
    main_colour_kind,
    plan_samples,
    sample_pieces,
)
from jointseg.io.formats.ply.core import (
    split_vertex,
    vertex_columns,
)
from jointseg.io.limits import ScanInfo, check_input_file, check_max_points
from jointseg.progress import ProgressFn, report
from jointseg.scan import Scan

logger = logging.getLogger(__name__)

#: What ``Scan.meta`` says about a glTF file's axes and unit, both fixed by the specification.
GLTF_UP = {"axis": "+y", "source": "glTF 2.0 (y up by specification)"}
GLTF_UNITS = {"units": "m", "units_source": "glTF 2.0 (metres by specification)"}
#: At most this many leading ``#`` lines of an OBJ file are kept as comments.
MAX_OBJ_COMMENTS = 50
#: PLY vertex properties (lower case) never carried to sampled points, besides the coordinates
#: and the colour channels: normals, and colour's alpha.
NOT_CARRIED = frozenset({"nx", "ny", "nz", "normal_x", "normal_y", "normal_z", "alpha"})
#: What ``Scan.meta["mesh"]["labels"]`` says when a PLY mesh's vertex labels were carried.
LABELS_CARRIED = "nearest vertex"


@dataclass
class LoadedMesh:
    """A mesh file flattened to one frame: its triangle pieces, or its bare vertices.

    Attributes
    ----------
    pieces : list of MeshPiece
        Every triangle mesh, node transforms applied.
    points : ndarray (P, 3), optional
        Vertices of a file without triangles (read as points).
    points_rgb : ndarray (P, 3) uint8, optional
    vertices, faces : int
        Totals over the pieces (or the bare vertices).
    """

    pieces: list[MeshPiece] = field(default_factory=list)
    points: np.ndarray | None = None
    points_rgb: np.ndarray | None = None
    vertices: int = 0
    faces: int = 0


def check_mesh_size(path: Path, vertices: int, faces: int, max_points: int) -> None:
    """Refuse a mesh whose vertices or triangles outnumber ``max_points`` before it is decoded.

    A mesh is held in memory whole while it is sampled, at about the cost of one point per
    vertex and per triangle, so the limit on points bounds it too.

    Raises
    ------
    ScanFormatError
    """
    for count, what in ((faces, "triangles"), (vertices, "vertices")):
        if count > max_points:
            raise ScanFormatError(
                f"{path}: the mesh has {count:,} {what}, more than max_points={max_points:,} "
                f"(a mesh is held in memory whole while it is sampled); pass a larger "
                f"max_points or simplify the mesh first"
            )


def _load_scene(path: Path, fmt: str) -> Any:
    """trimesh's scene of the file; any error of trimesh's readers becomes a ScanFormatError."""
    import trimesh

    try:
        return trimesh.load(str(path), file_type=fmt, force="scene", process=False)
    except MemoryError:
        raise
    except Exception as exc:  # trimesh's readers raise whatever their parsing meets
        raise ScanFormatError(
            f"{path}: cannot read the {fmt.upper()} mesh: {library_reason(exc)}"
        ) from exc


def _material_colour(material: Any) -> np.ndarray | None:
    """A material's one colour: glTF's base colour factor (white when absent, as the
    specification says), else an OBJ material's diffuse colour (``Kd``)."""
    from trimesh.visual.material import PBRMaterial

    if isinstance(material, PBRMaterial):
        factor = material.baseColorFactor
        return (
            np.full(3, 255, np.uint8) if factor is None else np.asarray(factor)[:3].astype(np.uint8)
        )
    diffuse = getattr(material, "diffuse", None)
    return None if diffuse is None else np.asarray(diffuse)[:3].astype(np.uint8)


def _texture_colour(visual: Any, n_vertices: int) -> PieceColour | None:
    """The texture of a textured piece, when it has an image and one UV per vertex."""
    from trimesh.visual.material import PBRMaterial

    material = visual.material
    if isinstance(material, PBRMaterial):
        image = material.baseColorTexture
        factor = material.baseColorFactor
    else:
        image, factor = getattr(material, "image", None), None
    uv = None if visual.uv is None else np.asarray(visual.uv, dtype=np.float64)
    if image is None or uv is None or uv.shape != (n_vertices, 2):
        return None
    rgb = np.asarray(image.convert("RGB"), dtype=np.uint8)
    scale = None if factor is None else np.asarray(factor)[:3].astype(np.float64) / 255.0
    if scale is not None and np.all(scale == 1.0):
        scale = None
    return PieceColour("texture", uv=uv, image=rgb, factor=scale)


def piece_colour(geometry: Any) -> PieceColour:
    """How trimesh says ``geometry`` is coloured, as a :class:`PieceColour`."""
    from trimesh.visual import TextureVisuals

    visual = geometry.visual
    if isinstance(visual, TextureVisuals):
        texture = _texture_colour(visual, len(geometry.vertices))
        if texture is not None:
            return texture
        colour = _material_colour(visual.material)
        return PieceColour() if colour is None else PieceColour("material", values=colour)
    if visual.kind == "vertex":
        return PieceColour(
            "vertex", values=np.asarray(visual.vertex_colors)[:, :3].astype(np.uint8)
        )
    if visual.kind == "face":
        return PieceColour("face", values=np.asarray(visual.face_colors)[:, :3].astype(np.uint8))
    return PieceColour()


def _checked_piece(path: Path, geometry: Any, name: str) -> MeshPiece:
    """One triangle mesh with its vertices finite and its faces indexing them."""
    vertices = np.asarray(geometry.vertices, dtype=np.float64)
    faces = np.asarray(geometry.faces, dtype=np.int64).reshape(-1, 3)
    where = f" of mesh {name!r}" if name else ""
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        raise ScanFormatError(
            f"{path}: vertex {bad}{where} has non-finite coordinates {vertices[bad].tolist()} "
            f"({int((~finite).sum()):,} of its {len(vertices):,} vertices are NaN or infinite); "
            f"coordinates must be finite numbers"
        )
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        row = int(np.flatnonzero(((faces < 0) | (faces >= len(vertices))).any(axis=1))[0])
        raise ScanFormatError(
            f"{path}: triangle {row}{where} refers to vertices {faces[row].tolist()}, but the "
            f"mesh has {len(vertices):,} vertices (0..{len(vertices) - 1})"
        )
    return MeshPiece(vertices, faces, piece_colour(geometry))


def _ply_records(geometry: Any) -> np.ndarray | None:
    """The PLY vertex element trimesh read for ``geometry``, as one structured array.

    trimesh keeps the parsed elements in ``metadata["_ply_raw"]``: a structured array from a
    binary file, a dict of (V, 1) columns from an ASCII one. None when neither is there.
    """
    raw = geometry.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    if isinstance(raw, np.ndarray) and raw.dtype.names:
        return raw
    if not isinstance(raw, dict) or not raw:
        return None
    columns = {str(k): np.asarray(v) for k, v in raw.items()}
    rows = {c.shape[0] for c in columns.values()}
    if len(rows) != 1 or any(c.ndim > 2 or c[:1].size > 1 for c in columns.values()):
        return None
    records = np.empty(rows.pop(), dtype=[(k, c.dtype) for k, c in columns.items()])
    for name, column in columns.items():
        records[name] = column.reshape(-1)
    return records


def _file_vertices(vertices: np.ndarray, file_xyz: np.ndarray) -> np.ndarray | None:
    """For each of a piece's vertices, the index of the file's vertex it came from.

    trimesh keeps the file's vertices as they are, except that a PLY with per-face texture
    coordinates has its vertices split by UV (copies of file vertices): those are found by
    their exact coordinates. None when some vertex matches none of the file's.
    """
    if vertices.shape == file_xyz.shape and np.array_equal(vertices, file_xyz):
        return np.arange(len(vertices))
    both = np.concatenate([file_xyz, vertices])
    _, first, inverse = np.unique(both, axis=0, return_index=True, return_inverse=True)
    index = first[inverse.reshape(-1)[len(file_xyz) :]]
    return index if (index < len(file_xyz)).all() else None


def _carried_names(names: list[str]) -> list[str]:
    """The vertex properties read for carrying: all but colour channels, alpha and normals."""
    colour, _ = vertex_columns(names)
    skip = {n.lower() for n in colour or ()} | NOT_CARRIED
    return [n for n in names if n.lower() not in skip]


def _with_vertex_values(path: Path, piece: MeshPiece, geometry: Any) -> MeshPiece:
    """``piece`` with the labels and other scalar numeric properties of its PLY vertices.

    Read as :func:`jointseg.io.formats.ply.core.read_ply` reads a point cloud's (labels as S3DIS
    classes, the raw values kept as field ``raw_label`` when some are no class). A piece whose
    vertex element has no label property is returned as it is.
    """
    records = _ply_records(geometry)
    if records is None:
        logger.debug("%s: trimesh kept no PLY vertex element; nothing carried", path)
        return piece
    names = [n for n in records.dtype.names or () if records.dtype[n].kind in "iuf"]
    if vertex_columns(names)[1] is None:
        return piece
    xyz, _, labels, fields = split_vertex(records[_carried_names(names)], path)
    index = _file_vertices(piece.vertices, xyz)
    if index is None or labels is None:
        logger.warning(
            "%s: the mesh's vertices do not match its PLY vertex element; labels not carried",
            path,
        )
        return piece
    return replace(piece, labels=labels[index], fields={k: v[index] for k, v in fields.items()})


def _bare_points(clouds: list[Any]) -> tuple[np.ndarray, np.ndarray | None]:
    """The vertices of a file without triangles, with their colours when all have them."""
    xyz = np.concatenate([np.asarray(c.vertices, dtype=np.float64) for c in clouds])
    colours = [np.asarray(getattr(c, "colors", ())) for c in clouds]
    if all(c.ndim == 2 and len(c) == len(g.vertices) for c, g in zip(colours, clouds, strict=True)):
        return xyz, np.concatenate([c[:, :3] for c in colours]).astype(np.uint8)
    return xyz, None


def load_mesh(path: Path, fmt: str) -> LoadedMesh:
    """Read a mesh file through trimesh and flatten it: node transforms applied, checked.

    Parameters
    ----------
    path : Path
    fmt : {"glb", "gltf", "obj", "ply"}
        trimesh's reader to use.

    Returns
    -------
    LoadedMesh

    Raises
    ------
    ScanFormatError
        When trimesh cannot read the file, a vertex is not finite, a triangle refers to a
        vertex that does not exist, or the file holds neither triangles nor vertices.
    """
    import trimesh

    geometries = _load_scene(path, fmt).dump()
    meshes = [g for g in geometries if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    several = len(meshes) > 1
    pieces = [
        _checked_piece(path, g, str(g.metadata.get("name", "")) if several else "") for g in meshes
    ]
    if fmt == "ply":
        pieces = [_with_vertex_values(path, p, g) for p, g in zip(pieces, meshes, strict=True)]
    if pieces:
        return LoadedMesh(
            pieces,
            vertices=sum(len(p.vertices) for p in pieces),
            faces=sum(len(p.faces) for p in pieces),
        )
    clouds = [g for g in geometries if len(getattr(g, "vertices", ())) and hasattr(g, "colors")]
    clouds += [g for g in geometries if isinstance(g, trimesh.Trimesh) and len(g.vertices)]
    if not clouds:
        raise ScanFormatError(
            f"{path}: the {fmt.upper()} file holds no mesh: no triangles and no vertices"
        )
    xyz, rgb = _bare_points(clouds)
    logger.info("%s: no triangles; its %d vertices are read as points", path, len(xyz))
    return LoadedMesh(points=xyz, points_rgb=rgb, vertices=len(xyz))


def _plan(path: Path, mesh: LoadedMesh, max_points: int) -> SamplePlan:
    """How many points the mesh's triangles get; refuses a mesh of zero total area."""
    area = float(sum(piece.areas().sum() for piece in mesh.pieces))
    if not area > 0.0:
        raise ScanFormatError(
            f"{path}: the mesh has zero total area (all {mesh.faces:,} of its triangles are "
            f"degenerate: lines or points); there is no surface to sample points on"
        )
    return plan_samples(area, max_points, path)


def mesh_scan(
    path: Path,
    fmt: str,
    mesh: LoadedMesh,
    *,
    max_points: int,
    meta: dict[str, Any],
) -> Scan:
    """The scan of a loaded mesh: points sampled on its triangles (or its bare vertices), with
    ``meta`` and the ``mesh`` record added."""
    if mesh.points is not None:
        check_max_points(len(mesh.points), max_points, path)
        samples = MeshSamples(mesh.points, mesh.points_rgb)
        plan = SamplePlan(len(samples.xyz), 0.0, 0.0)
        kind = "none" if samples.rgb is None else "vertex"
    else:
        plan = _plan(path, mesh, max_points)
        samples = sample_pieces(mesh.pieces, plan.points)
        kind = main_colour_kind(mesh.pieces)
    xyz = samples.xyz
    record: dict[str, Any] = {
        "vertices": mesh.vertices,
        "faces": mesh.faces,
        "area_m2_or_units2": plan.area,
        "sampled_points": len(xyz),
        "spacing": plan.spacing,
        "colour": kind,
    }
    if samples.labels is not None:
        record["labels"] = LABELS_CARRIED
    logger.info(
        "%s: %d vertices, %d triangles, area %.4g: %d points at a %.3g spacing (colour: %s)",
        path,
        mesh.vertices,
        mesh.faces,
        plan.area,
        len(xyz),
        plan.spacing,
        kind,
    )
    scan = build_scan(path, fmt, xyz, samples.rgb, samples.labels, samples.fields)
    return replace(scan, meta={**meta, "mesh": record})


def mesh_info(path: Path, fmt: str, mesh: LoadedMesh, max_points: int) -> ScanInfo:
    """What reading the mesh will give (its point count, colour, labels and fields) without
    sampling it."""
    if mesh.points is not None:
        check_max_points(len(mesh.points), max_points, path)
        return ScanInfo(
            path=str(path),
            format=fmt,
            n_points=len(mesh.points),
            has_rgb=mesh.points_rgb is not None,
        )
    plan = _plan(path, mesh, max_points)
    coloured = main_colour_kind(mesh.pieces) != "none"
    return ScanInfo(
        path=str(path),
        format=fmt,
        n_points=plan.points,
        has_rgb=coloured,
        has_labels=any(piece.labels is not None for piece in mesh.pieces),
        fields=tuple(carried_fields(mesh.pieces)),
    )


# --- glTF / GLB ------------------------------------------------------------------------------


def _gltf_checked(path: Path, max_points: int) -> GltfFacts:
    facts = gltf_facts(path)
    check_neighbours(path, facts)
    check_mesh_size(path, facts.vertices, facts.faces, max_points)
    return facts


def _gltf_meta(facts: GltfFacts) -> dict[str, Any]:
    return {"comments": list(facts.comments), "up_convention": dict(GLTF_UP), **GLTF_UNITS}


def _gltf_format(path: Path) -> str:
    return "glb" if path.suffix.lower() == ".glb" else "gltf"


def read_gltf(path: Path, *, max_points: int, progress: ProgressFn | None = None) -> Scan:
    """Read a GLB or glTF file (by its extension) as points sampled on its meshes.

    Parameters
    ----------
    path : Path
        A ``.glb``, or a ``.gltf`` with its buffers and textures embedded or beside it.
    max_points : int
        At most this many points are sampled (the spacing grows to fit); a mesh with more
        vertices or triangles is refused before it is decoded.
    progress : ProgressFn, optional
        Receives ``("read", fraction)``.

    Returns
    -------
    Scan
        In the file's own (y-up, metre) coordinates; ``meta`` says so (``up_convention``,
        ``units``) with ``comments`` and ``mesh``.

    Raises
    ------
    ScanFormatError
        On a truncated or corrupt GLB, a JSON file that is not glTF 2.0, missing buffer files,
        a mesh too large, non-finite vertices, faces pointing at missing vertices, or no
        surface.
    """
    fmt = _gltf_format(path)
    report(progress, "read", 0.0)
    facts = _gltf_checked(path, max_points)
    mesh = load_mesh(path, "glb" if facts.binary else "gltf")
    report(progress, "read", 0.6)
    scan = mesh_scan(path, fmt, mesh, max_points=max_points, meta=_gltf_meta(facts))
    report(progress, "read", 1.0)
    return scan


def probe_gltf(path: Path, *, max_points: int) -> ScanInfo:
    """Check a GLB or glTF file and say how many points reading it gives (nothing sampled).

    Raises
    ------
    ScanFormatError
        As :func:`read_gltf`.
    """
    facts = _gltf_checked(path, max_points)
    mesh = load_mesh(path, "glb" if facts.binary else "gltf")
    return mesh_info(path, _gltf_format(path), mesh, max_points)


def check_single_file(path: Path) -> None:
    """Refuse a glTF that needs files beside it, for an upload (which arrives alone).

    Other formats pass: an OBJ without its MTL is still read, without the colours the MTL
    gave (the log says so).

    Raises
    ------
    ScanFormatError
        For a ``.gltf`` or ``.glb`` whose buffers or images are not embedded (and, as the
        readers do, for a missing or empty file).
    """
    if path.suffix.lower() in (".gltf", ".glb"):
        check_input_file(path)
        embedded_only(path, gltf_facts(path))


# --- OBJ -------------------------------------------------------------------------------------


def _obj_comments(data: bytes) -> list[str]:
    """The ``#`` lines at the top of an OBJ file (blank lines skipped), at most 50."""
    comments: list[str] = []
    for raw in data[: 1 << 16].splitlines():
        line = raw.strip()
        if not line:
            continue
        if not line.startswith(b"#") or len(comments) == MAX_OBJ_COMMENTS:
            break
        comments.append(line[1:].strip().decode("utf-8", "replace"))
    return comments


def _obj_count(data: bytes, keyword: bytes) -> int:
    """Lines starting with ``keyword`` followed by a space or tab (counted in C, not Python)."""
    count = 0
    for gap in (b" ", b"\t"):
        count += data.count(b"\n" + keyword + gap) + data.startswith(keyword + gap)
    return count


_ZERO_INDEX = re.compile(rb"(?m)^f[ \t][^\n]*?(?<=[ \t])0(?=[/\s]|\Z)")


def _bad_face_line(data: bytes) -> str | None:
    """Where an OBJ face first refers to a vertex that does not exist (0, or past the vertices
    defined so far), as a message; a Python loop over lines, run only on a file found broken."""
    seen = 0
    for number, raw in enumerate(data.splitlines(), start=1):
        words = raw.split()
        if not words:
            continue
        if words[0] == b"v":
            seen += 1
        elif words[0] == b"f":
            for word in words[1:]:
                token = word.split(b"/")[0]
                index = int(token) if token.lstrip(b"-").isdigit() else 0
                if index == 0 or index > seen or -index > seen:
                    return (
                        f"line {number}: face refers to vertex {token.decode(errors='replace')}, "
                        f"but {seen:,} vertices are defined before it (OBJ vertex numbers run "
                        f"from 1, or back from -1)"
                    )
    return None


def _obj_loaded(path: Path, max_points: int) -> tuple[LoadedMesh, list[str]]:
    data = path.read_bytes()
    check_mesh_size(path, _obj_count(data, b"v"), _obj_count(data, b"f"), max_points)
    comments = _obj_comments(data)
    if _ZERO_INDEX.search(data):
        raise ScanFormatError(f"{path}: {_bad_face_line(data) or 'a face refers to vertex 0'}")
    try:
        mesh = load_mesh(path, "obj")
    except ScanFormatError as exc:
        if not isinstance(exc.__cause__, IndexError):
            raise
        where = _bad_face_line(data)
        raise ScanFormatError(
            f"{path}: {where or f'faces refer to vertices that do not exist ({exc.__cause__})'}"
        ) from exc
    return mesh, comments


def read_obj(path: Path, *, max_points: int, progress: ProgressFn | None = None) -> Scan:
    """Read a Wavefront OBJ as points sampled on its faces.

    Colour comes from ``v x y z r g b`` vertex colours, else from the MTL file's texture
    (``map_Kd``) at each point's UV, else from its diffuse colour (``Kd``), per material.
    A file with vertices and no faces is read as those points.

    Parameters
    ----------
    path : Path
        The OBJ; its MTL and textures are looked up beside it.
    max_points : int
        At most this many points are sampled (the spacing grows to fit); a mesh with more
        vertices or faces is refused before it is parsed.
    progress : ProgressFn, optional

    Returns
    -------
    Scan
        In the file's own coordinates; ``meta`` holds ``comments`` (the leading ``#`` lines)
        and ``mesh``.

    Raises
    ------
    ScanFormatError
        On faces pointing at missing vertices, non-finite vertices, no vertices at all, zero
        area or a mesh too large.
    """
    report(progress, "read", 0.0)
    mesh, comments = _obj_loaded(path, max_points)
    report(progress, "read", 0.6)
    scan = mesh_scan(path, "obj", mesh, max_points=max_points, meta={"comments": comments})
    report(progress, "read", 1.0)
    return scan


def probe_obj(path: Path, *, max_points: int) -> ScanInfo:
    """Check an OBJ and say how many points reading it gives (nothing sampled).

    Raises
    ------
    ScanFormatError
        As :func:`read_obj`.
    """
    mesh, _ = _obj_loaded(path, max_points)
    return mesh_info(path, "obj", mesh, max_points)


# --- PLY with faces (the table calls these when the header, parsed by ply.core, declares faces) -


def read_ply_mesh(
    path: Path,
    *,
    comments: list[str],
    vertices: int,
    faces: int,
    max_points: int,
    progress: ProgressFn | None = None,
) -> Scan:
    """Read a PLY whose header declares faces as points sampled on them.

    Parameters
    ----------
    path : Path
    comments : list of str
        The header's ``comment`` and ``obj_info`` lines (parsed by
        :mod:`jointseg.io.formats.ply.core`).
    vertices, faces : int
        The header's counts, checked against ``max_points`` before the body is read.
    max_points : int
    progress : ProgressFn, optional

    Returns
    -------
    Scan
        Colour from vertex colours, face colours or a texture (``comment TextureFile``).
        When the vertex element has labels, each point takes the label of its triangle's
        nearest vertex, and that vertex's other scalar numeric properties as fields
        (coordinates, colours, alpha and normals aside; ``raw_label`` when some label values
        are no S3DIS class, as :func:`jointseg.io.formats.ply.core.read_ply` does); ``meta["mesh"]``
        then says ``"labels": "nearest vertex"``. Without labels, no vertex property is carried.

    Raises
    ------
    ScanFormatError
        As :func:`read_obj`.
    """
    check_mesh_size(path, vertices, faces, max_points)
    report(progress, "read", 0.0)
    mesh = load_mesh(path, "ply")
    report(progress, "read", 0.6)
    scan = mesh_scan(path, "ply", mesh, max_points=max_points, meta={"comments": comments})
    report(progress, "read", 1.0)
    return scan


def probe_ply_mesh(path: Path, *, vertices: int, faces: int, max_points: int) -> ScanInfo:
    """How many points reading a PLY mesh gives (the mesh read, nothing sampled)."""
    check_mesh_size(path, vertices, faces, max_points)
    return mesh_info(path, "ply", load_mesh(path, "ply"), max_points)
