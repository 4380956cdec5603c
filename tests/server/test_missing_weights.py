"""A job for a network without weights on the service is refused at submission (422, naming the
command that installs them), not accepted and failed later in a worker; once the weights are
where `jointseg models pull` puts them, the same job is accepted, without a restart."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from jointseg.network import published
from tests.support.service_process import Service, left_in_incoming, post_scan, running, scan_file


@pytest.fixture(scope="module")
def bare(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Service, Path]]:
    """A service (no worker: jobs stay queued) whose weights cache is empty, and that cache."""
    cache = tmp_path_factory.mktemp("empty-cache")
    folder = tmp_path_factory.mktemp("bare")
    with running(folder, workers=0, api_keys="key-one", cache=str(cache)) as svc:
        yield svc, cache


def test_a_network_without_weights_is_refused_at_submission_then_accepted_once_pulled(
    bare: tuple[Service, Path], scans: Path, dgcnn_random_weights: Path
) -> None:
    service, cache = bare
    room = scan_file(scans, ".ply", points=1000, seed=7)
    with service.http() as http:
        before = http.get("/v1/jobs").json()["total"]
        refused = post_scan(http, room, {"network": {"name": "dgcnn"}})
        assert refused.status_code == 422, refused.text
        assert refused.headers["content-type"] == "application/json"
        detail = refused.json()["detail"]
        assert f"jointseg models pull {published.DEFAULT_DGCNN}" in detail
        assert "config.network.name" in detail and "'dgcnn'" in detail
        assert http.get("/v1/jobs").json()["total"] == before  # no job row ...
        assert left_in_incoming(service.data_dir) == []  # ... and no upload left

        # the default network (bundled weights) is still accepted
        default = post_scan(http, room)
        assert default.status_code == 201, default.text

        # the weights where `jointseg models pull` leaves them: accepted, no restart needed
        pulled = cache / "weights" / published.lookup(published.DEFAULT_DGCNN).filename
        pulled.parent.mkdir(parents=True)
        shutil.copyfile(dgcnn_random_weights, pulled)
        accepted = post_scan(http, room, {"network": {"name": "dgcnn"}})
        assert accepted.status_code == 201, accepted.text
        assert accepted.json()["network"] == "dgcnn"
