"""``jointseg adapt``: a model that has learnt from corrected results, written as an ordinary
RandLA-Net checkpoint (the bundled network with its head refitted), so ``jointseg segment
--weights MODEL`` and the service's ``network.weights`` use it with nothing else to install."""

from __future__ import annotations

import hashlib
import logging
import os
import platform
import time
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from torch import nn

from jointseg.adapt.examples import ScanExamples, scan_examples
from jointseg.adapt.head import AdaptParams, Examples, fit_head
from jointseg.exceptions import ConfigError
from jointseg.io import read_scan
from jointseg.labels.version import USER_LABEL_FIELD, check_result, user_labels_of
from jointseg.network.checkpoint import save_checkpoint
from jointseg.network.choice import Choice, network_for
from jointseg.network.randlanet.model import RandLANet
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from jointseg.scan import Scan

log = logging.getLogger(__name__)
#: A result a model learns from may hold at most this many points.
MAX_POINTS = 50_000_000
#: The generated rooms of :func:`replay`: seeds and points.
REPLAY_SEED, REPLAY_POINTS = 7_000, 60_000


@dataclass(frozen=True)
class Corrected:
    """One corrected result: its file, a name and version for the card, and (from the run's
    report, when known) the transform to the frame the network worked in."""

    path: Path
    name: str | None = None
    version: int | None = None
    to_work: np.ndarray | None = None


@dataclass
class Adapted:
    """What :func:`adapt` made: the model's file, its card and the fit's losses."""

    path: Path
    card: dict[str, Any]
    losses: list[float] = field(default_factory=list)


def _read(item: Corrected) -> tuple[Scan, np.ndarray]:
    name = item.name or item.path.name
    scan = read_scan(item.path, max_points=MAX_POINTS)
    check_result(scan, name=name)
    user = user_labels_of(scan)
    if user is None or not (user >= 0).any():
        raise ConfigError(
            f"{name}: no corrected points (its {USER_LABEL_FIELD} field is missing or all -1); "
            "correct it first (jointseg relabel, the viewer or PATCH /v1/jobs/ID/labels)"
        )
    return scan, user


def _card(base: dict[str, Any], seen: list[tuple[Corrected, ScanExamples]], params: AdaptParams,
          seconds: float, base_name: str, left_out: int) -> dict[str, Any]:  # fmt: skip
    scans = [
        {
            "name": item.name or item.path.name,
            "version": item.version,
            "points": ex.points,
            "corrected_points": ex.corrected_points,
            "classes": ex.classes,
        }
        for item, ex in seen
    ]
    return {
        **base,
        "adapted": {
            "from": base_name,
            "what": "the head (last three point-wise layers) refitted to the users' classes, "
            "the rest of the network unchanged; points nobody corrected held to the base "
            "network's answer"
            + (
                ""
                if params.keep_base_above is None
                else f"; the bundled head kept beside it, its answer used where its top "
                f"probability reaches {params.keep_base_above}"
            ),
            "scans": scans,
            "corrected_points": sum(s["corrected_points"] for s in scans),
            # sub-sampled corrected points not learnt from (Examples.believable)
            "left_out_samples": left_out,
            "params": params.model_dump(),
            "seconds": round(seconds, 1),
            "hardware": f"{platform.machine()} CPU, {os.cpu_count()} cores, "
            f"torch {torch.__version__}",
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
        },
    }


def adapt(
    corrected: list[Corrected],
    out: Path,
    *,
    predictor: Any,
    choice: Choice,
    params: AdaptParams | None = None,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
) -> Adapted:
    """Learn from ``corrected`` results and write the adapted model to ``out``.

    ``predictor`` is the loaded base network (the configured one); a result without colour
    adapts the colour-free network, as the pipeline would label it. All results must agree.

    Raises
    ------
    ConfigError
        No result, a file that is no result or has no corrected point, or results that mix
        scans with and without colour.
    """
    if not corrected:
        raise ConfigError("adapt: no corrected result given")
    if predictor.name != "randlanet":
        raise ConfigError(f"adapt: only RandLA-Net can be adapted, not {predictor.name}")
    params = params or AdaptParams()
    started = time.perf_counter()
    scans = [_read(item) for item in corrected]  # every file checked before any work
    coloured = {scan.rgb is not None for scan, _ in scans}
    if len(coloured) > 1:
        raise ConfigError("adapt: the results mix scans with and without colour; adapt each kind")
    net = network_for(predictor, replace(choice, ensemble=False), usable_colour=coloured.pop())
    seen: list[tuple[Corrected, ScanExamples]] = []
    for i, (item, (scan, user)) in enumerate(zip(corrected, scans, strict=True)):
        check_cancel(cancel)
        ex = scan_examples(net, scan, user, to_work=item.to_work, seed=params.seed, cancel=cancel)
        seen.append((item, ex))
        report(progress, "features", (i + 1) / len(scans))
    parts = [ex.examples for _, ex in seen] + replay(net, params, cancel)
    examples = Examples(
        np.concatenate([e.features for e in parts]),
        np.concatenate([e.target for e in parts]),
        np.concatenate([e.teacher for e in parts]),
        _groups(parts),
    )
    base = cast(RandLANet, net.model)
    head, losses = fit_head(base.head, examples, params, progress=progress, cancel=cancel)
    model = with_head(base, cast(nn.Sequential, head), params.keep_base_above)
    learnt = int(np.count_nonzero(examples.believable(params.min_base_probability)))
    left_out = examples.corrected - learnt
    log.info("learning from %d corrected samples, %d left out (another object in a corrected "
             "segment)", learnt, left_out)  # fmt: skip
    card = _card(net.card, seen, params, time.perf_counter() - started, _base_name(net), left_out)
    save_checkpoint(out, model, card, half=True, compress=True)
    log.info("adapted model written to %s (%d corrected points)", out, examples.corrected)
    return Adapted(out, card, losses)


def _groups(parts: list[Examples]) -> np.ndarray:
    """The parts' corrected segments as ids unique over every part (-1 stays -1)."""
    out, offset = [], 0
    for e in parts:
        g = np.full(len(e.target), -1, np.int64) if e.group is None else e.group
        out.append(np.where(g >= 0, g + offset, -1))
        offset += int(g.max(initial=-1)) + 1
    return np.concatenate(out)


def with_head(base: RandLANet, head: nn.Sequential, keep_base_above: float | None) -> RandLANet:
    """``base`` with ``head`` in place of its own; with a gate, the bundled head kept beside it
    (an adapted model adapted again keeps the bundled head it started from)."""
    config = base.config.model_copy(update={"keep_base_above": keep_base_above})
    model = RandLANet(config)
    state = {k: v for k, v in base.state_dict().items() if not k.startswith("head.")}
    state |= {f"head.{k}": v for k, v in head.state_dict().items()}
    if keep_base_above is not None:
        kept = base.base_head if base.base_head is not None else base.head
        state |= {f"base_head.{k}": v for k, v in kept.state_dict().items()}
    else:
        state = {k: v for k, v in state.items() if not k.startswith("base_head.")}
    model.load_state_dict(state)
    return model.eval()


def replay(net: Any, params: AdaptParams, cancel: CancelToken | None) -> list[Examples]:
    """Generated rooms (:mod:`jointseg.synth`, every kind of room and furniture) with no
    corrections: points where the head is held to the base network, so that what the corrected
    scans do not show (other rooms, other classes) keeps its labels."""
    from jointseg.adapt.features import head_inputs
    from jointseg.synth import make_room

    out = []
    for i in range(params.replay_rooms):
        room = make_room(REPLAY_SEED + i, points=REPLAY_POINTS)
        if net.card.get("colour", True) is False:
            room = Scan(room.xyz, None)
        inputs = head_inputs(net, Scan(room.xyz, room.rgb), seed=params.seed, cancel=cancel)
        out.append(Examples(inputs.features, np.full(len(inputs.features), -1), inputs.probs))
    return out


def _base_name(net: Any) -> str:
    """The base network named by its weights' digest (the card of an adapted model must say
    what it started from even when the file moves)."""
    digest = hashlib.sha256()
    for tensor in net.model.state_dict().values():
        digest.update(tensor.detach().cpu().numpy().tobytes())
    return f"randlanet {'colour' if net.card.get('colour', True) is not False else 'colour-free'}"\
        f" weights sha256:{digest.hexdigest()[:16]}"  # fmt: skip
