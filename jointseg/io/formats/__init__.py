"""Which file extensions name which format, and which module reads, probes and writes it.

Kept in one table so the CLI's help, the upload API's checks and the dispatch in
:mod:`jointseg.io` and :mod:`jointseg.io.stream` cannot disagree. Every format lives below this
package, one module or one small package each, whole-file, probing and chunked reading and
writing together: :mod:`.ply` (and :mod:`.ply.stream`, :mod:`.ply.blocks`), :mod:`.las` (and
:mod:`.las.stream`, :mod:`.las.result`), :mod:`.pcd` (with its :mod:`.pcd.lzf`), :mod:`.e57`,
:mod:`.text`, :mod:`.arrays` (NPY/NPZ), :mod:`.s3dis` and :mod:`.mesh` (GLB/glTF, OBJ, PLY with
faces, through trimesh). What several formats share (limits, columns, colour, labels, fields,
numeric tables, atomic writes, chunk types) stays one level up, in :mod:`jointseg.io`.

A PLY is a point cloud or a mesh by its header; :func:`read_ply_file` makes that choice here, so
the PLY and mesh packages never import each other's readers.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from jointseg.exceptions import ScanFormatError, UnsupportedFormatError
from jointseg.io.chunks import ChunkOpener, WriterOpener
from jointseg.io.formats import arrays, e57, s3dis, text
from jointseg.io.formats.las import core as las
from jointseg.io.formats.las import stream as las_stream
from jointseg.io.formats.mesh import core as mesh
from jointseg.io.formats.pcd import core as pcd
from jointseg.io.formats.ply import core as ply
from jointseg.io.formats.ply import stream as ply_stream
from jointseg.io.limits import ScanInfo
from jointseg.progress import ProgressFn
from jointseg.scan import Scan

Reader = Callable[..., Scan]
Prober = Callable[..., ScanInfo]
Writer = Callable[..., None]


@dataclass(frozen=True)
class Format:
    """One supported format: its name and the functions handling it.

    ``inflates`` marks formats whose body may be compressed, so their reader and prober take
    ``max_inflation`` (what a header declares against the file's size). ``open_chunks`` and
    ``open_writer`` read and write the format chunk by chunk in bounded memory
    (:mod:`jointseg.io.stream`); a format without them is read whole and sliced, or written
    whole at the end.
    """

    name: str
    read: Reader
    probe: Prober
    write: Writer | None = None
    inflates: bool = False
    open_chunks: ChunkOpener | None = None
    open_writer: WriterOpener | None = None

    def limits(self, max_points: int, max_inflation: float) -> dict[str, float]:
        """The keyword arguments bounding this format's reader and prober."""
        if self.inflates:
            return {"max_points": max_points, "max_inflation": max_inflation}
        return {"max_points": max_points}


def read_ply_file(path: Path, *, max_points: int, progress: ProgressFn | None = None) -> Scan:
    """Read any PLY: a mesh (its header declares faces) as points sampled on its faces, a point
    cloud as :func:`jointseg.io.formats.ply.core.read_ply` reads it;
    which of the two is the table's choice, so neither format imports the other's reader."""
    header = ply.probe_header(path)
    if not header.faces:
        return ply.read_ply(path, max_points=max_points, progress=progress)
    return mesh.read_ply_mesh(
        path,
        comments=header.comments,
        vertices=ply.vertex_element(header, path).count,
        faces=header.faces,
        max_points=max_points,
        progress=progress,
    )


def probe_ply_file(path: Path, *, max_points: int) -> ScanInfo:
    """Probe any PLY (see :func:`read_ply_file`)."""
    header = ply.probe_header(path)
    if not header.faces:
        return ply.probe_ply(path, max_points=max_points)
    count = ply.vertex_element(header, path).count
    return mesh.probe_ply_mesh(path, vertices=count, faces=header.faces, max_points=max_points)


def _las_format(name: str, *, compress: bool) -> Format:
    """LAS and LAZ: one reader and streaming for both; the writer compresses for LAZ."""
    return Format(
        name,
        las.read_las,
        las.probe_las,
        partial(las.write_las, compress=compress),
        inflates=True,
        open_chunks=las_stream.open_las_chunks,
        open_writer=las_stream.LasChunkWriter,
    )


FORMATS: dict[str, Format] = {
    "ply": Format(
        "ply",
        read_ply_file,
        probe_ply_file,
        ply.write_ply,
        open_chunks=ply_stream.open_ply_chunks,
        open_writer=ply_stream.PlyChunkWriter,
    ),
    "las": _las_format("las", compress=False),
    "laz": _las_format("laz", compress=True),
    "e57": Format("e57", e57.read_e57, e57.probe_e57, inflates=True),
    "pcd": Format("pcd", pcd.read_pcd, pcd.probe_pcd, pcd.write_pcd, inflates=True),
    "txt": Format(
        "txt",
        partial(text.read_text, fmt="txt"),
        partial(text.probe_text, fmt="txt"),
        partial(text.write_text, comma=False),
    ),
    "xyz": Format(
        "xyz",
        partial(text.read_text, fmt="xyz"),
        partial(text.probe_text, fmt="xyz"),
        partial(text.write_text, comma=False),
    ),
    "csv": Format(
        "csv",
        partial(text.read_text, fmt="csv"),
        partial(text.probe_text, fmt="csv"),
        partial(text.write_text, comma=True),
    ),
    "npy": Format("npy", arrays.read_npy, arrays.probe_npy),
    "npz": Format("npz", arrays.read_npz, arrays.probe_npz, arrays.write_npz, inflates=True),
    # meshes (phone scanning apps): read as points sampled on their faces, never written
    "glb": Format("glb", mesh.read_gltf, mesh.probe_gltf),
    "gltf": Format("gltf", mesh.read_gltf, mesh.probe_gltf),
    "obj": Format("obj", mesh.read_obj, mesh.probe_obj),
    "s3dis": Format("s3dis", s3dis.read_s3dis_room, s3dis.probe_s3dis_room),
}

#: File extensions :func:`jointseg.io.read_scan` accepts (a folder is read as an S3DIS room).
READ_EXTENSIONS: tuple[str, ...] = tuple(
    f".{name}" for name, fmt in FORMATS.items() if name != "s3dis"
)
#: File extensions :func:`jointseg.io.write_scan` accepts.
WRITE_EXTENSIONS: tuple[str, ...] = tuple(
    f".{name}" for name, fmt in FORMATS.items() if fmt.write is not None
)


def detect_format(path: str | Path) -> str:
    """Name the format of ``path`` from its extension (a folder is an S3DIS room).

    Parameters
    ----------
    path : str or Path
        A scan file, or a room folder with ``Annotations/``; the file need not exist (for
        writing), the folder must.

    Returns
    -------
    str
        One of ``ply las laz e57 pcd txt xyz csv npy npz glb gltf obj s3dis``.

    Raises
    ------
    ScanFormatError
        On an unknown extension (listing the supported ones) or a folder that is not an S3DIS
        room.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if path.is_dir():
        if suffix in READ_EXTENSIONS:
            raise ScanFormatError(f"{path}: is a directory, expected a {suffix} file")
        s3dis.annotations_dir(path)
        return "s3dis"
    name = suffix[1:]
    if name not in FORMATS or name == "s3dis":
        raise UnsupportedFormatError(
            f"{path}: unsupported file extension {suffix or '(none)'!r}; supported: "
            f"{', '.join(READ_EXTENSIONS)}, or an S3DIS room folder"
        )
    return name


def get_format(name: str) -> Format:
    """The :class:`Format` entry named ``name``."""
    return FORMATS[name]


def writer_for(path: Path) -> Callable[[Scan, Path, ProgressFn | None], None]:
    """The writer for ``path``'s extension.

    Raises
    ------
    ScanFormatError
        When the extension cannot be written (listing the ones that can).
    """
    suffix = path.suffix.lower()
    fmt = FORMATS.get(suffix[1:])
    if fmt is None or fmt.write is None or suffix[1:] == "s3dis":
        raise ScanFormatError(
            f"{path}: cannot write {suffix or 'files without an extension'!r}; supported: "
            f"{', '.join(WRITE_EXTENSIONS)}"
        )
    write = fmt.write

    def run(scan: Scan, target: Path, progress: ProgressFn | None) -> None:
        write(scan, target, progress=progress)

    return run
