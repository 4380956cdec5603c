"""Bad input through the API: the malformed scans jointseg.io rejects, bad configs, bad requests,
hostile file names and oversized uploads. Each gets its 4xx with a JSON message and leaves no
job and no file behind."""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from jointseg.io import READ_EXTENSIONS
from tests.support.service_process import left_in_incoming, post_scan, scan_file

#: Extensions whose files are tried with plain text in them (text formats would parse it).
WRONG_CONTENT = (".ply", ".las", ".laz", ".e57", ".pcd", ".npy", ".npz", ".glb", ".gltf", ".obj")


def _ply_binary(path: Path, xyz: np.ndarray) -> Path:
    """A binary PLY written with plyfile (jointseg's writer refuses non-finite points)."""
    vertex = np.zeros(len(xyz), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    for i, axis in enumerate("xyz"):
        vertex[axis] = xyz[:, i]
    PlyData([PlyElement.describe(vertex, "vertex")]).write(str(path))
    return path


def _bad_files(folder: Path, scans: Path) -> dict[str, tuple[Path, int, str]]:
    """name -> (file, expected status, text the message must contain)."""
    cases: dict[str, tuple[Path, int, str]] = {}
    for ext in READ_EXTENSIONS:
        empty = folder / f"empty{ext}"
        empty.write_bytes(b"")
        cases[f"empty{ext}"] = (empty, 422, "empty")
    for ext in WRONG_CONTENT:
        wrong = folder / f"wrong{ext}"
        wrong.write_text("this is not a point cloud\n" * 20)
        cases[f"wrong-content{ext}"] = (wrong, 422, f"wrong{ext}")
    good = scan_file(scans, ".ply", points=1000, seed=7).read_bytes()
    truncated = folder / "truncated.ply"
    truncated.write_bytes(good[: len(good) - 100])
    cases["truncated-ply"] = (truncated, 422, "truncated.ply")
    no_end = folder / "no_end.ply"
    no_end.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n")
    cases["ply-header-without-end"] = (no_end, 422, "no_end.ply")
    xyz = np.zeros((5, 3))
    xyz[3, 1] = np.nan
    cases["nan-binary-ply"] = (_ply_binary(folder / "nan.ply", xyz), 422, "non-finite")
    inf = folder / "inf.ply"
    inf.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
        "property float z\nend_header\n0 0 0\n1 inf 1\n"
    )
    cases["inf-ascii-ply"] = (inf, 422, "non-finite")
    huge = folder / "huge.ply"
    huge.write_text(
        "ply\nformat binary_little_endian 1.0\nelement vertex 900000000\nproperty float x\n"
        "property float y\nproperty float z\nend_header\n"
    )
    cases["too-many-points"] = (huge, 422, "max_points")
    for span in ("1e18", "1e300"):  # a room's points, one of them absurdly far away
        far = folder / f"far_{span}.ply"
        far.write_text(
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
            f"property double z\nend_header\n0 0 0\n1 1 1\n{span} 0 -{span}\n"
        )
        cases[f"span-{span}"] = (far, 422, "span")
    columns = folder / "columns.txt"
    columns.write_text("0 0 0 1 2 3\n1 1 1 4 5 6\n2 2 2 7 8\n")
    cases["txt-mismatched-columns"] = (columns, 422, "line 3")
    word = folder / "word.txt"
    word.write_text("0 0 0\n1 one 1\n")
    cases["txt-non-numeric"] = (word, 422, "line 2")
    nan_txt = folder / "nan.txt"
    nan_txt.write_text("0 0 0\nnan 1 1\n")
    cases["txt-nan"] = (nan_txt, 422, "line 2")
    garbage = folder / "garbage.txt"
    garbage.write_bytes(bytes(np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8)))
    cases["txt-binary-garbage"] = (garbage, 422, "garbage.txt")
    npy = folder / "nan.npy"
    np.save(npy, np.array([[0.0, 0, 0], [np.inf, 0, 0]]))
    cases["npy-inf"] = (npy, 422, "non-finite")
    pcd = folder / "cols.pcd"
    pcd.write_text(
        "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\n"
        "POINTS 2\nDATA ascii\n0 0 0\n1 1\n"
    )
    cases["pcd-ascii-columns"] = (pcd, 422, "cols.pcd")
    for name in ("scan.docx", "scan"):
        other = folder / name
        other.write_bytes(good)
        cases[f"unsupported-{name}"] = (other, 415, "unsupported file extension")
    return cases


@pytest.fixture(scope="module")
def bad_files(tmp_path_factory, scans) -> dict[str, tuple[Path, int, str]]:
    return _bad_files(tmp_path_factory.mktemp("bad"), scans)


def _assert_nothing_left(service, http: httpx.Client, total_before: int) -> None:
    assert http.get("/v1/jobs").json()["total"] == total_before
    assert left_in_incoming(service.data_dir) == []


def _json_error(response: httpx.Response, status: int) -> str:
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/json"
    detail = response.json()["detail"]
    assert isinstance(detail, str) and detail
    return detail


@pytest.mark.parametrize(
    "case",
    [f"empty{ext}" for ext in READ_EXTENSIONS]
    + [f"wrong-content{ext}" for ext in WRONG_CONTENT]
    + [
        "truncated-ply",
        "ply-header-without-end",
        "nan-binary-ply",
        "inf-ascii-ply",
        "too-many-points",
        "span-1e18",
        "span-1e300",
        "txt-mismatched-columns",
        "txt-non-numeric",
        "txt-nan",
        "txt-binary-garbage",
        "npy-inf",
        "pcd-ascii-columns",
        "unsupported-scan.docx",
        "unsupported-scan",
    ],
)
def test_bad_scan_gets_4xx_with_the_readers_message(locked, bad_files, case) -> None:
    path, status, needle = bad_files[case]
    with locked.http() as http:
        before = http.get("/v1/jobs").json()["total"]
        detail = _json_error(post_scan(http, path), status)
        assert needle in detail
        assert path.name in detail  # the user's name ...
        assert str(locked.data_dir) not in detail  # ... never the server's path
        _assert_nothing_left(locked, http, before)


@pytest.mark.parametrize(
    ("config", "needle"),
    [
        ("{not json", "not valid JSON"),
        (json.dumps({"fusion": {"ratio_treshold": 0.3}}), "config.fusion.ratio_treshold"),
        (json.dumps({"fusion": {"ratio_threshold": "high"}}), "config.fusion.ratio_threshold"),
        (json.dumps({"seed": [1]}), "config.seed"),
        (json.dumps({"network": {"name": "pointnet"}}), "config.network.name"),
        (json.dumps({"network": {"weights": "/nonexistent/w.pt"}}), "config.network.weights"),
        (
            json.dumps({"network": {"name": "dgcnn", "weights": "dgcnn-s3dis-6"}}),
            "dgcnn-s3dis-6 is not pulled on this service",
        ),
        (json.dumps([1, 2]), "config"),
        (
            json.dumps({"tiles": {"max_points": 50_000_000}}),
            "config.tiles.max_points: 50,000,000 is above this service's limit",
        ),
        (json.dumps({"tiles": {"overlap": -1}}), "config.tiles.overlap"),
        (json.dumps({"frame": {"up": "sideways"}}), "config.frame.up"),
        (json.dumps({"frame": {"units": "furlong"}}), "config.frame.units"),
        (json.dumps({"network": {"colour_free": "maybe"}}), "config.network.colour_free"),
        (json.dumps({"quality": "ultra"}), "config.quality"),
        (json.dumps({"network": {"randlanet": {"views": 0}}}), "config.network.randlanet.views"),
        # accepted by the model, but failed (or took a worker's memory) in the worker before
        (json.dumps({"seed": -1}), "config.seed: -1 must be at least 0"),
        (json.dumps({"seed": 2**64}), "config.seed"),
        ('{"fusion": {"evidence_weight": 1e400}}', "config.fusion.evidence_weight: inf must be"),
        (json.dumps({"geometry": {"face_distance": 1e300}}), "config.geometry.face_distance"),
        (json.dumps({"geometry": {"neighbours": 10**6}}), "config.geometry.neighbours"),
        (json.dumps({"network": {"batch_size": 10**6}}), "config.network.batch_size"),
        (json.dumps({"network": {"dgcnn": {"stride": 1e-9}}}), "config.network.dgcnn.stride"),
    ],
)
def test_bad_config_names_the_field(locked, scans, config, needle) -> None:
    with locked.http() as http:
        before = http.get("/v1/jobs").json()["total"]
        with open(scan_file(scans, ".ply", points=1000, seed=7), "rb") as fh:
            response = http.post(
                "/v1/jobs", files={"file": ("room.ply", fh)}, data={"config": config}
            )
        assert needle in _json_error(response, 422)
        _assert_nothing_left(locked, http, before)


def test_bad_requests(locked, scans) -> None:
    room = scan_file(scans, ".ply", points=1000, seed=7).read_bytes()
    with locked.http() as http:
        before = http.get("/v1/jobs").json()["total"]
        no_file = http.post("/v1/jobs", files={"config": (None, "{}")})
        assert "form field 'file'" in _json_error(no_file, 422)
        extra = http.post("/v1/jobs", files={"file": ("a.ply", room), "other": (None, "x")})
        assert "unknown form field 'other'" in _json_error(extra, 422)
        two = http.post("/v1/jobs", files=[("file", ("a.ply", room)), ("file", ("b.ply", room))])
        assert "given twice" in _json_error(two, 422)
        not_a_file = http.post("/v1/jobs", files={"file": (None, "0 0 0")})
        assert "must be a file" in _json_error(not_a_file, 422)
        as_json = http.post("/v1/jobs", json={"file": "room.ply"})
        assert "multipart/form-data" in _json_error(as_json, 415)
        _assert_nothing_left(locked, http, before)
        assert http.get("/v1/jobs/" + "0" * 32).status_code == 404
        assert http.get("/v1/jobs/not-an-id").status_code == 422
        assert http.get("/v1/jobs", params={"status": "lost"}).status_code == 422
        assert http.get("/v1/jobs", params={"limit": 0}).status_code == 422


@pytest.mark.parametrize(
    ("name", "stored"),
    [
        ("../../escape.ply", "escape.ply"),
        ("..\\..\\windows\\escape.ply", "escape.ply"),
        ("/etc/passwd.ply", "passwd.ply"),
        ("sub/dir/room.ply", "room.ply"),
        ("..ply", "ply"),
    ],
)
def test_hostile_file_names_are_reduced_to_a_base_name(locked, scans, name, stored) -> None:
    with locked.http() as http:
        response = post_scan(http, scan_file(scans, ".ply", points=1000, seed=7), filename=name)
        if stored == "ply":  # nothing but dots and an extension-less name: refused
            assert "unsupported file extension" in _json_error(response, 415)
            return
        assert response.status_code == 201, response.text
        job = response.json()
        assert job["filename"] == stored
        http.delete(f"/v1/jobs/{job['id']}")
    folder = locked.data_dir / "jobs" / job["id"]
    assert [p.name for p in folder.iterdir()] == ["input.ply"]
    assert not (locked.data_dir.parent / "escape.ply").exists()


def test_oversized_file_name(locked, scans) -> None:
    with locked.http() as http:
        room = scan_file(scans, ".ply", points=1000)
        response = post_scan(http, room, filename="a" * 300 + ".ply")
        assert "at most 255" in _json_error(response, 422)
        empty = http.post("/v1/jobs", files={"file": ("", room.read_bytes())})
        assert "file" in _json_error(empty, 422)  # httpx drops an empty name: not a file


def test_upload_over_the_limit_is_413_and_leaves_nothing(locked, scans) -> None:
    big = scan_file(scans, ".ply", points=20_000, seed=3)  # ~ 300 kB > 64 KiB
    assert big.stat().st_size > 64 * 1024
    with locked.http() as http:
        before = http.get("/v1/jobs").json()["total"]
        assert "limit" in _json_error(post_scan(http, big), 413)

        def chunks():  # no Content-Length: the limit is enforced while streaming
            boundary = b"--b0undary"
            yield boundary + b'\r\nContent-Disposition: form-data; name="file"; filename="b.ply"'
            yield b"\r\n\r\n"
            data = big.read_bytes()
            for start in range(0, len(data), 16384):
                yield data[start : start + 16384]
            yield b"\r\n" + boundary + b"--\r\n"

        try:
            streamed = http.post(
                "/v1/jobs",
                content=chunks(),
                headers={"content-type": "multipart/form-data; boundary=b0undary"},
            )
            assert "limit" in _json_error(streamed, 413)
        except httpx.TransportError:
            pass  # the server may close the connection before the client finished sending
        _assert_nothing_left(locked, http, before)


def test_weights_outside_the_weights_folders_get_one_answer(locked, scans, random_weights) -> None:
    """Whether the file exists or not, and whatever it holds, the answer is the same 422: it
    tells nothing about the server's files, and no job (so no worker) ever opens them."""
    room = scan_file(scans, ".ply", points=1000, seed=7)
    link = random_weights.parent / "leads-out.pt"  # a link in the weights folder to outside
    link.unlink(missing_ok=True)
    link.symlink_to("/etc/hostname")
    values = [
        "/etc/hostname",
        "/etc/does-not-exist",
        "/etc/shadow",
        "../../../../../../etc/hostname",
        str(random_weights.parent / ".." / "elsewhere.pt"),
        "leads-out.pt",
    ]
    try:
        with locked.http() as http:
            before = http.get("/v1/jobs").json()["total"]
            bodies = []
            for value in values:
                response = post_scan(http, room, {"network": {"weights": value}})
                detail = _json_error(response, 422)
                assert detail.startswith("config.network.weights: "), detail
                assert "/etc" not in detail and str(random_weights.parent) not in detail
                bodies.append(response.json())
            assert all(body == bodies[0] for body in bodies), bodies
            assert "random.pt" in bodies[0]["detail"]  # the names a job may use
            _assert_nothing_left(locked, http, before)

            # the same file by its name in the weights folder, or by its path: accepted
            for value in ("random.pt", str(random_weights)):
                accepted = post_scan(http, room, {"network": {"weights": value}})
                assert accepted.status_code == 201, accepted.text
                http.delete(f"/v1/jobs/{accepted.json()['id']}")
    finally:
        link.unlink()
