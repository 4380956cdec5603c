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

    .venv/bin/python bench/viewer.py [--points 1000000] [--repeats 3] [--cache bench/_cache]
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cache", type=Path, default=ROOT / "bench" / "_cache")
    args = parser.parse_args()

    from playwright.sync_api import sync_playwright

    from web.sources import DirectorySource
    from web.viewer import Viewer

    big, small = make_results(args.points, args.cache)
    rows = []
    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as pw:
        folder = Path(tmp)
        stage_jobs(big, small, folder)
        viewer = Viewer(DirectorySource(folder), port=8190)
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            for job_id in ("big_plain", "big_truth"):
                row = measure(viewer, browser, job_id, args.repeats)
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


if __name__ == "__main__":
    main()
