"""schemathesis over the live service's OpenAPI schema: generated requests to every operation,
with a valid key, must never get a 5xx, and every answer must be one the schema lists (status,
media type, body, headers), errors in their one shape."""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis.checks import (
    content_type_conformance,
    not_a_server_error,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)

EXAMPLES_PER_OPERATION = 25
#: What each answer is checked for: no 5xx, and nothing the schema does not list.
CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
    response_headers_conformance,
]
OPERATIONS = [
    "POST /v1/jobs",
    "GET /v1/jobs",
    "GET /v1/jobs/{job_id}",
    "GET /v1/jobs/{job_id}/result",
    "GET /v1/jobs/{job_id}/report",
    "GET /v1/jobs/{job_id}/objects",
    "DELETE /v1/jobs/{job_id}",
    "GET /v1/jobs/{job_id}/labels",
    "PATCH /v1/jobs/{job_id}/labels",
    "POST /v1/jobs/{job_id}/rerun",
    "GET /healthz",
]


def _operations(url: str) -> list:
    schema = schemathesis.openapi.from_url(f"{url}/openapi.json")
    return [result.ok() for result in schema.get_all_operations()]


def test_every_operation_is_fuzzed(locked) -> None:
    assert set(OPERATIONS) <= {op.label for op in _operations(locked.url)}


@pytest.mark.parametrize("label", OPERATIONS)
def test_no_server_errors(locked, label) -> None:
    (operation,) = [op for op in _operations(locked.url) if op.label == label]
    seen: list[int] = []

    @given(case=operation.as_strategy())
    @settings(
        max_examples=EXAMPLES_PER_OPERATION,
        deadline=None,
        suppress_health_check=list(HealthCheck),
        database=None,
    )
    def check(case) -> None:
        response = case.call(base_url=locked.url, headers={"Authorization": "Bearer key-one"})
        seen.append(response.status_code)
        case.validate_response(response, checks=CHECKS)
        if response.status_code >= 400:
            assert set(response.json()) == {"error", "detail"}, response.text

    check()
    assert seen and all(status < 500 for status in seen)
