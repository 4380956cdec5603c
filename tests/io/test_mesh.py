"""Meshes as input (issue 41, part 4): GLB/glTF, OBJ and PLY with faces, written with trimesh
into a temporary folder and read back through jointseg.io, the CLI and the job service."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import trimesh
from PIL import Image
from plyfile import PlyData, PlyElement

from jointseg.client import JobClient
from jointseg.exceptions import ScanFormatError
from jointseg.io import READ_EXTENSIONS, probe_scan, read_scan
from jointseg.io.formats.mesh.core import check_single_file
from jointseg.io.formats.mesh.sample import SAMPLE_SPACING
from jointseg.io.stream import open_chunks
from tests.support.cli import run_cli

#: A 1 m x 1 m quad on z = 0 (two triangles).
QUAD_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
QUAD_F = np.array([[0, 1, 2], [0, 2, 3]])
QUAD_UV = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
RED = (255, 0, 0)
#: Points a 1 m² quad gets at the default spacing.
PER_M2 = math.ceil(1.0 / SAMPLE_SPACING**2)


def quad(**visual: Any) -> trimesh.Trimesh:
    return trimesh.Trimesh(QUAD_V.copy(), QUAD_F.copy(), process=False, **visual)


def red_image() -> Image.Image:
    return Image.new("RGB", (8, 8), RED)


def textured_quad() -> trimesh.Trimesh:
    """A quad whose only colour is a red texture (base colour factor white, as apps write)."""
    material = trimesh.visual.material.PBRMaterial(
        baseColorTexture=red_image(), baseColorFactor=[255, 255, 255, 255]
    )
    return quad(visual=trimesh.visual.TextureVisuals(uv=QUAD_UV, material=material))


def glb_json(path: Path) -> dict[str, Any]:
    data = path.read_bytes()
    length = int.from_bytes(data[12:16], "little")
    return dict(json.loads(data[20 : 20 + length]))


# --- GLB / glTF ------------------------------------------------------------------------------


def test_glb_scene_is_flattened_with_its_node_transforms(tmp_path: Path) -> None:
    scene = trimesh.Scene()
    moved = np.eye(4)
    moved[:3, 3] = (10.0, 0.0, 2.0)
    scene.add_geometry(textured_quad(), node_name="near")
    scene.add_geometry(textured_quad(), node_name="far", transform=moved)
    path = tmp_path / "scene.glb"
    scene.export(path)
    scan = read_scan(path)
    assert scan.source_format == "glb"
    assert len(scan) == math.ceil(2.0 / SAMPLE_SPACING**2)  # area / spacing²
    far = scan.xyz[:, 0] > 5
    assert abs(int(far.sum()) - len(scan) / 2) <= 1  # each quad its share, give or take one
    np.testing.assert_allclose(scan.xyz[far, 2], 2.0)  # the node's transform applied
    assert scan.xyz[far, 0].min() >= 10.0 and scan.xyz[far, 0].max() <= 11.0
    np.testing.assert_allclose(scan.xyz[~far, 2], 0.0)
    assert (scan.rgb == RED).all()  # a red texture reads back red
    mesh = scan.meta["mesh"]
    assert mesh == {
        "vertices": 8,
        "faces": 4,
        "area_m2_or_units2": pytest.approx(2.0),
        "sampled_points": len(scan),
        "spacing": SAMPLE_SPACING,
        "colour": "texture",
    }


def test_gltf_meta_says_y_up_and_metres_and_the_points_are_not_turned(tmp_path: Path) -> None:
    path = tmp_path / "quad.glb"
    quad(vertex_colors=[RED] * 4).export(path)
    scan = read_scan(path)
    assert scan.meta["up_convention"] == {
        "axis": "+y",
        "source": "glTF 2.0 (y up by specification)",
    }
    assert scan.meta["units"] == "m"
    assert scan.meta["units_source"] == "glTF 2.0 (metres by specification)"
    assert scan.meta["comments"] == [f"generator: {glb_json(path)['asset']['generator']}"]
    # the quad lies in the file's z = 0 plane, as written: nothing rotated to z up
    np.testing.assert_allclose(scan.xyz[:, 2], 0.0)
    assert scan.xyz[:, :2].min() >= 0.0 and scan.xyz[:, :2].max() <= 1.0
    assert scan.meta["mesh"]["colour"] == "vertex" and (scan.rgb == RED).all()


def test_gltf_copyright_is_a_comment_too(tmp_path: Path) -> None:
    gltf = trimesh.exchange.gltf.export_gltf(trimesh.Scene(quad()), embed_buffers=True)
    doc = json.loads(gltf["model.gltf"])
    doc["asset"].update(generator="Polycam", copyright="Someone 2025")
    path = tmp_path / "quad.gltf"
    path.write_text(json.dumps(doc))
    scan = read_scan(path)
    assert scan.source_format == "gltf" and len(scan) == PER_M2
    assert scan.meta["comments"] == ["generator: Polycam", "copyright: Someone 2025"]
    assert scan.rgb is None and scan.meta["mesh"]["colour"] == "none"


def test_material_colour_of_a_glb(tmp_path: Path) -> None:
    material = trimesh.visual.material.PBRMaterial(baseColorFactor=[255, 0, 0, 255])
    path = tmp_path / "material.glb"
    quad(visual=trimesh.visual.TextureVisuals(material=material)).export(path)
    scan = read_scan(path)
    assert (scan.rgb == RED).all() and scan.meta["mesh"]["colour"] == "material"


def test_gltf_with_its_bin_beside_it_reads_from_disk_but_is_no_upload(tmp_path: Path) -> None:
    files = trimesh.exchange.gltf.export_gltf(trimesh.Scene(textured_quad()))
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    path = tmp_path / "model.gltf"
    assert any(name.endswith(".bin") for name in files)
    scan = read_scan(path)  # the CLI and the library read it with its neighbours
    assert len(scan) == PER_M2 and (scan.rgb == RED).all()
    with pytest.raises(ScanFormatError, match=r"upload a \.glb instead") as info:
        check_single_file(path)
    assert "model.gltf" in str(info.value)
    bin_name = next(name for name in files if name.endswith(".bin"))
    (tmp_path / bin_name).unlink()
    with pytest.raises(ScanFormatError, match=f"refers to '{bin_name}', which is not beside it"):
        read_scan(path)


def test_an_embedded_gltf_and_a_glb_are_single_files(tmp_path: Path) -> None:
    gltf = trimesh.exchange.gltf.export_gltf(trimesh.Scene(textured_quad()), embed_buffers=True)
    assert list(gltf) == ["model.gltf"]
    (tmp_path / "one.gltf").write_bytes(gltf["model.gltf"])
    check_single_file(tmp_path / "one.gltf")
    assert (read_scan(tmp_path / "one.gltf").rgb == RED).all()
    textured_quad().export(tmp_path / "one.glb")
    check_single_file(tmp_path / "one.glb")


# --- OBJ -------------------------------------------------------------------------------------


def test_obj_texture_and_comments(tmp_path: Path) -> None:
    material = trimesh.visual.material.SimpleMaterial(image=red_image(), diffuse=[90, 90, 90, 255])
    obj = quad(visual=trimesh.visual.TextureVisuals(uv=QUAD_UV, material=material))
    path = tmp_path / "room.obj"
    obj.export(path, header="Scanned with 3D Scanner App\n#  Exported 2025-01-01")
    scan = read_scan(path)
    assert scan.source_format == "obj" and len(scan) == PER_M2
    assert (scan.rgb == RED).all() and scan.meta["mesh"]["colour"] == "texture"
    assert scan.meta["comments"] == ["Scanned with 3D Scanner App", "Exported 2025-01-01"]


def test_obj_mtl_diffuse_colour_per_material(tmp_path: Path) -> None:
    (tmp_path / "m.mtl").write_text("newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n")
    path = tmp_path / "two.obj"
    path.write_text(
        "# two materials\nmtllib m.mtl\n"
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 5 0 0\nv 6 0 0\nv 6 1 0\nv 5 1 0\n"
        "usemtl red\nf 1 2 3\nf 1 3 4\nusemtl blue\nf 5 6 7\nf 5 7 8\n"
    )
    scan = read_scan(path)
    assert len(scan) == math.ceil(2.0 / SAMPLE_SPACING**2)
    assert scan.meta["mesh"]["colour"] == "material"
    right = scan.xyz[:, 0] > 3
    assert (scan.rgb[right] == (0, 0, 255)).all() and (scan.rgb[~right] == RED).all()
    assert scan.meta["comments"] == ["two materials"]


def test_obj_vertex_colours_are_interpolated(tmp_path: Path) -> None:
    path = tmp_path / "ramp.obj"
    path.write_text(
        "v 0 0 0 0 0 0\nv 1 0 0 1 1 1\nv 1 1 0 1 1 1\nv 0 1 0 0 0 0\nf 1 2 3\nf 1 3 4\n"
    )
    scan = read_scan(path)
    assert scan.meta["mesh"]["colour"] == "vertex"
    # black at x = 0, white at x = 1: the grey follows x (barycentric interpolation)
    grey = scan.rgb[:, 0].astype(float)
    np.testing.assert_allclose(grey, 255 * scan.xyz[:, 0], atol=1.0)
    assert (scan.rgb[:, 0] == scan.rgb[:, 2]).all()


def test_obj_without_faces_is_read_as_its_points(tmp_path: Path) -> None:
    path = tmp_path / "cloud.obj"
    path.write_text("# a point cloud\nv 0 0 0 1 0 0\nv 1 0 0 1 0 0\nv 2 1 0 1 0 0\n")
    scan = read_scan(path)
    np.testing.assert_array_equal(scan.xyz, [[0, 0, 0], [1, 0, 0], [2, 1, 0]])
    assert (scan.rgb == RED).all()
    assert scan.meta["mesh"]["faces"] == 0 and scan.meta["mesh"]["sampled_points"] == 3
    assert probe_scan(path).n_points == 3


# --- PLY -------------------------------------------------------------------------------------


def _ply_with_comments(path: Path, *, faces: bool, binary: bool = True) -> None:
    vertex = np.zeros(
        4,
        dtype=[
            ("x", "f4"),
            ("y", "f4"),
            ("z", "f4"),
            ("red", "u1"),
            ("green", "u1"),
            ("blue", "u1"),
            ("label", "i4"),
        ],
    )
    for i, axis in enumerate("xyz"):
        vertex[axis] = QUAD_V[:, i]
    vertex["red"] = 255
    vertex["label"] = (2, 2, 7, 7)
    elements = [PlyElement.describe(vertex, "vertex")]
    if faces:
        face = np.zeros(2, dtype=[("vertex_indices", "i4", (3,))])
        face["vertex_indices"] = QUAD_F
        elements.append(PlyElement.describe(face, "face"))
    PlyData(
        elements,
        text=not binary,
        comments=["Created by Polycam", "up axis: y"],
        obj_info=["scanned 2025"],
    ).write(str(path))


@pytest.mark.parametrize("binary", [True, False])
def test_ply_mesh_is_sampled_with_its_comments(tmp_path: Path, binary: bool) -> None:
    path = tmp_path / "mesh.ply"
    _ply_with_comments(path, faces=True, binary=binary)
    scan = read_scan(path)
    assert scan.source_format == "ply" and len(scan) == PER_M2
    assert (scan.rgb == RED).all() and scan.meta["mesh"]["colour"] == "vertex"
    assert scan.meta["comments"] == ["Created by Polycam", "up axis: y", "scanned 2025"]
    assert set(np.unique(scan.labels)) == {2, 7} and not scan.fields  # the vertices' labels
    assert scan.meta["mesh"]["labels"] == "nearest vertex"
    assert probe_scan(path).n_points == PER_M2
    with open_chunks(path) as chunks:  # a mesh is read whole, then sliced
        assert not chunks.streams and chunks.count == PER_M2
        np.testing.assert_array_equal(
            np.concatenate([c.xyz for c in chunks.chunks(1000)]), scan.xyz
        )


#: A rhombus of two equilateral triangles (ABC, BDC) on z = 0: in an equilateral triangle the
#: corner with the largest barycentric weight is the nearest one, and no point of one triangle
#: is nearer to the other's far corner, so a point's nearest vertex of all four is the nearest
#: corner of its triangle.
RHOMBUS_V = np.array(
    [[0, 0, 0], [1, 0, 0], [0.5, math.sqrt(3) / 2, 0], [1.5, math.sqrt(3) / 2, 0]], dtype=float
)
RHOMBUS_F = np.array([[0, 1, 2], [1, 3, 2]])
RHOMBUS_LABELS = np.array([3, 7, 3, 7])
RHOMBUS_INTENSITY = np.array([10.0, 20.0, 30.0, 40.0])


def _labelled_rhombus(
    path: Path, label: str | None, *, binary: bool = True, texcoord: bool = False
) -> None:
    """The rhombus as a PLY mesh with colour, alpha, normals, ``intensity`` and (under the name
    ``label``, when given) the vertex labels 3 and 7; ``texcoord``: per-face UVs that differ at
    the shared vertices, so trimesh splits those vertices."""
    props = [(a, "f4") for a in ("x", "y", "z", "nx", "ny", "nz")]
    props += [(c, "u1") for c in ("red", "green", "blue", "alpha")] + [("intensity", "f4")]
    vertex = np.zeros(4, dtype=props + ([(label, "u2")] if label else []))
    for i, axis in enumerate("xyz"):
        vertex[axis] = RHOMBUS_V[:, i]
    vertex["nz"], vertex["red"], vertex["alpha"] = 1.0, 255, 255
    vertex["intensity"] = RHOMBUS_INTENSITY
    if label:
        vertex[label] = RHOMBUS_LABELS
    face_props: list[Any] = [("vertex_indices", "i4", (3,))]
    face = np.zeros(2, dtype=face_props + ([("texcoord", "f4", (6,))] if texcoord else []))
    face["vertex_indices"] = RHOMBUS_F
    if texcoord:
        face["texcoord"] = [[0, 0, 0.5, 0, 0, 0.5], [0.5, 0.5, 1, 1, 0.5, 1]]
    elements = [PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face")]
    PlyData(elements, text=not binary).write(str(path))


def _nearest_vertex(xyz: np.ndarray) -> np.ndarray:
    """Index of the rhombus vertex nearest to each point (from the geometry alone)."""
    return np.linalg.norm(xyz[:, None, :] - RHOMBUS_V[None], axis=2).argmin(axis=1)


@pytest.mark.parametrize(
    ("label", "binary", "texcoord"),
    [
        ("label", True, False),
        ("label", False, False),
        ("scalar_Classification", True, False),
        ("CLASS", False, True),
    ],
)
def test_ply_mesh_vertex_labels_and_properties_go_to_the_nearest_points(
    tmp_path: Path, label: str, binary: bool, texcoord: bool
) -> None:
    """ScanNet's ``*_vh_clean_2.labels.ply`` is such a mesh: its labels are the ground truth."""
    path = tmp_path / "labelled.ply"
    _labelled_rhombus(path, label, binary=binary, texcoord=texcoord)
    if texcoord:  # the case where trimesh's vertices are not the file's
        assert len(trimesh.load(path, process=False).vertices) > 4
    scan = read_scan(path)
    nearest = _nearest_vertex(scan.xyz)
    assert len(np.unique(nearest)) == 4  # every corner has points
    np.testing.assert_array_equal(scan.labels, RHOMBUS_LABELS[nearest])
    assert scan.labels.dtype == np.int32 and set(np.unique(scan.labels)) == {3, 7}
    assert set(scan.fields) == {"intensity"}  # no normals, no alpha
    np.testing.assert_array_equal(scan.fields["intensity"], RHOMBUS_INTENSITY[nearest])
    assert scan.fields["intensity"].dtype == np.float32
    assert texcoord or (scan.rgb == RED).all()  # (UVs without an image: trimesh's grey)
    assert scan.meta["mesh"]["labels"] == "nearest vertex"
    info = probe_scan(path)
    assert (info.has_labels, info.fields, info.n_points) == (True, ("intensity",), len(scan))


def test_ply_mesh_without_labels_carries_nothing(tmp_path: Path) -> None:
    path = tmp_path / "unlabelled.ply"
    _labelled_rhombus(path, None)
    scan = read_scan(path)
    assert scan.labels is None and scan.fields == {}
    assert "labels" not in scan.meta["mesh"]
    assert not probe_scan(path).has_labels


def test_ply_mesh_labels_that_are_no_class_keep_their_raw_values(tmp_path: Path) -> None:
    """ScanNet's labels are NYU40 ids: as read_ply does, those outside the classes are -1, and
    the raw value of the nearest vertex is kept as ``raw_label``."""
    path = tmp_path / "nyu40.ply"
    _labelled_rhombus(path, "label")
    data = PlyData.read(str(path), mmap=False)
    data["vertex"].data["label"] = (3, 7, 3, 39)
    data.write(str(path))
    scan = read_scan(path)
    nearest = _nearest_vertex(scan.xyz)
    np.testing.assert_array_equal(scan.labels, np.array([3, 7, 3, -1])[nearest])
    np.testing.assert_array_equal(scan.fields["raw_label"], np.array([3, 7, 3, 39])[nearest])


def test_ply_face_colours(tmp_path: Path) -> None:
    path = tmp_path / "faces.ply"
    quad(face_colors=[RED, (0, 0, 255)]).export(path)
    scan = read_scan(path)
    assert scan.meta["mesh"]["colour"] == "face"
    lower = scan.xyz[:, 0] > scan.xyz[:, 1]  # triangle 0 is below the diagonal
    assert (scan.rgb[lower] == RED).all() and (scan.rgb[~lower] == (0, 0, 255)).all()


@pytest.mark.parametrize("binary", [True, False])
def test_ply_without_faces_is_read_as_before_plus_its_comments(
    tmp_path: Path, binary: bool
) -> None:
    """The vertices, bit for bit as plyfile reads them (as jointseg always has), and now the
    header's comments; an empty face element changes nothing."""
    path = tmp_path / "cloud.ply"
    _ply_with_comments(path, faces=False, binary=binary)
    raw = PlyData.read(str(path))["vertex"].data
    scan = read_scan(path)
    np.testing.assert_array_equal(scan.xyz, np.stack([raw[a] for a in "xyz"], 1).astype(float))
    np.testing.assert_array_equal(scan.rgb, np.stack([raw[c] for c in ("red", "green", "blue")], 1))
    np.testing.assert_array_equal(scan.labels, raw["label"])
    assert scan.fields == {} and "mesh" not in scan.meta
    assert scan.meta == {"comments": ["Created by Polycam", "up axis: y", "scanned 2025"]}
    with open_chunks(path) as chunks:
        assert chunks.streams == binary
        assert all(c.meta == scan.meta for c in chunks.chunks(3))
    text = path.read_bytes()
    empty_faces = tmp_path / "empty_faces.ply"
    head, body = text.split(b"end_header\n", 1)
    empty_faces.write_bytes(
        head + b"element face 0\nproperty list uchar int vertex_indices\nend_header\n" + body
    )
    again = read_scan(empty_faces)
    np.testing.assert_array_equal(again.xyz, scan.xyz)
    np.testing.assert_array_equal(again.labels, scan.labels)


# --- sampling --------------------------------------------------------------------------------


def test_sampling_is_deterministic_and_capped_by_max_points(tmp_path: Path) -> None:
    path = tmp_path / "quad.glb"
    quad(vertex_colors=[RED] * 4).export(path)
    a, b = read_scan(path), read_scan(path)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    capped = read_scan(path, max_points=1000)
    assert len(capped) == 1000
    assert capped.meta["mesh"]["spacing"] == pytest.approx(math.sqrt(1.0 / 1000))
    assert probe_scan(path, max_points=1000).n_points == 1000
    assert probe_scan(path).n_points == len(a)
    # the points cover the quad evenly: every 10 cm cell holds its share, give or take
    cells = np.bincount(
        (np.floor(a.xyz[:, 0] * 10) * 10 + np.floor(a.xyz[:, 1] * 10)).astype(int).clip(0, 99),
        minlength=100,
    )
    assert cells.min() > 0.6 * len(a) / 100 and cells.max() < 1.4 * len(a) / 100


# --- bad meshes ------------------------------------------------------------------------------


def _bad_meshes(folder: Path) -> dict[str, tuple[Path, str]]:
    """name -> (file, text the message must hold)."""
    good = folder / "good.glb"
    quad().export(good)
    data = good.read_bytes()
    cases: dict[str, tuple[Path, str]] = {}

    def put(name: str, content: bytes | str, needle: str) -> None:
        path = folder / name
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
        cases[name] = (path, needle)

    put("truncated.glb", data[: len(data) // 2], "truncated GLB")
    put("garbage.glb", b"\x00" * 64, "not a GLB file")
    put("json.glb", b'{"asset": {"version": "2.0"}}', "not a GLB file")
    put("notgltf.gltf", json.dumps({"scenes": []}), "not a glTF file")
    put("gltf1.gltf", json.dumps({"asset": {"version": "1.0"}}), "only glTF 2.0")
    put("broken.gltf", '{"asset": ', "not valid JSON")
    put("empty.gltf", json.dumps({"asset": {"version": "2.0"}}), "no triangles and no vertices")
    put("missing_vertex.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 9\n", "line 4: face refers")
    put("vertex_zero.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 0 1 2\n", "refers to vertex 0")
    put("comments_only.obj", "# nothing here\n", "no triangles and no vertices")
    put("flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "zero total area")
    put("nan.obj", "v 0 0 0\nv nan 0 0\nv 1 1 0\nf 1 2 3\n", "non-finite coordinates")
    put(
        "missing_vertex.ply",
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n1 1 0\n3 0 1 7\n",
        "refers to vertices [0, 1, 7]",
    )
    put(
        "nan.ply",
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 nan 0\n1 1 0\n3 0 1 2\n",
        "non-finite coordinates",
    )
    return cases


@pytest.fixture(scope="module")
def bad_meshes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, str]]:
    return _bad_meshes(tmp_path_factory.mktemp("bad-meshes"))


BAD = [
    "truncated.glb",
    "garbage.glb",
    "json.glb",
    "notgltf.gltf",
    "gltf1.gltf",
    "broken.gltf",
    "empty.gltf",
    "missing_vertex.obj",
    "vertex_zero.obj",
    "comments_only.obj",
    "flat.obj",
    "nan.obj",
    "missing_vertex.ply",
    "nan.ply",
]


@pytest.mark.parametrize("name", BAD)
def test_a_bad_mesh_is_one_scan_format_error_naming_file_and_problem(
    bad_meshes: dict[str, tuple[Path, str]], name: str
) -> None:
    path, needle = bad_meshes[name]
    for call in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError) as info:
            call(path)
        message = str(info.value)
        assert needle in message and str(path) in message and "\n" not in message


def test_a_mesh_larger_than_max_points_is_refused_before_it_is_decoded(tmp_path: Path) -> None:
    sphere = trimesh.creation.icosphere(subdivisions=4)  # 5 120 triangles
    for suffix in (".glb", ".obj", ".ply"):
        path = tmp_path / f"sphere{suffix}"
        sphere.export(path)
        with pytest.raises(ScanFormatError, match="5,120 triangles, more than max_points=5,000"):
            read_scan(path, max_points=5000)


# --- registered like every other format ------------------------------------------------------


def test_the_mesh_extensions_are_read_everywhere() -> None:
    assert {".glb", ".gltf", ".obj"} <= set(READ_EXTENSIONS)
    from web.page import page_html

    accept = page_html().split(b'accept="', 1)[1].split(b'"', 1)[0].decode()
    assert accept.split(",") == list(READ_EXTENSIONS)
    static = (Path(__file__).parents[2] / "web" / "static" / "index.html").read_text()
    assert f'accept="{",".join(READ_EXTENSIONS)}"' in static  # the file itself kept current


@pytest.mark.slow
def test_cli_info_on_a_glb_and_a_bad_glb(
    tmp_path: Path, bad_meshes: dict[str, tuple[Path, str]]
) -> None:
    path = tmp_path / "quad.glb"
    textured_quad().export(path)
    shown = run_cli("info", "--json", str(path))
    assert shown.returncode == 0, shown.stderr
    summary = json.loads(shown.stdout)
    assert summary["source_format"] == "glb" and summary["points"] == PER_M2
    bad, _ = bad_meshes["truncated.glb"]
    for args in (("info", str(bad)), ("segment", str(bad), "-o", str(tmp_path / "x.ply"))):
        result = run_cli(*args)
        assert result.returncode == 2, result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and "truncated GLB" in lines[0], result.stderr
        assert "Traceback" not in result.stderr
    assert not (tmp_path / "x.ply").exists()


def test_the_service_takes_a_glb_and_refuses_a_gltf_that_needs_its_bin(
    service: Any, random_weights: Path, tmp_path: Path
) -> None:
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))  # 6 m²
    box.visual.vertex_colors = [200, 30, 30, 255]
    glb = tmp_path / "box.glb"
    box.export(glb)
    config = {"network": {"weights": str(random_weights), "device": "cpu"}, "seed": 1}
    expected = read_scan(glb)
    with JobClient(service.url, api_key=service.api_key) as client:
        job = client.submit(glb, config=config)
        assert job.format == "glb" and job.points == len(expected)
        done = client.wait(job.id, poll_s=0.2, timeout_s=180)
        assert done.status == "succeeded", done.error
        result = read_scan(client.download(job.id, tmp_path / "out.ply"))
    np.testing.assert_allclose(result.xyz, expected.xyz, atol=1e-6)  # the sampled points
    assert "fused_label" in result.fields
    files = trimesh.exchange.gltf.export_gltf(trimesh.Scene(box))
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    headers = {"Authorization": f"Bearer {service.api_key}"} if service.api_key else {}
    with open(tmp_path / "model.gltf", "rb") as fh:
        response = httpx.post(
            f"{service.url}/v1/jobs",
            files={"file": ("scan.gltf", fh)},
            data={"config": json.dumps(config)},
            headers=headers,
            timeout=60,
        )
    assert response.status_code == 422, response.text
    detail = response.json()["detail"]
    assert "upload a .glb instead" in detail and "scan.gltf" in detail
    assert str(service.data_dir) not in detail
