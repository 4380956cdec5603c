"""Objects, rooms and the IFC model through the real service (uvicorn + worker processes)."""

from __future__ import annotations

from pathlib import Path

from tests.support.service_process import post_scan, scan_file, wait_for


def test_a_job_serves_its_objects_rooms_and_ifc_model(service, scans, tmp_path: Path) -> None:
    import ifcopenshell

    from jointseg.objects.ifc import entity_counts, validation_errors

    source = scan_file(scans, ".ply", points=20_000, seed=11)
    with service.http() as http:
        created = post_scan(http, source, {})  # the bundled network: real labels, real rooms
        assert created.status_code == 201, created.text
        job_id = created.json()["id"]
        assert wait_for(http, job_id, timeout=180)["status"] == "succeeded"
        body = http.get(f"/v1/jobs/{job_id}/objects")
        assert body.status_code == 200, body.text
        layout = body.json()
        assert layout["rooms"] and layout["walls"] and layout["objects"]
        report = http.get(f"/v1/jobs/{job_id}/report").json()
        assert layout["objects"] == report["objects"]
        # each download names its file as the job page and the viewer save it (issue 45)
        stem = source.name.rsplit(".", 1)[0]
        for route, name in (("objects", "objects"), ("report", "report")):
            header = http.get(f"/v1/jobs/{job_id}/{route}").headers["content-disposition"]
            assert header == f'inline; filename="{stem}_{name}.json"'
        model = http.get(f"/v1/jobs/{job_id}/result", params={"format": "ifc"})
        assert model.status_code == 200
        assert model.headers["content-disposition"] == f'attachment; filename="{stem}.ifc"'
        (tmp_path / "model.ifc").write_bytes(model.content)
        opened = ifcopenshell.open(str(tmp_path / "model.ifc"))
        assert validation_errors(opened) == []
        counts = entity_counts(opened)
        assert counts["IfcSpace"] == len(layout["rooms"])
        assert counts["IfcWall"] == len(layout["walls"])
        # a job run without the objects stage says so, in JSON, for both
        off = post_scan(http, source, {"objects": {"enabled": False}})
        off_id = off.json()["id"]
        assert wait_for(http, off_id, timeout=180)["status"] == "succeeded"
        for url, params in (
            (f"/v1/jobs/{off_id}/objects", None),
            (f"/v1/jobs/{off_id}/result", {"format": "ifc"}),
        ):
            refused = http.get(url, params=params)
            assert refused.status_code == 409, refused.text
            assert "no objects or rooms" in refused.json()["detail"]
        assert not (service.data_dir / "jobs" / off_id / "result.ifc").exists()
