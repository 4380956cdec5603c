"""Fitting the up-axis weighing (``up_model.json``'s ``weigh``): the plan (which z-up rooms and
captures, delivered which ways, judged by which network), the conditional logit over the six
signed axes fitted on their gathered evidence, and the model file with its provenance.

Why a plan: the inputs of a shipped model must be named so that `jointseg fit up-axis --plan
PLAN` on the same scans writes the same file. The geometry's own axis and sign steps are taken
from an existing model (``geometry_from``) and copied into the new one, since the weighing is
fitted on the probabilities those steps give.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from jointseg.config_file import load_params_file
from jointseg.exceptions import ConfigError
from jointseg.fitting.outputs import labeller_record, network_spec, weights_fingerprint
from jointseg.fitting.provenance import (
    Provenance,
    ScanRecord,
    file_sha256,
    fit_record,
    only_known,
    portable_path,
    write_model,
)
from jointseg.fitting.scans import named_scan_files
from jointseg.fitting.up_axis_cases import (
    DELIVERIES,
    DELIVERY_WEIGHT,
    Case,
    Gathered,
    gather_case,
    room_cases,
)
from jointseg.frame import gravity, weigh
from jointseg.frame.model import MODEL_FILE, read_up_model, weight_vector
from jointseg.frame.sources import SIGNED_AXES
from jointseg.labeller import LabelFn

log = logging.getLogger(__name__)

SignedAxis = Literal["+x", "-x", "+y", "-y", "+z", "-z"]
#: Decimals the fitted weights are written with: a last-bit difference of the optimiser on
#: another machine must not change the file.
DECIMALS = 4


class Capture(BaseModel):
    """A real capture as its sensor delivered it, and the file axis nearest its true up."""

    model_config = ConfigDict(extra="forbid")

    file: Path
    truth: SignedAxis


class UpPlan(BaseModel):
    """Everything an up-axis fit reads besides the scans' and weights' bytes."""

    model_config = ConfigDict(extra="forbid")

    #: z-up room files, or folders of them, relative to the plan's folder
    rooms: list[Path] = []
    captures: list[Capture] = []
    deliveries: list[str] = list(DELIVERIES)
    #: camera views cut from every room
    views: int = Field(4, ge=0)
    seed: int = Field(0, ge=0)
    delivery_weight: dict[str, float] = dict(DELIVERY_WEIGHT)
    #: L2 penalty of the weights
    l2: float = Field(1.0, ge=0)
    #: the network that judges candidate frames (``backend[:weights]``)
    judge: str = "randlanet"
    #: the model whose geometry steps (axis and sign weights) are kept; None: the shipped one
    geometry_from: Path | None = None

    @field_validator("deliveries")
    @classmethod
    def _known(cls, names: list[str]) -> list[str]:
        return only_known(names, DELIVERIES, "deliveries")


def read_plan(path: Path) -> UpPlan:
    """The plan at ``path``, validated (a ConfigError naming the file and field otherwise)."""
    return load_params_file(path, UpPlan)


def plan_cases(plan: UpPlan, base: Path) -> tuple[list[Case], list[ScanRecord]]:
    """The plan's cases, and a record of every file read."""
    from jointseg.io import read_scan
    from jointseg.scan import Scan

    cases: list[Case] = []
    records = []
    kinds = tuple(plan.deliveries)
    for path, shown in named_scan_files(plan.rooms, base):
        room = read_scan(path)
        room = Scan(room.xyz, room.rgb, room.labels, source_format="ply")
        source = path.parent.name
        cases += room_cases(
            path.stem, source, room, seed=plan.seed, kinds=kinds, n_views=plan.views
        )
        records.append(
            ScanRecord(
                dataset=source,
                name=path.stem,
                path=shown,
                sha256=file_sha256(path),
                made="z up room, delivered",
            )
        )
    for capture in plan.captures:
        path = base / capture.file
        scan = read_scan(path)
        cases.append(Case(path.stem, "other sensors", "as delivered", capture.truth, scan))
        records.append(
            ScanRecord(
                dataset="other sensors",
                name=path.stem,
                path=str(capture.file),
                sha256=file_sha256(path),
                made=f"as delivered, up {capture.truth}",
            )
        )
    if not cases:
        raise ConfigError("the up-axis plan names no rooms and no captures")
    return cases, records


def geometry_steps(plan: UpPlan, base: Path) -> tuple[Path, dict[str, Any]]:
    """The model the geometry steps come from, and its axis and sign weights (checked)."""
    path = MODEL_FILE if plan.geometry_from is None else base / plan.geometry_from
    body = read_up_model(path)
    axis = weight_vector(body, "axis_weights", gravity.AXIS_SIZE, path)
    sign = weight_vector(body, "sign_weights", gravity.SIGN_SIZE, path)
    return path, {"axis_weights": axis, "sign_weights": sign, "fitted_on": body.get("fitted_on")}


def _case_nll(g: Gathered, w: np.ndarray, full: bool, base_w: np.ndarray | None) -> float | None:
    """Minus the log-probability of the true axis of one case under weights ``w`` (the base
    model, or the full one over the candidates the network would judge); None when the truth
    is not among those candidates."""
    truth = g.case.truth
    base = g.evidence.base()
    if full:
        names = weigh.candidates(g.evidence, base_weights=base_w)
        if truth not in names:
            return None
        top = [SIGNED_AXES.index(a) for a in names]
        x = np.array([np.concatenate([base[i], g.net[SIGNED_AXES[i]]]) for i in top])
        t = names.index(truth)
    else:
        x, t = base, SIGNED_AXES.index(str(truth))
    z = x @ w
    return float(np.logaddexp.reduce(z) - z[t])


def _nll(
    w: np.ndarray,
    rows: list[Gathered],
    full: bool,
    base_w: np.ndarray | None,
    l2: float,
    weights: dict[str, float],
) -> float:
    total = 0.0
    for g in rows:
        nll = _case_nll(g, w, full, base_w)
        if nll is not None:
            total += weights.get(g.case.delivery, 1.0) * nll
    return total + l2 * float(w @ w)


def fit_weights(
    rows: list[Gathered], l2: float = 1.0, weights: dict[str, float] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The weighing without the network (base) and with it (full), fitted on the cases of
    known truth, each weighed by how often its delivery arrives."""
    from scipy.optimize import minimize

    weights = DELIVERY_WEIGHT if weights is None else weights
    known = [g for g in rows if g.case.truth is not None]
    if not known:
        raise ConfigError("no cases of known up to fit the weighing on")
    if any(not g.net for g in known):
        raise ConfigError("every case needs the network's verdicts to fit the full weighing")
    x0 = np.ones(len(weigh.BASE_FEATURES))
    base = minimize(_nll, x0, args=(known, False, None, l2, weights)).x
    x0 = np.r_[base, np.zeros(len(weigh.FULL_FEATURES) - len(base))]
    full = minimize(_nll, x0, args=(known, True, base, l2, weights), method="L-BFGS-B").x
    return base, full


def _judge(spec: str) -> LabelFn | None:
    """The network's crop labeller, or a ConfigError for a network that cannot judge."""
    from jointseg.network import load
    from jointseg.network.judge import crop_labeller

    backend, _, weights = spec.partition(":")
    label = crop_labeller(load(backend, weights or None))
    if label is None:
        raise ConfigError(f"the network {spec!r} cannot judge frames (no loaded model)")
    return label


def gather_all(
    cases: list[Case], spec: str, geometry: tuple[np.ndarray, np.ndarray], cache: Path | None
) -> list[Gathered]:
    """Every case gathered (or read from ``cache``), the judge loaded only if one is not."""
    loaded: list[LabelFn | None] = []

    def label() -> LabelFn | None:
        if not loaded:
            loaded.append(_judge(spec))
        return loaded[0]

    key = f"{spec}|{weights_fingerprint(spec)}"
    rows = []
    for n, case in enumerate(cases):
        rows.append(gather_case(case, label, geometry, key, cache))
        if n % 25 == 0:
            log.info("gathered %d / %d cases", n + 1, len(cases))
    return rows


def fit_up_axis(
    plan: UpPlan, base: Path, out: Path, *, command: str, cache: Path | None = None
) -> Provenance:
    """Fit the weighing the plan describes (paths relative to ``base``) and write the model at
    ``out`` (the geometry steps copied) and its provenance beside it."""
    started = time.perf_counter()
    spec = network_spec(plan.judge, base)
    judge = labeller_record(spec)
    source, steps = geometry_steps(plan, base)
    cases, records = plan_cases(plan, base)
    rows = gather_all(cases, spec, (steps["axis_weights"], steps["sign_weights"]), cache)
    base_w, full_w = fit_weights(rows, plan.l2, plan.delivery_weight)
    body = {
        "axis_weights": steps["axis_weights"].tolist(),
        "sign_weights": steps["sign_weights"].tolist(),
        "fitted_on": steps["fitted_on"],
        "weigh": {
            "features": list(weigh.FULL_FEATURES),
            "base": (np.round(base_w, DECIMALS) + 0.0).tolist(),
            "full": (np.round(full_w, DECIMALS) + 0.0).tolist(),
            "fitted_on": sorted({g.case.name for g in rows if g.case.truth is not None}),
        },
    }
    facts = {
        "cases": len(rows),
        "geometry_from": {"path": portable_path(source), "sha256": file_sha256(source)},
        "seconds": round(time.perf_counter() - started, 1),
    }
    record = fit_record(plan, command, records, [judge], facts)
    return write_model(out, body, record, indent=1)
