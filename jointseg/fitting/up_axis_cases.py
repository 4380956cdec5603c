"""The cases the up-axis weighing is fitted (and benchmarked) on: z-up rooms delivered as users
deliver them (y up, upside down, tilted, sliced, as camera frames...) and real captures whose up
is known, each with the evidence the frame stage gathers on it and the network's verdict on
every signed axis, optionally cached on disk.

Why every axis is judged: the weighing being fitted decides which candidates the network would
judge, so the verdicts of all six are kept and the fit picks those its weights would ask for.
"""

from __future__ import annotations

import hashlib
import json
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.frame import gravity, weigh
from jointseg.frame.colour import decide_colour
from jointseg.frame.decide import gather, judge_candidates, rotation_about
from jointseg.frame.params import FrameParams
from jointseg.frame.sources import SIGNED_AXES
from jointseg.labeller import LabelFn
from jointseg.scan import Scan

#: Part of every cached case's key: bump it when gathering changes what it computes.
GATHER_VERSION = 1
#: The deliveries of a z-up room, in the order they are made (see :func:`deliveries`).
DELIVERIES = (
    "z up, as is", "z up, LAS", "y up export", "y up GLB", "y up phone PLY", "upside down",
    "x up", "z up, tilted", "z up, 1.2 m slice", "z up, half room",
)  # fmt: skip
#: How often scans arrive each way, relative to an even mix: the fit weighs each case by it, so
#: its priors are the world's, not the bench's (z up as is most; upside down and x up rare).
DELIVERY_WEIGHT = {
    "z up, as is": 6.0, "z up, LAS": 2.0, "z up, tilted": 2.0, "z up, 1.2 m slice": 2.0,
    "z up, half room": 2.0, "upside down": 0.2, "x up": 0.3,
}  # fmt: skip


@dataclass
class Case:
    """One delivered scan and the truth about it."""

    name: str
    source: str
    delivery: str
    truth: str | None  # signed file axis nearest the true up; None: unknown
    scan: Scan
    judging: bool = False  # the benchmark's split; a fit reads tuning cases only


@dataclass
class Gathered:
    """A case with the evidence before the network and the network's verdict on each axis."""

    case: Case
    evidence: weigh.Evidence
    net: dict[str, np.ndarray]
    seconds: float


def to_axis(target: str) -> np.ndarray:
    """A proper rotation taking +z to the signed axis ``target``."""
    want = gravity.AXES[target]
    if abs(want[2]) > 0.5:
        return np.eye(3) if want[2] > 0 else rotation_about(np.array([1.0, 0, 0]), 180)
    return rotation_about(np.cross([0.0, 0.0, 1.0], want), 90)


def nearest_axis(up: np.ndarray) -> str:
    """The signed file axis nearest the direction ``up``."""
    i = int(np.argmax(np.abs(up)))
    return ("+" if up[i] > 0 else "-") + "xyz"[i]


def _part(a: np.ndarray | None, m: np.ndarray) -> np.ndarray | None:
    return None if a is None else a[m]


def deliveries(room: Scan, rng: np.random.Generator) -> list[tuple[str, str, Scan]]:
    """(delivery, truth, scan) for one z-up room, in :data:`DELIVERIES` order."""

    def turned(r: np.ndarray, **kw: Any) -> Scan:
        return replace(room, xyz=room.xyz @ r.T, **kw)

    tilt = rotation_about(np.array([*rng.normal(size=2), 0.0]), rng.uniform(5, 20))
    yaw = rotation_about(np.array([0.0, 0.0, 1.0]), rng.uniform(0, 360))
    h = room.xyz[:, 2]
    slice_ = h < np.quantile(h, 0.005) + 1.2
    half = room.xyz[:, 0] < np.median(room.xyz[:, 0])
    out = [
        ("z up, as is", "+z", room),
        ("z up, LAS", "+z", replace(room, source_format="las")),
        ("y up export", "+y", turned(to_axis("+y") @ yaw)),
        ("y up GLB", "+y", turned(to_axis("+y"), source_format="glb",
                                  meta={"up_convention": {"axis": "+y", "source": "glTF"}})),
        ("y up phone PLY", "+y", turned(to_axis("+y") @ yaw,
                                        meta={"comments": ["Exported by Polycam"]})),
        ("upside down", "-z", turned(to_axis("-z") @ yaw)),
        ("x up", "+x", turned(to_axis("+x") @ yaw)),
        ("z up, tilted", "+z", turned(tilt @ yaw)),
        ("z up, 1.2 m slice", "+z", replace(room, xyz=room.xyz[slice_], rgb=_part(room.rgb, slice_),
                                            labels=_part(room.labels, slice_))),
        ("z up, half room", "+z", replace(room, xyz=room.xyz[half], rgb=_part(room.rgb, half),
                                          labels=_part(room.labels, half))),
    ]  # fmt: skip
    return out


def views(room: Scan, rng: np.random.Generator, n: int) -> list[tuple[str, str, Scan]]:
    """Up to ``n`` single camera views of a z-up room in the camera's frame, every other one
    delivered as an organised PCD."""
    from jointseg.synth.views import camera_view

    out = []
    for i in range(n):
        v = camera_view(room, rng)
        if v is None:
            continue
        scan = v.scan
        if i % 2:
            scan = replace(scan, source_format="pcd", meta={"organised": [640, 480]})
        kind = "organised PCD" if i % 2 else "plain PLY"
        out.append((f"camera frame, {kind}", nearest_axis(v.up), scan))
    return out


def room_cases(
    name: str, source: str, room: Scan, *, seed: int, kinds: tuple[str, ...], n_views: int
) -> list[Case]:
    """The deliveries named in ``kinds`` and ``n_views`` camera views of one z-up room. Each
    room draws from its own generator (``seed`` and its name), so adding or leaving out a room
    changes no other room's cases."""
    rng = np.random.default_rng([seed, zlib.crc32(name.encode())])
    out = [
        Case(name, source, delivery, truth, scan)
        for delivery, truth, scan in deliveries(room, rng)
        if delivery in kinds
    ]
    for delivery, truth, scan in views(room, rng, n_views):
        out.append(Case(name, "camera frames", delivery, truth, scan))
    return out


def _case_key(case: Case, geometry: tuple[np.ndarray, np.ndarray], judge_key: str) -> str:
    """The cache key of a gathered case: its points, colour and file facts, the geometry
    steps' weights, the judge and :data:`GATHER_VERSION`."""
    h = hashlib.sha256(f"{GATHER_VERSION}|{judge_key}|{case.scan.source_format}|".encode())
    h.update(json.dumps(case.scan.meta, sort_keys=True, default=str).encode())
    for a in (case.scan.xyz, case.scan.rgb, *geometry):
        h.update(b"none" if a is None else np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:32]


def _gather_now(
    case: Case, label: LabelFn | None, geometry: tuple[np.ndarray, np.ndarray]
) -> dict[str, Any]:
    """The evidence and the verdicts of one case, as plain lists (what the cache holds)."""
    rng = np.random.default_rng(0)
    xyz = case.scan.xyz
    centre = np.median(xyz[:: max(1, len(xyz) // 100_000)], axis=0)
    sample = gravity.frame_sample(xyz - centre, rng)
    g = gather(case.scan, sample, FrameParams(), geometry)
    net: dict[str, np.ndarray] = {}
    if label is not None:
        colour = decide_colour(case.scan.rgb, True)
        net = judge_candidates(g, case.scan, centre, colour, label, list(SIGNED_AXES))
    return {**evidence_record(g.evidence), "net": verdict_record(net)}


def evidence_record(e: weigh.Evidence) -> dict[str, Any]:
    """The evidence before the network as plain JSON types (what a cache of cases holds)."""
    return {
        "file": e.file.tolist(),
        "axis_p": e.axis_p.tolist(),
        "sign_p": e.sign_p.tolist(),
        "room_like": e.room_like,
        "camera_up": e.camera_up,
        "floor_only": None if e.floor_only is None else e.floor_only.tolist(),
    }


def verdict_record(verdicts: dict[str, np.ndarray]) -> dict[str, list[float]]:
    """The network's verdict per candidate axis as plain lists."""
    return {a: np.asarray(v, dtype=np.float64).tolist() for a, v in verdicts.items()}


def _optional(values: list[float] | None) -> np.ndarray | None:
    return None if values is None else np.array(values)


def _from_stored(case: Case, body: dict[str, Any], seconds: float) -> Gathered:
    evidence = weigh.Evidence(
        file=np.array(body["file"]),
        axis_p=np.array(body["axis_p"]),
        sign_p=np.array(body["sign_p"]),
        room_like=bool(body["room_like"]),
        camera_up=body["camera_up"],
        floor_only=_optional(body.get("floor_only")),
    )
    return Gathered(case, evidence, {a: np.array(v) for a, v in body["net"].items()}, seconds)


def gather_case(
    case: Case,
    label: Callable[[], LabelFn | None],
    geometry: tuple[np.ndarray, np.ndarray],
    judge_key: str,
    cache: Path | None = None,
) -> Gathered:
    """One case's evidence and verdicts: from ``cache`` when gathered before with the same
    geometry weights and judge, else gathered now (``label()`` gives the judge, loaded on
    first use) and stored there."""
    path = None if cache is None else cache / "up" / f"{_case_key(case, geometry, judge_key)}.json"
    if path is not None and path.is_file():
        return _from_stored(case, json.loads(path.read_text()), 0.0)
    t = time.perf_counter()
    body = _gather_now(case, label(), geometry)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(body))
        tmp.replace(path)
    return _from_stored(case, body, time.perf_counter() - t)
