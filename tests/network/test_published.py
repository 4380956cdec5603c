"""`jointseg models pull`: published weights fetched from a real HTTP server on a loopback port.

The server serves files the tests make: a good file, a file with the wrong bytes for its
checksum, a file whose first response is cut halfway (then served with ranges), and a 404.
"""

from __future__ import annotations

import hashlib
import json
import threading
import typing
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from jointseg.exceptions import ConfigError
from jointseg.network import published
from jointseg.network.registry import REGISTRY, resolve_weights
from tests.support.cli import run_cli

GOOD = bytes(range(256)) * 4096  # 1 MiB
CUT = bytes(reversed(range(256))) * 6000


class Files(BaseHTTPRequestHandler):
    """Serves ``files`` with Range support; paths in ``cut_once`` break their first response."""

    files: dict[str, bytes] = {}
    cut_once: set[str] = set()
    ranges: list[str] = []

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        body = self.files.get(self.path)
        if body is None:
            self.send_error(404, "Not Found")
            return
        start = 0
        header = self.headers.get("Range")
        if header:
            self.ranges.append(f"{self.path} {header}")
            start = int(header.removeprefix("bytes=").split("-")[0])
            self.send_response(206)
            self.send_header("Content-Range", f"bytes {start}-{len(body) - 1}/{len(body)}")
        else:
            self.send_response(200)
        self.send_header("Content-Length", str(len(body) - start))
        self.end_headers()
        if self.path in self.cut_once:
            self.cut_once.discard(self.path)
            self.wfile.write(body[start : start + (len(body) - start) // 2])
            self.wfile.flush()
            self.close_connection = True
            return
        self.wfile.write(body[start:])

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def server() -> Iterator[str]:
    Files.files = {"/good.t7": GOOD, "/cut.t7": CUT, "/bad.t7": GOOD[:-1] + b"x"}
    Files.cut_once, Files.ranges = set(), []
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Files)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()
    httpd.server_close()


@pytest.fixture
def catalogue(server: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A catalogue file naming the served files, and an empty cache, both in tmp_path."""
    sha = hashlib.sha256(GOOD).hexdigest()
    entries = [
        {"name": "good", "backend": "dgcnn", "url": f"{server}/good.t7", "sha256": sha},
        {"name": "bad", "backend": "dgcnn", "url": f"{server}/bad.t7", "sha256": sha},
        {
            "name": "cut",
            "backend": "dgcnn",
            "url": f"{server}/cut.t7",
            "sha256": hashlib.sha256(CUT).hexdigest(),
        },
        {"name": "gone", "backend": "dgcnn", "url": f"{server}/gone.t7", "sha256": sha},
        {"name": "nosum", "backend": "dgcnn", "url": f"{server}/good.t7"},
        # a port nothing listens on: the server's own port, a second after it closes, is not
        # safe, so use port 9 (discard), refused on loopback
        {"name": "offline", "backend": "dgcnn", "url": "http://127.0.0.1:9/x.t7", "sha256": sha},
    ]
    path = tmp_path / "catalogue.json"
    path.write_text(json.dumps(entries))
    monkeypatch.setenv(published.CATALOGUE_ENV, str(path))
    monkeypatch.setenv(published.CACHE_ENV, str(tmp_path / "cache"))
    return path


def cache_files(tmp_path: Path) -> list[str]:
    folder = tmp_path / "cache" / "weights"
    return sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []


def test_good_file_lands_checked_with_progress(catalogue: Path, tmp_path: Path) -> None:
    seen: list[float] = []
    path = published.pull("good", progress=lambda stage, f: seen.append(f))
    assert path == tmp_path / "cache" / "weights" / "good.t7"
    assert path.read_bytes() == GOOD
    assert cache_files(tmp_path) == ["good.t7"]  # no .part left
    assert seen[-1] == 1.0 and seen == sorted(seen)
    assert published.pulled_path("good") == path


def test_wrong_checksum_leaves_nothing(catalogue: Path, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="checksum mismatch.*deleted"):
        published.pull("bad")
    assert cache_files(tmp_path) == []
    assert published.pulled_path("bad") is None


def test_connection_cut_halfway_is_resumed_in_the_same_call(
    catalogue: Path, tmp_path: Path
) -> None:
    Files.cut_once.add("/cut.t7")
    path = published.pull("cut", retries=1)
    assert path.read_bytes() == CUT
    assert Files.ranges == [f"/cut.t7 bytes={len(CUT) // 2}-"]
    assert cache_files(tmp_path) == ["cut.t7"]


def test_broken_download_is_kept_for_the_next_run_to_resume(
    catalogue: Path, tmp_path: Path
) -> None:
    Files.cut_once.add("/cut.t7")
    with pytest.raises(ConfigError, match="again to resume"):
        published.pull("cut", retries=0)
    assert cache_files(tmp_path) == ["cut.t7.part"]  # only the partial, never the final name
    assert published.pulled_path("cut") is None
    path = published.pull("cut", retries=0)
    assert path.read_bytes() == CUT and Files.ranges == [f"/cut.t7 bytes={len(CUT) // 2}-"]
    assert cache_files(tmp_path) == ["cut.t7"]


def test_404_and_offline_are_one_line_errors_and_leave_nothing(
    catalogue: Path, tmp_path: Path
) -> None:
    with pytest.raises(ConfigError, match="HTTP 404"):
        published.pull("gone")
    with pytest.raises(ConfigError, match="cannot reach 127.0.0.1:9"):
        published.pull("offline", retries=0)
    assert cache_files(tmp_path) == []


def test_no_published_checksum_needs_consent(catalogue: Path, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="--unverified"):
        published.pull("nosum")
    assert cache_files(tmp_path) == []
    assert published.pull("nosum", unverified=True).read_bytes() == GOOD


def test_unknown_name_and_bad_catalogue(catalogue: Path, tmp_path: Path, monkeypatch) -> None:
    with pytest.raises(ConfigError, match="unknown weights 'nope'.*dgcnn-s3dis-5"):
        published.pull("nope")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps([{"name": "x", "backend": "dgcnn", "url": "ftp://a/b"}]))
    monkeypatch.setenv(published.CATALOGUE_ENV, str(bad))
    with pytest.raises(ConfigError, match=r"bad.json: entry 0: url: .*not an http"):
        published.catalogue()
    bad.write_text("[{")
    with pytest.raises(ConfigError, match="bad.json: not JSON"):
        published.catalogue()


def test_pulled_names_work_as_weights(catalogue: Path, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.delenv(REGISTRY["dgcnn"].env, raising=False)
    with pytest.raises(ConfigError, match="jointseg models pull good"):
        resolve_weights("dgcnn", "good")
    assert resolve_weights("dgcnn") is None  # the default DGCNN weights are not pulled
    path = published.pull("good")
    assert resolve_weights("dgcnn", "good") == path


def test_open3d_ml_checkpoint_is_converted_on_arrival(
    server: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import torch

    from jointseg.network.convert import ZOO_FILE, to_open3d_ml_state
    from jointseg.network.randlanet.checkpoint import load_checkpoint
    from jointseg.network.randlanet.model import RandLANet, RandLANetConfig

    torch.manual_seed(0)
    ours = RandLANet(RandLANetConfig(num_points=4096)).eval()
    src = tmp_path / ZOO_FILE
    torch.save({"model_state_dict": to_open3d_ml_state(ours.state_dict()), "epoch": 3}, src)
    Files.files[f"/{ZOO_FILE}"] = src.read_bytes()
    entry = {
        "name": "zoo",
        "backend": "randlanet",
        "url": f"{server}/{ZOO_FILE}",
        "convert": "open3d-ml",
    }
    (tmp_path / "c.json").write_text(json.dumps([entry]))
    monkeypatch.setenv(published.CATALOGUE_ENV, str(tmp_path / "c.json"))
    monkeypatch.setenv(published.CACHE_ENV, str(tmp_path / "cache"))
    path = published.pull("zoo", unverified=True)
    assert cache_files(tmp_path) == ["zoo.pt"]  # the raw .pth and the partial are gone
    model, card, _ = load_checkpoint(path)
    assert card["source_sha256"] == hashlib.sha256(src.read_bytes()).hexdigest()
    assert ZOO_FILE in card["source"] and card["source_epoch"] == 3
    for (key, a), b in zip(ours.state_dict().items(), model.state_dict().values(), strict=True):
        if key.startswith("stem.") and key.endswith("weight"):
            continue  # colour columns are rescaled by the converter (0-255 vs 0-1)
        assert torch.allclose(a.float(), b.float(), atol=1e-6), key


def test_cached_files_take_a_suffix_their_backend_reads() -> None:
    """published cannot import the registry (the registry imports it), so its table of suffixes
    is checked against the backends' records here."""
    backends = typing.get_args(published.PublishedWeights.model_fields["backend"].annotation)
    assert backends == tuple(published.SUFFIXES)
    for name, suffix in published.SUFFIXES.items():
        assert suffix in REGISTRY[name].suffixes, name
    names = {e.name: e.filename for e in published.BUILT_IN}
    assert names["dgcnn-s3dis-5"] == "dgcnn-s3dis-5.t7"
    assert names["randlanet-s3dis-open3d-ml"] == "randlanet-s3dis-open3d-ml.pt"


def test_built_in_checksums_match_the_shared_copies(shared_file) -> None:
    """The pinned SHA-256 sums are those of the real published files (../shared holds them)."""
    for i in range(1, 7):
        entry = published.lookup(f"dgcnn-s3dis-{i}")
        path = shared_file(f"models/dgcnn_s3dis/model_{i}.t7")
        assert published.file_sha256(path) == entry.sha256, entry.name
        assert entry.url.endswith(f"pretrained/semseg_s3dis/model_{i}.t7")


@pytest.mark.slow
def test_cli_pull_and_list(catalogue: Path, tmp_path: Path) -> None:
    done = run_cli("models", "pull", "good", timeout=120)
    assert done.returncode == 0, done.stderr
    assert "--weights good" in done.stderr
    assert (tmp_path / "cache" / "weights" / "good.t7").read_bytes() == GOOD
    failed = run_cli("models", "pull", "bad", timeout=120)
    assert failed.returncode != 0
    assert failed.stderr.strip().count("\n") == 0 and "checksum mismatch" in failed.stderr
    listed = run_cli("models", "list", timeout=120)
    assert listed.returncode == 0, listed.stderr
    assert "dgcnn-s3dis-6" in listed.stdout and str(tmp_path / "cache") in listed.stdout
