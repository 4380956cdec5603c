"""Upload, poll, download through the real service (uvicorn + two worker processes): every
input format, every result format, the report, and 20 uploads at once."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from jointseg.client import JobClient
from jointseg.io import WRITE_EXTENSIONS, read_scan
from jointseg.pipeline import OUTPUT_FIELDS
from tests.support.service_process import post_scan, scan_file, wait_for

pye57 = pytest.importorskip("pye57")


def _e57(folder: Path, points: int = 3000) -> Path:
    """The synthetic room as an E57 file (jointseg reads E57 but does not write it)."""
    path = folder / f"room_{points}.e57"
    if not path.exists():
        scan = read_scan(scan_file(folder, ".ply", points=points))
        data = {
            "cartesianX": scan.xyz[:, 0],
            "cartesianY": scan.xyz[:, 1],
            "cartesianZ": scan.xyz[:, 2],
            "colorRed": scan.rgb[:, 0],
            "colorGreen": scan.rgb[:, 1],
            "colorBlue": scan.rgb[:, 2],
        }
        with pye57.E57(str(path), mode="w") as e57:
            e57.write_scan_raw(data)
    return path


def _strings(value: object) -> Iterator[str]:
    """Every string inside a JSON value."""
    if isinstance(value, dict):
        for item in value.values():
            yield from _strings(item)
    elif isinstance(value, list):
        for item in value:
            yield from _strings(item)
    elif isinstance(value, str):
        yield value


def _check_result(path: Path, source: Path) -> None:
    expected = read_scan(source)
    result = read_scan(path)
    assert len(result) == len(expected)
    assert set(OUTPUT_FIELDS) <= set(result.fields)
    np.testing.assert_allclose(result.xyz, expected.xyz, atol=1e-3)
    fused = result.fields["fused_label"]
    assert fused.min() >= 0 and fused.max() <= 12
    conf = result.fields["fused_confidence"]
    assert ((conf >= 0) & (conf <= 1)).all()
    if expected.labels is not None:
        np.testing.assert_array_equal(result.labels, expected.labels)


@pytest.mark.parametrize("suffix", sorted({*WRITE_EXTENSIONS, ".e57"}))
def test_round_trip_every_input_format(service, scans, job_config, tmp_path, suffix) -> None:
    source = _e57(scans) if suffix == ".e57" else scan_file(scans, suffix)
    with JobClient(service.url, api_key=service.api_key) as client:
        job = client.submit(source, config=job_config)
        assert job.status == "queued" and job.points == 3000
        done = client.wait(job.id, poll_s=0.1, timeout_s=120)
        out = client.download(job.id, tmp_path / "out.ply")
    assert done.status == "succeeded" and done.progress == 1.0 and done.points == 3000
    assert done.timings is not None and done.timings["total"] > 0
    _check_result(out, source)


def test_result_formats_report_and_links(service, scans, job_config, tmp_path) -> None:
    source = scan_file(scans, ".ply", seed=1)
    with service.http() as http:
        created = post_scan(http, source, job_config)
        assert created.status_code == 201, created.text
        body = created.json()
        assert created.headers["location"] == body["links"]["self"] == f"/v1/jobs/{body['id']}"
        job = wait_for(http, body["id"])
        assert job["status"] == "succeeded", job
        assert job["attempts"] == 1 and job["network"] == "randlanet"
        assert job["started_at"] >= job["created_at"] and job["finished_at"] >= job["started_at"]
        for fmt in ("ply", "las", "laz"):
            response = http.get(body["links"]["result"], params={"format": fmt})
            assert response.status_code == 200
            assert f"_segmented.{fmt}" in response.headers["content-disposition"]
            out = tmp_path / f"result.{fmt}"
            out.write_bytes(response.content)
            _check_result(out, source)
        report = http.get(body["links"]["report"]).json()
    assert report["points"] == 3000 and report["input"] == source.name
    assert {"network", "geometry", "fusion", "read", "write", "total"} <= set(report["timings_s"])
    assert report["metrics"]["fused"]["miou"] is not None  # the synthetic room is labelled
    # the weights by file name only: no path on the server anywhere in the report (issue 44)
    assert report["params"]["network"]["weights"] == Path(job_config["network"]["weights"]).name
    text = json.dumps(report)
    assert str(service.data_dir) not in text
    assert str(Path(job_config["network"]["weights"]).parent) not in text
    assert not [s for s in _strings(report) if s.startswith(("/", "~"))]
    assert report["frame"]["up"]["axis"] == "+z" and report["frame"]["units"]["unit"] == "m"
    # cached conversions next to the PLY the worker wrote
    files = sorted(p.name for p in (service.data_dir / "jobs" / body["id"]).iterdir())
    assert files == ["input.ply", "report.json", "result.las", "result.laz", "result.ply"]


def test_twenty_concurrent_uploads_all_succeed(service, scans, job_config) -> None:
    sources = [scan_file(scans, ".ply", seed=seed, points=2000) for seed in range(5)]
    started = time.monotonic()

    def submit(i: int) -> str:
        with JobClient(service.url, api_key=service.api_key) as client:
            return client.submit(sources[i % len(sources)], config=job_config).id

    with ThreadPoolExecutor(20) as pool:
        ids = list(pool.map(submit, range(20)))
    assert len(set(ids)) == 20
    with JobClient(service.url, api_key=service.api_key) as client:
        jobs = [client.wait(job_id, poll_s=0.2, timeout_s=180) for job_id in ids]
    assert all(job.status == "succeeded" and job.points == 2000 for job in jobs)
    assert time.monotonic() - started < 180


def test_a_job_takes_the_frame_overrides(service, scans, job_config, tmp_path) -> None:
    """A y-up scan in millimetres, with up and units given in the job's config: the report says
    so and the result keeps the file's own coordinates."""
    from jointseg.io import write_scan
    from jointseg.scan import Scan

    room = read_scan(scan_file(scans, ".ply", seed=3))
    source = tmp_path / "yup_mm.ply"
    write_scan(Scan(room.xyz[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0]) * 1000.0, room.rgb), source)
    config = {**job_config, "frame": {"up": "+y", "units": "mm"}}
    with service.http() as http:
        created = post_scan(http, source, config)
        assert created.status_code == 201, created.text
        links = created.json()["links"]
        job = wait_for(http, created.json()["id"])
        assert job["status"] == "succeeded", job
        report = http.get(links["report"]).json()
        result = http.get(links["result"])
    assert report["frame"]["up"] == {
        **report["frame"]["up"],
        "axis": "+y",
        "how": "set by the user",
    }
    assert report["frame"]["units"]["unit"] == "mm"
    out = tmp_path / "result.ply"
    out.write_bytes(result.content)
    assert np.array_equal(read_scan(out).xyz, read_scan(source).xyz)
