"""The glTF 2.0 container checked before trimesh reads it: GLB chunks, JSON, asset and buffers.

trimesh reads a broken GLB with a JSON decoding error and a JSON file that is no glTF as an
empty scene; these checks say instead, naming the file, what is wrong (a truncated file, a
missing ``asset``, a glTF 1.0 file, a buffer file that is not there). They also give what the
frame stage reads from the document (generator, copyright) and the sizes a reader checks
against ``max_points`` before anything is decoded. Nothing here needs trimesh.
"""

from __future__ import annotations

import json
import struct
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from jointseg.exceptions import ScanFormatError, library_reason

#: The first four bytes of a GLB file.
GLB_MAGIC = b"glTF"
_JSON_CHUNK, _BIN_CHUNK = 0x4E4F534A, 0x004E4942
#: glTF primitive modes that hold triangles (TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN).
_TRIANGLE_MODES = (4, 5, 6)
#: Largest JSON document read from a .gltf file or a GLB's JSON chunk.
_MAX_JSON_BYTES = 256 << 20


@dataclass(frozen=True)
class GltfFacts:
    """What a glTF document says before its buffers are decoded.

    Attributes
    ----------
    document : dict
        The JSON document.
    comments : list of str
        ``"generator: ..."`` and ``"copyright: ..."`` from ``asset`` (those present).
    external : list of str
        URIs of buffers and images that are files beside the document (not ``data:`` URIs, not
        the GLB's own binary chunk).
    vertices, faces : int
        Vertices and triangles its meshes hold, each mesh counted once per node that places it.
    binary : bool
        Whether the file is a GLB (by its magic, whatever its extension).
    """

    document: dict[str, Any]
    comments: list[str]
    external: list[str]
    vertices: int
    faces: int
    binary: bool


def _glb_json(data: bytes, path: Path) -> bytes:
    """The JSON chunk of a GLB file, after checking the header's length and the chunk layout."""
    if len(data) < 20 or data[:4] != GLB_MAGIC:
        raise ScanFormatError(f"{path}: not a GLB file (it does not start with the 'glTF' magic)")
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise ScanFormatError(f"{path}: GLB version {version}; only glTF 2.0 (GLB 2) is read")
    if length > len(data):
        raise ScanFormatError(
            f"{path}: truncated GLB: the header declares {length:,} bytes but the file has "
            f"{len(data):,}"
        )
    chunk_length, chunk_type = struct.unpack_from("<II", data, 12)
    if chunk_type != _JSON_CHUNK:
        raise ScanFormatError(f"{path}: corrupt GLB: the first chunk is not the JSON chunk")
    if 20 + chunk_length > length:
        raise ScanFormatError(
            f"{path}: truncated GLB: the JSON chunk of {chunk_length:,} bytes runs past the "
            f"end of the file ({length:,} bytes)"
        )
    end = 20 + chunk_length
    if end + 8 <= length:
        bin_length, bin_type = struct.unpack_from("<II", data, end)
        if bin_type == _BIN_CHUNK and end + 8 + bin_length > length:
            raise ScanFormatError(
                f"{path}: truncated GLB: the binary chunk of {bin_length:,} bytes runs past the "
                f"end of the file ({length:,} bytes)"
            )
    return data[20:end]


def _document(raw: bytes, path: Path) -> dict[str, Any]:
    """The parsed JSON, required to be a glTF 2.0 document (an object with ``asset.version``)."""
    try:
        doc = json.loads(raw.decode("utf-8-sig"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ScanFormatError(
            f"{path}: the glTF JSON is not valid JSON: {library_reason(exc)}"
        ) from exc
    asset = doc.get("asset") if isinstance(doc, dict) else None
    if not isinstance(asset, dict) or "version" not in asset:
        raise ScanFormatError(
            f"{path}: not a glTF file: its JSON has no 'asset' object with a 'version' (every "
            f"glTF 2.0 file has one)"
        )
    if not str(asset["version"]).startswith("2"):
        raise ScanFormatError(
            f"{path}: glTF version {asset['version']}; only glTF 2.0 is read (re-export it)"
        )
    return doc


def _sizes(doc: dict[str, Any]) -> tuple[int, int]:
    """Vertices and triangles of the document's meshes, each counted per node placing it."""
    accessors = doc.get("accessors") or []
    placed = Counter(
        n["mesh"] for n in doc.get("nodes") or [] if isinstance(n, dict) and "mesh" in n
    )
    vertices = faces = 0
    for index, mesh in enumerate(doc.get("meshes") or []):
        for prim in mesh.get("primitives") or [] if isinstance(mesh, dict) else []:
            if not isinstance(prim, dict):
                continue
            n_vert = _count(accessors, (prim.get("attributes") or {}).get("POSITION"))
            n_index = _count(accessors, prim.get("indices")) if "indices" in prim else n_vert
            times = placed.get(index, 0)
            vertices += times * n_vert
            if prim.get("mode", 4) in _TRIANGLE_MODES:
                faces += times * (n_index // 3 if prim.get("mode", 4) == 4 else max(n_index - 2, 0))
    return vertices, faces


def _count(accessors: list[Any], index: Any) -> int:
    """The ``count`` of accessor ``index`` (0 for a missing or malformed one)."""
    if not isinstance(index, int) or not 0 <= index < len(accessors):
        return 0
    count = accessors[index].get("count", 0) if isinstance(accessors[index], dict) else 0
    return count if isinstance(count, int) and count > 0 else 0


def _external(doc: dict[str, Any]) -> list[str]:
    """URIs of buffers and images that are not embedded (``data:``) in the document."""
    out = []
    for key in ("buffers", "images"):
        for item in doc.get(key) or []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                out.append(uri)
    return out


def gltf_facts(path: Path) -> GltfFacts:
    """Check a ``.glb`` or ``.gltf`` file's container and read its document.

    Parameters
    ----------
    path : Path
        A GLB file (by its magic) or a JSON glTF file.

    Returns
    -------
    GltfFacts

    Raises
    ------
    ScanFormatError
        On a truncated or corrupt GLB, JSON that does not parse, a document that is not glTF
        2.0, or a JSON file larger than 256 MiB (its binary data belongs in buffers).
    """
    with open(path, "rb") as fh:
        head = fh.read(4)
    if head == GLB_MAGIC:
        raw = _glb_json(path.read_bytes(), path)
    elif path.suffix.lower() == ".glb":
        raise ScanFormatError(f"{path}: not a GLB file (it does not start with the 'glTF' magic)")
    else:
        if path.stat().st_size > _MAX_JSON_BYTES:
            raise ScanFormatError(
                f"{path}: a {path.stat().st_size:,}-byte .gltf is too large to be a glTF JSON "
                f"document; export it as .glb"
            )
        raw = path.read_bytes()
    doc = _document(raw, path)
    asset = doc["asset"]
    comments = [f"{key}: {asset[key]}" for key in ("generator", "copyright") if asset.get(key)]
    vertices, faces = _sizes(doc)
    return GltfFacts(doc, comments, _external(doc), vertices, faces, head == GLB_MAGIC)


def check_neighbours(path: Path, facts: GltfFacts) -> None:
    """Refuse a glTF whose buffer or image files are missing beside it, naming the first one.

    Raises
    ------
    ScanFormatError
        When a file a URI names does not exist in the document's folder.
    """
    from urllib.parse import unquote

    for uri in facts.external:
        if not (path.parent / unquote(uri)).is_file():
            raise ScanFormatError(
                f"{path}: the glTF refers to {uri!r}, which is not beside it; keep a .gltf's "
                f".bin and texture files in its folder, or use a .glb (one file)"
            )


def embedded_only(path: Path, facts: GltfFacts) -> None:
    """Refuse a glTF that needs files beside it (an upload arrives as one file).

    Raises
    ------
    ScanFormatError
        Naming the first outside file and saying to upload a .glb.
    """
    if facts.external:
        more = f" and {len(facts.external) - 1} more" if len(facts.external) > 1 else ""
        raise ScanFormatError(
            f"{path}: the glTF refers to files beside it ({facts.external[0]!r}{more}), which "
            f"an upload cannot bring along; upload a .glb instead (binary glTF: one file with "
            f"its buffers and textures), or a .gltf with them embedded as data: URIs"
        )
