"""How fast the viewer shows a big job: from choosing it in the job picker to its panels
received by a headless browser, and how many bytes that sends per point.

A 1 M-point synthetic room goes through the real pipeline once (bundled weights; cached in
--cache), then the viewer serves a folder with that result (once with ground truth: four
panels, once without: three) and a small job. Debian's headless chromium (/usr/bin/chromium,
driven by Playwright) opens a fresh tab on the small job for each timed run, opens the picker
and clicks the big job's entry. Times from that click:

- sent: the viewer has read (or found cached), prepared and handed every panel to the socket;
- received: the browser's end has acknowledged every byte sent (kernel TCP counters of the
  viewer's sockets, read with `ss`): the panels have reached the browser;
- in scene: the browser answered a request sent after the last panel, which it does only
  once it has handled every message before it (the panels are in its scene; drawing them is
  then the GPU's work, SwiftShader's on this machine).

The first pick reads the result file (cold), later ones reuse the viewer's cache (warm, the
median is shown). Bytes are counted from the same socket counters. Target (issue 8): <= 5 s
from choosing a 1 M-point job to its three panels received.

Big results (issue 16): ``--part big`` opens results of 1 M, 4 M and 20 M points (``--sizes``),
more than a panel shows (2 M points), and follows the viewer's own process: its resident memory
before, after opening a result, and after opening and closing results of the same size
several times (flat: no growth), and the time from a fresh tab's request to a usable scene.
These results are not made by the pipeline (minutes at 20 M points): each is a synthetic
28-room floor (``jointseg synth --floor 28 --points N``, through ``jointseg.synth.make_floor``)
with its ground truth, and the pipeline's five fields filled with plausible values
(:func:`make_big_result`), written by ``jointseg.io.write_scan`` as the service writes a result.
The viewer runs in its own process (as in ``jointseg serve``), driven over its stdin; memory
is read a moment after each tab closes, once the viewer has handed freed memory back
(``web.memory``). Target (issue 16): a 20 M-point result opened within 5 s, memory flat over
repeated opens.

    .venv/bin/python bench/viewer.py [--part pick|big|both] [--points 1000000] [--repeats 3]
        [--sizes 1000000,4000000,20000000] [--opens 6] [--cache bench/_cache]
"""

from __future__ import annotations

import argparse
import gc
import json
import logging
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, TextIO

from helpers.report import header

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--no-first-run", "--disable-dev-shm-usage"]  # fmt: skip


def make_results(points: int, cache: Path) -> tuple[Path, Path]:
    """The big result (with ground truth) and a small one, made by the pipeline once."""
    from jointseg.io import write_scan
    from jointseg.pipeline import PipelineConfig, annotate, report_body, run
    from jointseg.synth import make_room

    cache.mkdir(parents=True, exist_ok=True)
    out = {}
    for name, n in (("big", points), ("small", 20_000)):
        path = cache / f"viewer_{name}_{n}.ply"
        if not path.exists():
            t = time.perf_counter()
            scan = make_room(0, points=n)
            result = run(scan, PipelineConfig(seed=0))
            write_scan(annotate(scan, result), path)
            report = report_body(scan, result)
            path.with_suffix(".report.json").write_text(json.dumps(report))
            print(f"made {path} in {time.perf_counter() - t:.0f} s", flush=True)
        out[name] = path
    return out["big"], out["small"]


def make_big_result(points: int, cache: Path, *, seed: int = 0) -> Path:
    """A result file of ``points`` points as the pipeline writes one, without running it.

    The scan is a synthetic 28-room floor (``jointseg.synth.make_floor``, what ``jointseg synth
    --floor 28 --points N`` writes) with its ground truth; the pipeline's five fields are filled
    with plausible values instead of a network run (minutes at 20 M points): ``segment`` is one
    id per 0.6 m cell and ground-truth class, ``network_label`` the ground truth with 8 % of the
    segments and 3 % of the points given a wrong class, ``fused_label`` the ground truth with
    half of those segments still wrong (the point noise voted away), confidences random. The
    file is written by ``jointseg.io.write_scan`` after ``Scan.with_fields`` as
    ``jointseg.pipeline.outputs.annotate`` does, with a report holding the scores.
    """
    import numpy as np

    from jointseg.classes import NUM_CLASSES
    from jointseg.grouping import compact_ids
    from jointseg.io import write_scan
    from jointseg.metrics import evaluate
    from jointseg.synth import make_floor

    cache.mkdir(parents=True, exist_ok=True)
    path = cache / f"viewer_floor28_{points}.ply"
    if path.exists():
        return path
    t = time.perf_counter()
    scan = make_floor(seed, rooms=28, points=points)
    assert scan.labels is not None
    truth = scan.labels.astype(np.int32)
    rng = np.random.default_rng(seed)
    cell = np.floor((scan.xyz - scan.xyz.min(axis=0)) / 0.6).astype(np.int64)
    dims = cell.max(axis=0) + 1
    key = ((truth.astype(np.int64) + 1) * dims[0] + cell[:, 0]) * dims[1] + cell[:, 1]
    key = key * dims[2] + cell[:, 2]
    _, segment = compact_ids(key)
    segment = segment.astype(np.int32)
    del cell, key
    n_seg = int(segment.max()) + 1
    wrong = rng.random(n_seg) < 0.08
    other = rng.integers(0, NUM_CLASSES, n_seg).astype(np.int32)
    still = wrong & (rng.random(n_seg) < 0.5)
    network = np.where(wrong[segment], other[segment], truth)
    noise = rng.random(len(scan)) < 0.03
    network[noise] = rng.integers(0, NUM_CLASSES, int(noise.sum()))
    fused = np.where(still[segment], other[segment], truth).astype(np.int32)
    confidence = rng.uniform(0.4, 1.0, len(scan)).astype(np.float32)
    confidence[noise] *= 0.5
    result = scan.with_fields(
        network_label=network.astype(np.int32),
        network_confidence=confidence,
        segment=segment,
        fused_label=fused,
        fused_confidence=rng.uniform(0.5, 1.0, len(scan)).astype(np.float32),
    )
    write_scan(result, path)
    report = {
        "points": len(scan),
        "segments": n_seg,
        "labels_changed": int(np.count_nonzero(network != fused)),
        "metrics": {
            "network": evaluate(truth, network).model_dump(),
            "fused": evaluate(truth, fused).model_dump(),
        },
        "note": "synthetic fields, no network run (bench/viewer.py make_big_result)",
    }
    path.with_suffix(".report.json").write_text(json.dumps(report))
    print(f"made {path} in {time.perf_counter() - t:.0f} s", flush=True)
    return path


def stage_jobs(big: Path, small: Path, folder: Path) -> None:
    """big_truth (4 panels), big_plain (3 panels: ground truth removed) and small."""
    from jointseg.io import read_scan, write_scan
    from jointseg.scan import Scan

    (folder / "big_truth.ply").symlink_to(big)
    (folder / "big_truth.report.json").symlink_to(big.with_suffix(".report.json"))
    scan = read_scan(big)
    write_scan(Scan(scan.xyz, scan.rgb, None, scan.fields), folder / "big_plain.ply")
    (folder / "small.ply").symlink_to(small)


def socket_bytes(port: int) -> dict[str, tuple[int, int]]:
    """Bytes each connection to the viewer's port has sent and had acknowledged by the browser
    (kernel TCP counters, read with `ss`), by peer address."""
    out = subprocess.run(
        ["ss", "-tinH", "state", "established", f"( sport = :{port} )"],
        capture_output=True, text=True, check=True,
    ).stdout.splitlines()  # fmt: skip
    counters = {}
    for head, info in zip(out[::2], out[1::2], strict=False):
        sent = re.search(r"bytes_sent:(\d+)", info)
        acked = re.search(r"bytes_acked:(\d+)", info)
        counters[head.split()[-1]] = (
            int(sent.group(1)) if sent else 0,
            int(acked.group(1)) if acked else 0,
        )
    return counters


def grown(before: dict[str, tuple[int, int]], after: dict[str, tuple[int, int]]) -> tuple[int, int]:
    """Bytes sent and acknowledged between two readings, over the connections in ``after``."""
    sent = acked = 0
    for peer, (s, a) in after.items():
        s0, a0 = before.get(peer, (0, 0))
        sent, acked = sent + s - s0, acked + a - a0
    return sent, acked


def sent_by(viewer: Any, job_id: str, timeout: float = 120.0) -> Any:
    """The newest tab's view once it shows ``job_id`` and has handed every panel to its
    websocket."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        views = sorted(viewer.views.items())
        if views and views[-1][1].job_id == job_id:
            view = views[-1][1]
            with view._lock:  # show_job holds it until every panel is queued
                pass
            view.client.flush()
            return view
        time.sleep(0.002)
    raise TimeoutError(f"{job_id} not shown in {timeout} s")


def in_scene(view: Any, timeout: float = 120.0) -> None:
    """Return once the browser has handled every message sent so far: it answers this request
    only after the ones queued before it."""
    view.client.local_storage.get_item("bench-ping", timeout=timeout)


def one_pick(viewer: Any, browser: Any, job_id: str) -> dict[str, float]:
    """A fresh tab on the small job; choose ``job_id`` with a click and time its arrival."""
    page = browser.new_page(viewport={"width": 1600, "height": 900})
    page.goto(viewer.link("small"))
    page.get_by_text("points shown").wait_for(timeout=60_000)
    in_scene(sent_by(viewer, "small"))
    page.get_by_label("Job", exact=True).click()
    option = page.get_by_role("option", name=f"{job_id}.ply", exact=False)
    option.wait_for()
    before = socket_bytes(viewer.port)
    t0 = time.perf_counter()
    option.click()
    view = sent_by(viewer, job_id)
    t_sent = time.perf_counter()
    # the socket writes run on viser's event loop after show_job returns: wait until the
    # browser has acknowledged at least the panels' payload (float32 xyz + rgb per point and
    # panel; the few other bytes are GUI updates)
    payload = 15 * view.data.xyz.shape[0] * len(view.visible_panels())
    while True:
        sent, acked = grown(before, socket_bytes(viewer.port))
        if acked >= payload:
            break
        time.sleep(0.02)
    t_received = time.perf_counter()
    in_scene(view)
    t_scene = time.perf_counter()
    sent, _ = grown(before, socket_bytes(viewer.port))
    page.close()
    return {
        "sent_s": t_sent - t0,
        "received_s": t_received - t0,
        "scene_s": t_scene - t0,
        "bytes": float(sent),
    }


def measure(viewer: Any, browser: Any, job_id: str, repeats: int) -> dict[str, Any]:
    """A cold pick (file read) and ``repeats`` warm ones (cached); medians of the warm ones."""
    viewer.cache._entries.clear()
    runs = []
    for _ in range(repeats + 1):
        runs.append(one_pick(viewer, browser, job_id))
        data = viewer.cache.load(viewer.source.result_path(job_id))
    warm = runs[1:] or runs
    panels = 4 if data.truth is not None else 3
    return {
        "job": job_id,
        "cold": runs[0],
        "warm": {k: statistics.median(r[k] for r in warm) for k in runs[0]},
        "panels": panels,
        "shown": data.xyz.shape[0],
        "total": data.total_points,
    }


# ---------------------------------------------------------------- big results (issue 16)
def memory() -> dict[str, int]:
    """This process's memory from /proc/self/status, bytes: resident (VmRSS), its anonymous and
    file-backed parts, and the peak resident since start or the last ``reset-peak`` (VmHWM)."""
    keys = {"VmRSS": "rss", "RssAnon": "anon", "RssFile": "file", "VmHWM": "peak"}
    out = {}
    for line in Path("/proc/self/status").read_text().splitlines():
        name, _, value = line.partition(":")
        if name in keys:
            out[keys[name]] = int(value.split()[0]) * 1024
    return out


def serve_viewer(folder: Path, port: int) -> None:
    """The viewer process of ``--part big``: a Viewer on ``folder`` taking one command per line
    on stdin and answering each with one JSON line on stdout.

    ``memory``: :func:`memory` after a garbage collection; ``reset-peak``: restart the peak;
    ``sent JOB``: wait until the newest tab shows JOB and has handed every panel to its socket;
    ``scene JOB``: wait until that tab's browser has handled every message (:func:`in_scene`);
    ``views``: tabs connected; ``quit``.
    """
    # the answers get the process's stdout to themselves; anything printed goes to stderr
    out: TextIO = os.fdopen(os.dup(sys.stdout.fileno()), "w")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())

    from web.sources import DirectorySource
    from web.viewer import Viewer

    try:
        from web.memory import TRIM_DELAY_S
    except ImportError:  # measuring a viewer from before web.memory
        TRIM_DELAY_S = 1.0

    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    viewer = Viewer(DirectorySource(folder), port=port)
    loads: list[float] = []
    load = viewer.cache.load

    def timed(*args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        try:
            return load(*args, **kwargs)
        finally:
            loads.append(time.perf_counter() - t)

    viewer.cache.load = timed  # type: ignore[method-assign]
    out.write(json.dumps({"port": viewer.port}) + "\n")
    out.flush()
    view: Any = None
    for line in sys.stdin:
        command, _, arg = line.strip().partition(" ")
        reply: dict[str, Any] = {}
        if command == "memory":
            # after what the viewer does once a tab closes or a job is shown: viser drops what
            # it was sending, and web.memory gives the freed heap back TRIM_DELAY_S later
            time.sleep(TRIM_DELAY_S + 1.0)
            gc.collect()
            reply = memory()
        elif command == "reset-peak":
            Path("/proc/self/clear_refs").write_text("5")
        elif command == "sent":
            view = sent_by(viewer, arg, timeout=300)
            data = view.data
            reply = {
                "t": time.monotonic(),
                "load_s": loads[-1] if loads else float("nan"),
                "shown": int(data.xyz.shape[0]),
                "total": int(data.total_points),
                "panels": len(view.visible_panels()),
                "per_panel": max(
                    sum(n.points.shape[0] for k, n in view.panels.nodes.items() if k[0] == p.key)
                    for p in view.visible_panels()
                ),
            }
        elif command == "scene":
            in_scene(view, timeout=300)
            reply = {"t": time.monotonic()}
            view = None
        elif command == "views":
            reply = {"views": len(viewer.views)}
        elif command == "quit":
            break
        out.write(json.dumps(reply) + "\n")
        out.flush()
    viewer.stop()


class ViewerProcess:
    """``bench/viewer.py --serve-viewer FOLDER`` in a child process, and its commands."""

    def __init__(self, folder: Path, port: int) -> None:
        cmd = [sys.executable, __file__, "--serve-viewer", str(folder), "--port", str(port)]
        self.process = subprocess.Popen(
            cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        self.port = int(self._read()["port"])

    def _read(self) -> dict[str, Any]:
        assert self.process.stdout is not None
        line = self.process.stdout.readline()
        if not line:
            raise RuntimeError(f"the viewer process ended (exit code {self.process.wait()})")
        return dict(json.loads(line))

    def ask(self, command: str) -> dict[str, Any]:
        assert self.process.stdin is not None
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()
        return self._read()

    def wait_for_views(self, count: int, timeout: float = 30.0) -> None:
        """Until ``count`` tabs are connected (a closed tab's view is dropped)."""
        deadline = time.monotonic() + timeout
        while self.ask("views")["views"] != count:
            if time.monotonic() > deadline:
                raise TimeoutError(f"the viewer still has tabs other than {count}")
            time.sleep(0.1)

    def close(self) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write("quit\n")
        self.process.stdin.close()
        self.process.wait(60)


def open_tab(viewer: ViewerProcess, browser: Any, job_id: str) -> tuple[Any, dict[str, float]]:
    """A fresh tab requesting ``job_id`` by its link, as the job page's view link does; seconds
    from the request until the viewer has loaded the result, handed every panel to the socket,
    the browser has acknowledged the panels' bytes, and has them in its scene."""
    from web.viewer import viewer_link

    page = browser.new_page(viewport={"width": 1600, "height": 900})
    before = socket_bytes(viewer.port)
    t0 = time.monotonic()
    page.goto(viewer_link(f"http://127.0.0.1:{viewer.port}", job_id))
    sent = viewer.ask(f"sent {job_id}")
    payload = 15 * sent["per_panel"] * sent["panels"]  # float32 xyz + rgb per point and panel
    while grown(before, socket_bytes(viewer.port))[1] < payload:
        time.sleep(0.02)
    t_received = time.monotonic()
    scene = viewer.ask(f"scene {job_id}")
    return page, {
        "load_s": sent["load_s"],
        "sent_s": sent["t"] - t0,
        "received_s": t_received - t0,
        "scene_s": scene["t"] - t0,
        "shown": sent["shown"],
        "per_panel": sent["per_panel"],
        "panels": sent["panels"],
        "total": sent["total"],
    }


def measure_big(result: Path, browser: Any, opens: int, port: int) -> dict[str, Any]:
    """One viewer process on three names of ``result`` (the cache keeps two, so every open
    reads the file): memory before, with the first open's tab showing it, after closing that
    tab, and after ``opens`` more tabs opened and closed in turn over the three names."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        names = [f"{result.stem}_{c}" for c in "abc"]
        for name in names:
            (folder / f"{name}.ply").symlink_to(result.resolve())
            (folder / f"{name}.report.json").symlink_to(result.with_suffix(".report.json"))
        viewer = ViewerProcess(folder, port)
        try:
            before = viewer.ask("memory")
            viewer.ask("reset-peak")
            page, first = open_tab(viewer, browser, names[0])
            opened = viewer.ask("memory")
            page.close()
            viewer.wait_for_views(0)
            closed = viewer.ask("memory")
            runs, after = [first], [closed]
            for i in range(opens):
                page, run = open_tab(viewer, browser, names[(i + 1) % 3])
                runs.append(run)
                page.close()
                viewer.wait_for_views(0)
                after.append(viewer.ask("memory"))
        finally:
            viewer.close()
    later = runs[1:] or runs
    median = {k: statistics.median(r[k] for r in later) for k in first}
    return {
        "result": result.name,
        "first": first,
        "median": {k: v if k.endswith("_s") else int(v) for k, v in median.items()},
        "worst_scene_s": max(r["scene_s"] for r in runs),
        "before": before,
        "opened": opened,
        "closed": closed,
        "after": after[-1],
        "rss_after_each": [m["rss"] for m in after],
    }


def print_big(rows: list[dict[str, Any]], opens: int) -> None:
    mb = 1 << 20
    print()
    print(
        "| points | per panel (panels) | open | load (s) | sent (s) | received (s) | in scene (s) |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        for kind in ("first", "median"):
            m = r[kind]
            label = "first" if kind == "first" else f"median of {opens} more"
            print(
                f"| {m['total']:,} | {m['per_panel']:,} ({m['panels']}) | {label} | "
                f"{m['load_s']:.2f} | {m['sent_s']:.2f} | {m['received_s']:.2f} | "
                f"{m['scene_s']:.2f} |"
            )
    print()
    print(
        "| points | RSS before (MB) | with it open (MB) | peak while opening (MB) "
        f"| after closing (MB) | after {opens} more opens and closes (MB) | RSS after each (MB) |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        each = " ".join(f"{v / mb:.0f}" for v in r["rss_after_each"])
        print(
            f"| {r['first']['total']:,} | {r['before']['rss'] / mb:.0f} | "
            f"{r['opened']['rss'] / mb:.0f} | {r['opened']['peak'] / mb:.0f} | "
            f"{r['closed']['rss'] / mb:.0f} | {r['after']['rss'] / mb:.0f} | {each} |"
        )


def run_big(sizes: list[int], opens: int, cache: Path) -> None:
    from playwright.sync_api import sync_playwright

    results = [make_big_result(n, cache) for n in sizes]
    rows = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            for result in results:
                row = measure_big(result, browser, opens, port=8191)
                rows.append(row)
                print(f"{result.name}: {json.dumps(row)}", flush=True)
        finally:
            browser.close()
    print_big(rows, opens)


def run_pick(points: int, repeats: int, cache: Path) -> None:
    from playwright.sync_api import sync_playwright

    from web.sources import DirectorySource
    from web.viewer import Viewer

    big, small = make_results(points, cache)
    rows = []
    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as pw:
        folder = Path(tmp)
        stage_jobs(big, small, folder)
        viewer = Viewer(DirectorySource(folder), port=8190)
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            for job_id in ("big_plain", "big_truth"):
                row = measure(viewer, browser, job_id, repeats)
                rows.append(row)
                print(f"{job_id}: {row}", flush=True)
        finally:
            browser.close()
            viewer.stop()

    print()
    print(
        "| job | points | panels | points per panel | pick | sent (s) | received (s) "
        "| in scene (s) | MB sent | bytes / point | bytes / point / panel |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        for kind in ("cold", "warm"):
            m = r[kind]
            print(
                f"| {r['job']} | {r['total']:,} | {r['panels']} | {r['shown']:,} | {kind} | "
                f"{m['sent_s']:.2f} | {m['received_s']:.2f} | {m['scene_s']:.2f} | "
                f"{m['bytes'] / 1e6:.1f} | {m['bytes'] / r['total']:.1f} | "
                f"{m['bytes'] / (r['shown'] * r['panels']):.1f} |"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--part", choices=("pick", "big", "both"), default="both")
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sizes", default="1000000,4000000,20000000")
    parser.add_argument("--opens", type=int, default=6, help="opens after the first (--part big)")
    parser.add_argument("--cache", type=Path, default=ROOT / "bench" / "_cache")
    parser.add_argument("--serve-viewer", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, default=8191, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve_viewer is not None:
        serve_viewer(args.serve_viewer, args.port)
        return
    header()
    if args.part in ("pick", "both"):
        run_pick(args.points, args.repeats, args.cache)
    if args.part in ("big", "both"):
        run_big([int(n) for n in args.sizes.split(",")], args.opens, args.cache)


if __name__ == "__main__":
    main()
