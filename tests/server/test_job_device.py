"""A job config's network device (issue 25) through the real service: a device no machine has is
refused at submission; CUDA asked for where the worker has none fails the job with the clear
message (the API cannot know the workers' hardware without importing torch, so the worker says it).
"""

from __future__ import annotations

import pytest
import torch

from jointseg.client import JobClient
from jointseg.exceptions import JobFailed, ServiceError
from tests.support.service_process import scan_file


def test_unknown_device_is_refused_at_submission(locked, scans, random_weights) -> None:
    config = {"network": {"weights": str(random_weights), "device": "tpu"}}
    with JobClient(locked.url, api_key=locked.api_key) as client:
        with pytest.raises(ServiceError, match="422 config.network.device"):
            client.submit(scan_file(scans, ".ply", points=1000, seed=7), config=config)


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
def test_cuda_job_on_a_cpu_worker_fails_with_the_reason(service, scans, random_weights) -> None:
    config = {"network": {"weights": str(random_weights), "device": "cuda"}, "seed": 1}
    with JobClient(service.url, api_key=service.api_key) as client:
        job = client.submit(scan_file(scans, ".ply", points=1000, seed=7), config=config)
        with pytest.raises(JobFailed, match="sees no CUDA device") as failed:
            client.wait(job.id, poll_s=0.1, timeout_s=120)
        assert "Traceback" not in str(failed.value) and "internal error" not in str(failed.value)
        assert client.get(job.id).status == "failed"


def test_job_on_the_default_device_succeeds(service, scans, random_weights) -> None:
    """``device`` left out: the worker picks CUDA when present, else the CPU; never forced."""
    config = {"network": {"weights": str(random_weights)}, "seed": 1}
    with JobClient(service.url, api_key=service.api_key) as client:
        job = client.submit(scan_file(scans, ".ply", points=1000, seed=7), config=config)
        assert client.wait(job.id, poll_s=0.1, timeout_s=120).status == "succeeded"
        device = client.report(job.id)["params"]["network"]["device"]
    assert device.startswith("cuda" if torch.cuda.is_available() else "cpu")
