"""API keys: every /v1 route needs one when keys are configured; /healthz stays open; keys are
never written to the log."""

from __future__ import annotations

import httpx
import pytest

from tests.support.service_process import post_scan, scan_file

ROUTES = [
    ("GET", "/v1/jobs"),
    ("GET", "/v1/jobs/" + "a" * 32),
    ("GET", "/v1/jobs/" + "a" * 32 + "/result"),
    ("GET", "/v1/jobs/" + "a" * 32 + "/report"),
    ("DELETE", "/v1/jobs/" + "a" * 32),
    ("POST", "/v1/jobs"),
]


@pytest.mark.parametrize(("method", "path"), ROUTES)
@pytest.mark.parametrize(
    "header", [None, "Bearer wrong-key", "Basic a2V5LW9uZTo=", "Token key-one"]
)
def test_missing_or_wrong_key_is_401(locked, method, path, header) -> None:
    headers = {"Authorization": header} if header else {}
    response = httpx.request(method, locked.url + path, headers=headers, timeout=30)
    assert response.status_code == 401, response.text
    assert response.json()["error"] in ("AuthenticationError", "HTTPException")
    assert "detail" in response.json()
    assert response.headers["www-authenticate"] == "Bearer"


def test_every_configured_key_works_and_is_never_logged(locked, scans) -> None:
    for key in ("key-one", "key-two"):
        with httpx.Client(
            base_url=locked.url, headers={"Authorization": f"Bearer {key}"}, timeout=30
        ) as http:
            assert http.get("/v1/jobs").status_code == 200
            created = post_scan(http, scan_file(scans, ".ply", points=1000, seed=7))
            assert created.status_code == 201
            assert http.delete(created.json()["links"]["self"]).status_code == 202
    assert httpx.get(locked.url + "/healthz", timeout=30).status_code == 200  # open
    log = locked.api.text()
    assert "POST /v1/jobs" in log  # requests are logged ...
    assert "key-one" not in log and "key-two" not in log  # ... keys are not


def test_openapi_declares_the_bearer_scheme(locked) -> None:
    schema = httpx.get(locked.url + "/openapi.json", timeout=30).json()
    assert schema["components"]["securitySchemes"]["HTTPBearer"]["scheme"] == "bearer"
    upload = schema["paths"]["/v1/jobs"]["post"]["requestBody"]["content"]
    assert upload["multipart/form-data"]["schema"]["required"] == ["file"]
