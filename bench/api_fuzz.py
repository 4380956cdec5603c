"""schemathesis over the whole API with a valid key (issue 44 acceptance): 100 examples per
operation, every answer checked against the schema.

Starts `jointseg serve` (one worker) with an API key on a free loopback port, runs one small
job to the end, loads its ``/openapi.json`` and, for every operation it lists, runs
``--examples`` generated requests with the key. Generated job ids are never real and generated
files never scans, so a drawn share of the requests is steered: a real job's id in the path
(the finished job, or a cancelled one), or a real PLY with the generated config. Each answer is
checked as the suite's tests/server/test_openapi_fuzz.py checks its 25: no 5xx, and the status,
media type, body and headers all listed in the schema, every error in the
``{"error", "detail"}`` shape. Prints one row per operation: examples run, 5xx answers, schema
violations, the statuses seen and the first violation of each kind; then the totals.

    .venv/bin/python bench/api_fuzz.py [--examples 100] [--workers 1]
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import schemathesis
from helpers.report import header
from helpers.service import start_service
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis.checks import (
    content_type_conformance,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)
from schemathesis.core.result import Err

from jointseg.io import write_scan
from jointseg.scan import Scan

log = logging.getLogger("bench.api_fuzz")

KEY = "bench-fuzz-key"
#: The suite's checks (tests/server/test_openapi_fuzz.py), the 5xx one counted apart.
SCHEMA_CHECKS = [
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
    response_headers_conformance,
]


@dataclass
class Row:
    """What one operation's run found."""

    label: str
    examples: int = 0
    server_errors: int = 0
    violations: int = 0
    statuses: Counter[int] = field(default_factory=Counter)
    kinds: Counter[str] = field(default_factory=Counter)
    first: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0


def _failures(exc: BaseException) -> list[BaseException]:
    """The single failures inside a schemathesis FailureGroup (or the exception itself)."""
    inner = getattr(exc, "exceptions", None)
    if inner:
        return [f for e in inner for f in _failures(e)]
    return [exc]


def _record(row: Row, kind: str, detail: str) -> None:
    row.kinds[kind] += 1
    row.first.setdefault(kind, detail.splitlines()[0][:160] if detail else kind)


@dataclass
class Seeds:
    """What generated requests are steered to, so they reach past the first check: real job ids
    (a generated id is never one) and a real scan (a generated file is never one)."""

    job_ids: list[str]
    scan: bytes


def _call(case: Any, url: str, headers: dict[str, str], seeds: Seeds, pick: int) -> Any:
    """Send ``case``; for ``pick`` below the seeds, with a real job id in its path or, for an
    upload, a real scan with the generated config."""
    if "job_id" in (case.path_parameters or {}) and pick < len(seeds.job_ids):
        case.path_parameters["job_id"] = seeds.job_ids[pick]
    elif case.method == "POST" and pick % 2 == 0 and isinstance(case.body, dict):
        config = case.body.get("config")
        return case.call(
            base_url=url,
            headers=headers,
            timeout=60,
            files={"file": ("room.ply", seeds.scan)},
            data={"config": config} if isinstance(config, str) else None,
        )
    return case.call(base_url=url, headers=headers, timeout=60)


def fuzz(operation: Any, url: str, examples: int, seeds: Seeds) -> Row:
    """``examples`` generated requests to ``operation``; every failure counted, none raised
    (so hypothesis keeps generating rather than shrinking the first one)."""
    row = Row(operation.label)
    headers = {"Authorization": f"Bearer {KEY}"}

    @given(case=operation.as_strategy(), pick=st.integers(0, 2 * len(seeds.job_ids) + 1))
    @settings(
        max_examples=examples,
        deadline=None,
        suppress_health_check=list(HealthCheck),
        database=None,
    )
    def run(case: Any, pick: int) -> None:
        row.examples += 1
        try:
            response = _call(case, url, headers, seeds, pick)
        except Exception as exc:  # noqa: BLE001 - a dropped connection is a finding too
            row.server_errors += 1
            _record(row, f"no answer: {type(exc).__name__}", str(exc))
            return
        row.statuses[response.status_code] += 1
        if response.status_code >= 500:
            row.server_errors += 1
            _record(row, f"{response.status_code}", response.text)
        found = False
        try:
            case.validate_response(response, checks=SCHEMA_CHECKS)
        except Exception as exc:  # noqa: BLE001 - schemathesis raises a group of failures
            for failure in _failures(exc):
                title = getattr(failure, "title", type(failure).__name__)
                _record(row, str(title), f"{case.method} {case.formatted_path}: {failure}")
            found = True
        if response.status_code >= 400:
            try:
                shape = set(response.json())
            except ValueError:
                shape = set()
            if shape != {"error", "detail"}:
                _record(row, "error shape", f"{response.status_code}: {response.text[:120]}")
                found = True
        row.violations += found

    started = time.monotonic()
    run()
    row.seconds = time.monotonic() - started
    return row


def _seeds(url: str, folder: Path, workers: int) -> Seeds:
    """A small room as PLY and two jobs of it: one finished (when there is a worker to run
    it, so results, reports and objects answer 200) and one cancelled."""
    path = folder / "room.ply"
    rng = np.random.default_rng(0)
    xyz = rng.random((3000, 3)) * [4.0, 3.0, 2.5]
    write_scan(Scan(xyz=xyz, rgb=rng.integers(0, 256, (3000, 3)).astype(np.uint8)), path)
    scan = path.read_bytes()
    headers = {"Authorization": f"Bearer {KEY}"}
    ids = []
    with httpx.Client(base_url=url, headers=headers, timeout=120) as http:
        for _ in range(2):
            answer = http.post(
                "/v1/jobs",
                files={"file": ("room.ply", scan)},
                data={"config": '{"network": {"device": "cpu"}}'},
            )
            answer.raise_for_status()
            ids.append(answer.json()["id"])
        http.delete(f"/v1/jobs/{ids[1]}").raise_for_status()  # cancelled (or deleted)
        deadline = time.monotonic() + 600
        while workers and time.monotonic() < deadline:
            if http.get(f"/v1/jobs/{ids[0]}").json()["status"] in ("succeeded", "failed"):
                break
            time.sleep(1)
        log.info("seed job %s: %s", ids[0], http.get(f"/v1/jobs/{ids[0]}").json()["status"])
    return Seeds(ids, scan)


def main() -> None:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=100, help="examples per operation")
    parser.add_argument("--workers", type=int, default=1, help="workers of the service")
    args = parser.parse_args()
    header()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    rows: list[Row] = []
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp)
        proc, url = start_service(data, args.workers, wait_s=180, key=KEY, JOINTSEG_API_KEYS=KEY)
        try:
            seeds = _seeds(url, data, args.workers)
            schema = schemathesis.openapi.from_url(f"{url}/openapi.json")
            operations = []
            for result in schema.get_all_operations():
                if isinstance(result, Err):
                    raise result.err()  # a schema the fuzzer cannot read is itself the finding
                operations.append(result.ok())
            # deletions last, so the seeded jobs are there for the other operations
            operations.sort(key=lambda op: op.method.upper() == "DELETE")
            for operation in operations:
                log.info("fuzzing %s", operation.label)
                rows.append(fuzz(operation, url, args.examples, seeds))
        finally:
            proc.terminate()
            proc.wait(60)
    print(
        f"schemathesis {schemathesis.__version__}, {args.examples} examples per operation, "
        f"valid key, workers: {args.workers}"
    )
    print("| operation | examples | 5xx | schema violations | statuses seen | seconds |")
    print("|---|---:|---:|---:|---|---:|")
    for row in rows:
        statuses = " ".join(f"{s}×{n}" for s, n in sorted(row.statuses.items()))
        print(
            f"| {row.label} | {row.examples} | {row.server_errors} | {row.violations} | "
            f"{statuses} | {row.seconds:.1f} |"
        )
    total = Row("total")
    for row in rows:
        total.examples += row.examples
        total.server_errors += row.server_errors
        total.violations += row.violations
    print(
        f"| **total ({len(rows)} operations)** | {total.examples} | {total.server_errors} | "
        f"{total.violations} | | {sum(r.seconds for r in rows):.1f} |"
    )
    found = [(row.label, kind, n, row.first[kind]) for row in rows for kind, n in row.kinds.items()]
    if found:
        print("\n| operation | finding | times | first seen |")
        print("|---|---|---:|---|")
        for label, kind, n, first in found:
            print(f"| {label} | {kind} | {n} | {first.replace('|', '/')} |")


if __name__ == "__main__":
    main()
