"""schemathesis over the ``/v1/models`` routes of the live service, as
``test_openapi_fuzz.py`` does for the jobs' routes: no 5xx, every answer one the schema lists."""

from __future__ import annotations

import pytest

from tests.server.test_openapi_fuzz import _operations
from tests.server.test_openapi_fuzz import test_no_server_errors as fuzz_operation
from tests.support.service_process import Service

MODEL_OPERATIONS = [
    "POST /v1/models",
    "GET /v1/models",
    "GET /v1/models/{model_id}",
    "GET /v1/models/{model_id}/file",
    "DELETE /v1/models/{model_id}",
]


def test_every_model_operation_is_fuzzed(locked: Service) -> None:
    assert set(MODEL_OPERATIONS) <= {op.label for op in _operations(locked.url)}


@pytest.mark.parametrize("label", MODEL_OPERATIONS)
def test_model_routes_answer_as_the_schema_says(locked: Service, label: str) -> None:
    fuzz_operation(locked, label)
