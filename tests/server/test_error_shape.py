"""One error shape: every 4xx and 5xx of the live service, the framework's own (request
validation, unknown routes, wrong methods) included, is ``{"error", "detail"}`` on one line, and
the OpenAPI schema lists the statuses and media types the routes really answer with."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from server.api.errors import MAX_DETAIL, http_status_name, one_line

KEY = {"Authorization": "Bearer key-one"}
JOB = "/v1/jobs/" + "a" * 32

#: Requests the framework, not a route, answers: (method, path, status, error, in the detail).
FRAMEWORK_ERRORS = [
    ("GET", "/v1/jobs?limit=0", 422, "RequestValidationError", "query.limit"),
    ("GET", "/v1/jobs?limit=x&offset=-1", 422, "RequestValidationError", "query.offset"),
    ("GET", "/v1/jobs?status=done", 422, "RequestValidationError", "query.status"),
    ("GET", "/v1/jobs/not-a-job-id", 422, "RequestValidationError", "path.job_id"),
    ("GET", JOB + "/result?format=exe", 422, "RequestValidationError", "query.format"),
    ("GET", "/v1/nothing", 404, "NotFound", "/v1/nothing"),
    ("GET", "/nothing/here", 404, "NotFound", "/nothing/here"),
    ("GET", "/web/nothing.js", 404, "NotFound", "nothing.js"),
    ("PUT", "/v1/jobs", 405, "MethodNotAllowed", "PUT"),
    ("PATCH", JOB, 405, "MethodNotAllowed", "PATCH"),
    ("POST", "/healthz", 405, "MethodNotAllowed", "POST"),
    ("POST", "/v1/jobs", 415, "UnsupportedFormatError", "multipart/form-data"),
]


def _shaped(response: httpx.Response) -> dict[str, Any]:
    assert response.headers["content-type"] == "application/json", response.text
    body = response.json()
    assert set(body) == {"error", "detail"}, body
    assert isinstance(body["detail"], str) and isinstance(body["error"], str), body
    assert "\n" not in response.text and "Traceback" not in response.text
    return dict(body)


@pytest.mark.parametrize(("method", "path", "status", "error", "names"), FRAMEWORK_ERRORS)
def test_framework_errors_have_the_documented_shape(
    locked, method: str, path: str, status: int, error: str, names: str
) -> None:
    response = httpx.request(method, locked.url + path, headers=KEY, timeout=30)
    assert response.status_code == status, response.text
    body = _shaped(response)
    assert body["error"] == error and names in body["detail"], body
    if status == 405:
        assert response.headers["allow"], response.headers  # the methods the path takes


def test_validation_errors_do_not_echo_the_input(locked) -> None:
    secret = "x" * 40 + "-echoed"
    response = httpx.get(f"{locked.url}/v1/jobs?limit={secret}", headers=KEY, timeout=30)
    assert response.status_code == 422
    assert secret not in _shaped(response)["detail"]


def test_messages_are_one_line_and_bounded() -> None:
    assert one_line("failed:\n  File '/usr/src/e57.cpp'\tline 3\r\n") == (
        "failed: File '/usr/src/e57.cpp' line 3"
    )
    long = one_line("y" * (MAX_DETAIL * 3))
    assert len(long) == MAX_DETAIL and long.endswith("…")
    assert (http_status_name(404), http_status_name(405)) == ("NotFound", "MethodNotAllowed")


def test_the_schema_lists_every_error_status_and_media_type(locked) -> None:
    schema = httpx.get(locked.url + "/openapi.json", timeout=30).json()
    assert "HTTPValidationError" not in schema["components"]["schemas"]  # not what 422 sends
    for path, operations in schema["paths"].items():
        for method, operation in operations.items():
            responses = operation["responses"]
            assert {"405", "500"} <= set(responses), (method, path)
            assert "Allow" in responses["405"]["headers"], (method, path)
            for status, response in responses.items():
                if int(status) < 400 or (path, status) == ("/healthz", "503"):
                    continue
                ref = response["content"]["application/json"]["schema"]["$ref"]
                assert ref == "#/components/schemas/ErrorBody", (method, path, status)
            if path.startswith("/v1"):
                assert {"401", "404", "422"} <= set(responses), (method, path)
    result = schema["paths"]["/v1/jobs/{job_id}"]["get"]
    assert "409" not in result["responses"]  # reading a job is never a conflict
    download = schema["paths"]["/v1/jobs/{job_id}/result"]["get"]["responses"]
    assert set(download["200"]["content"]) == {"application/octet-stream", "application/x-step"}
    assert "409" in download
    upload = schema["paths"]["/v1/jobs"]["post"]["responses"]
    assert {"413", "415", "503"} <= set(upload)


def test_an_unexpected_error_is_a_500_in_the_shape_without_its_text(tmp_path) -> None:
    from fastapi.testclient import TestClient

    from server.api.app import create_app
    from server.settings import Settings

    app = create_app(Settings(data_dir=tmp_path))

    @app.get("/boom")
    def boom() -> None:
        raise ValueError("cannot read /srv/jointseg/secret.bin\n  at libfoo.cpp:12")

    with TestClient(app, raise_server_exceptions=False) as client:
        response = client.get("/boom")
    assert response.status_code == 500
    body = _shaped(response)
    assert body["error"] == "InternalError" and "secret" not in response.text
