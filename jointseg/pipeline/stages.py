"""The whole method on one scan: the frame, network and geometry (side by side,
:mod:`jointseg.pipeline.side_by_side`), then fusion, objects and metrics."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.frame.colour import decide_colour
from jointseg.frame.decide import Frame, decide_frame, work_scan
from jointseg.fusion import FusionResult, StructureHint, fuse
from jointseg.geometry import GeometryResult
from jointseg.metrics import SegmentationMetrics, evaluate, segment_majority
from jointseg.network.backends import Predictor
from jointseg.network.choice import network_for
from jointseg.network.judge import crop_labeller
from jointseg.network.pending import PendingPredictor, resolve
from jointseg.network.registry import load, resolve_weights
from jointseg.network.results import NetworkResult
from jointseg.pipeline.config import NetworkConfig, PipelineConfig
from jointseg.pipeline.side_by_side import network_and_geometry
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from jointseg.scan import Scan

if TYPE_CHECKING:
    from jointseg.objects.layout import Layout

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PipelineResult:
    """Every stage's result, the timings, the parameters used and, with ground truth, metrics.

    Attributes
    ----------
    timings : dict of str to float, seconds
        ``load_network`` (when ``run`` loaded it), ``network``, ``geometry``, ``fusion``,
        ``metrics`` and ``total`` (network and geometry overlap when run concurrently).
    metrics : dict of str to SegmentationMetrics, optional
        ``network``, ``fused`` and ``oracle`` (the segments' ground-truth majority, the best
        any per-segment vote can do); None when the scan has no ground truth.
    params : dict
        The parameters used, adaptive geometry defaults resolved.
    frame : Frame, optional
        What the frame stage decided (up, units, stray points, colour); every per-point
        array above is for the user's points, strays included.
    layout : Layout, optional
        Objects (an id per point), rooms and walls; None when ``config.objects`` is off.
    """

    network: NetworkResult
    geometry: GeometryResult
    fusion: FusionResult
    config: PipelineConfig
    params: dict[str, Any]
    timings: dict[str, float] = field(default_factory=dict)
    metrics: dict[str, SegmentationMetrics] | None = None
    frame: Frame | None = None
    layout: Layout | None = None

    @property
    def instances(self) -> np.ndarray:
        """Object id per point, -1 for structure and strays (all -1 without objects)."""
        if self.layout is None:
            return np.full(len(self.fusion.labels), -1, dtype=np.int64)
        return self.layout.instances

    @property
    def stray(self) -> np.ndarray:
        """Stray point mask, (N,) bool (all False without a frame stage)."""
        if self.frame is None:
            return np.zeros(len(self.fusion.labels), dtype=bool)
        return self.frame.stray

    @property
    def network_labels(self) -> np.ndarray:
        """Network class per point, (N,) int32."""
        return self.network.labels

    @property
    def network_probs(self) -> np.ndarray:
        """Network class probabilities, (N, 13) float32."""
        return self.network.probs

    @property
    def segments(self) -> np.ndarray:
        """Geometric segment per point, (N,) int32."""
        return self.geometry.segments

    @property
    def fused_labels(self) -> np.ndarray:
        """Fused class per point, (N,) int32."""
        return self.fusion.labels

    @property
    def fused_confidence(self) -> np.ndarray:
        """Fused confidence per point, (N,) float32 in [0, 1]."""
        return self.fusion.confidence


def load_predictor(config: NetworkConfig) -> Predictor:
    """Load the configured network once (reuse it across scans with ``run(predictor=...)``).

    Raises
    ------
    ConfigError
        For an unknown backend or missing or unreadable weights.
    """
    return load(
        config.name,
        config.weights,
        device=config.device,
        batch_size=config.batch_size,
        params=config.options(),
    )


def run(
    scan: Scan,
    config: PipelineConfig | None = None,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
    *,
    predictor: Predictor | None = None,
) -> PipelineResult:
    """Label a scan with the network, segment it geometrically, fuse both, score with ground truth.

    Parameters
    ----------
    scan : Scan
        Points in any axes and unit (the frame stage decides); colour used when present;
        ``labels`` (ground truth) only for the metrics.
    config : PipelineConfig, optional
    progress : callable, optional
        ``progress(stage, fraction)`` for the stages ``network``, ``geometry`` and ``fusion``;
        calls are serialised, so the callback need not be thread-safe.
    cancel : object with ``is_set()``, optional
        Stops both running stages at their next check (between crop batches and geometry
        steps) and raises :class:`Cancelled`.
    predictor : Predictor, optional
        An already loaded network (e.g. one per worker process) or one still loading
        (:mod:`jointseg.network.pending`); default: loaded from ``config.network``.

    Returns
    -------
    PipelineResult

    Raises
    ------
    ConfigError
        For an empty scan or a network that cannot be loaded.
    Cancelled
        When ``cancel`` was set.
    """
    config = config or PipelineConfig()
    if len(scan) == 0:
        raise ConfigError("the scan has no points")
    started = time.perf_counter()
    timings: dict[str, float] = {}
    check_cancel(cancel)
    if predictor is None:
        predictor = load_predictor(config.network)
        timings["load_network"] = time.perf_counter() - started

    seed = config.seed
    frame, work, index, chosen = _frame_stage(scan, config, predictor, progress, timings)
    waited: list[float] = []
    network = _network_when_loaded(chosen, work, seed, waited)
    net, geo = network_and_geometry(work, config, network, progress, cancel, timings)
    chosen = resolve(chosen)
    _load_apart(timings, waited, isinstance(predictor, PendingPredictor))

    fused = _fusion_stage(work, config, net, geo, progress, cancel, timings)
    layout = _objects_stage(work, fused, frame, config, geo, timings)
    if index is not None:
        net, geo, fused = expand(net, geo, fused, index)
        layout = _expand_layout(layout, index, frame.stray)

    t = time.perf_counter()
    metrics = _metrics(scan, net, geo, fused)
    timings["metrics"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - started
    changed = int(np.count_nonzero(fused.changed))
    log.info(
        "pipeline: %d points, %d segments, %d labels changed", len(scan), geo.n_segments, changed
    )
    return PipelineResult(
        network=net,
        geometry=geo,
        fusion=fused,
        config=config,
        params=_resolved_params(config, chosen, geo),
        timings=timings,
        metrics=metrics,
        frame=frame,
        layout=layout,
    )


def _network_when_loaded(
    chosen: Predictor, work: Scan, seed: int, waited: list[float]
) -> Callable[[ProgressFn, CancelToken], NetworkResult]:
    """The network stage: ``chosen`` labels ``work``, once loaded when it is still loading
    (:class:`~jointseg.network.pending.PendingPredictor`); the seconds waited go to ``waited``."""

    def network(progress: ProgressFn, cancel: CancelToken) -> NetworkResult:
        t = time.perf_counter()
        ready = resolve(chosen)
        waited.append(time.perf_counter() - t)
        return ready.predict(work, progress, cancel, seed=seed)

    return network


def _load_apart(timings: dict[str, float], waited: list[float], pending: bool) -> None:
    """A network loaded beside the frame and the geometry: the network stage's wait for it is
    the load's (``network_wait``), not the network's."""
    if pending:
        timings["network"] -= sum(waited)
        timings["network_wait"] = sum(waited)


def _expand_layout(layout: Layout | None, index: np.ndarray, stray: np.ndarray) -> Layout | None:
    """The work scan's object ids carried to every user point; stray points belong to none."""
    if layout is None:
        return None
    instances = layout.instances[index]
    instances[stray] = -1
    return replace(layout, instances=instances)


def _objects_stage(
    work: Scan,
    fused: FusionResult,
    frame: Frame,
    config: PipelineConfig,
    geo: GeometryResult,
    timings: dict[str, float],
) -> Layout | None:
    """Objects, rooms and walls from the fused labels and the geometry's structure reading, in
    the work frame, reported in the user's coordinates; timed as ``objects``. None when
    switched off. The spacing is the one the geometry stage measured on the same points."""
    if not config.objects.enabled:
        return None
    from jointseg.objects.layout import find_layout

    t = time.perf_counter()
    to_user = np.linalg.inv(np.asarray(frame.matrix(), dtype=np.float64))
    layout = find_layout(
        work.xyz,
        fused.labels,
        fused.confidence,
        geo.params.spacing,
        to_user=to_user,
        params=config.objects,
        structure=geo.structure,
    )
    timings["objects"] = time.perf_counter() - t
    return layout


def _frame_stage(
    scan: Scan,
    config: PipelineConfig,
    predictor: Predictor,
    progress: ProgressFn | None,
    timings: dict[str, float],
) -> tuple[Frame, Scan, np.ndarray | None, Predictor]:
    """Pick the colour-free network for a scan without colour, decide the frame (that network
    judging the likeliest up axes), make the work scan and the map back to the user's points;
    timed as ``frame``."""
    t = time.perf_counter()
    usable = decide_colour(scan.rgb, config.frame.colour).usable
    chosen = network_for(predictor, config.network.choice(), usable)
    frame = decide_frame(scan, config.frame, judge=crop_labeller(chosen))
    work, index = work_scan(scan, frame)
    report(progress, "frame", 1.0)
    timings["frame"] = time.perf_counter() - t
    return frame, work, index, chosen


def expand(
    net: NetworkResult, geo: GeometryResult, fused: FusionResult, index: np.ndarray
) -> tuple[NetworkResult, GeometryResult, FusionResult]:
    """Per-point results of the work scan carried to every user point (``index``: each
    point's stand-in in the work scan; a stray point takes its nearest kept point's)."""
    return (
        replace(net, labels=net.labels[index], probs=net.probs[index]),
        replace(
            geo,
            segments=geo.segments[index],
            plane_id=geo.plane_id[index],
            structure=None if geo.structure is None else geo.structure[index],
            structure_confidence=None
            if geo.structure_confidence is None
            else geo.structure_confidence[index],
        ),
        replace(
            fused,
            labels=fused.labels[index],
            confidence=fused.confidence[index],
            network_labels=fused.network_labels[index],
        ),
    )


def _fusion_stage(
    scan: Scan,
    config: PipelineConfig,
    net: NetworkResult,
    geo: GeometryResult,
    progress: ProgressFn | None,
    cancel: CancelToken | None,
    timings: dict[str, float],
) -> FusionResult:
    """Fuse the network's labels over the geometry's segments, timed as ``fusion``."""
    t = time.perf_counter()
    check_cancel(cancel)
    fused = fuse(
        scan.xyz,
        geo.segments,
        net.labels,
        net.probs,
        config.fusion,
        main_plane=geo.main_plane,
        structure=structure_hint(geo),
        has_colour=scan.rgb is not None,
    )
    report(progress, "fusion", 1.0)
    timings["fusion"] = time.perf_counter() - t
    return fused


def structure_hint(geo: GeometryResult) -> StructureHint | None:
    """The geometry's structure reading as the fusion takes it; None when switched off."""
    if geo.structure is None or geo.structure_confidence is None:
        return None
    return StructureHint(geo.structure, geo.structure_confidence)


def _metrics(
    scan: Scan, net: NetworkResult, geo: GeometryResult, fused: FusionResult
) -> dict[str, SegmentationMetrics] | None:
    """The network's, the fused and the oracle's scores; None without ground truth."""
    metrics = None
    if scan.labels is not None and (scan.labels >= 0).any():
        metrics = {
            "network": evaluate(scan.labels, net.labels),
            "fused": evaluate(scan.labels, fused.labels),
            "oracle": evaluate(scan.labels, segment_majority(scan.labels, geo.segments)),
        }
    return metrics


def _resolved_params(
    config: PipelineConfig, predictor: Predictor, geometry: GeometryResult
) -> dict[str, Any]:
    """The parameters a run used, as JSON-ready values (geometry's adaptive ones resolved)."""
    network = config.network
    weights = resolve_weights(network.name, network.weights)
    device = predictor.device
    options = network.options()
    if predictor.card.get("colour") is False and network.weights is None:
        from jointseg.network.randlanet.backend import COLOUR_FREE_WEIGHTS

        weights = COLOUR_FREE_WEIGHTS
    members = getattr(predictor, "members", [predictor])
    return {
        "quality": config.quality,
        "network": {
            "name": network.name,
            "networks": [m.name for m in members],
            "views": getattr(getattr(members[0], "params", None), "views", 1),
            "weights": None if weights is None else str(weights),
            "colour": predictor.card.get("colour", True) is not False,
            "device": None if device is None else str(device),
            "batch_size": predictor.batch_size,
            "trained_on": predictor.card.get("data"),
            **({} if options is None else {network.name: options.model_dump()}),
        },
        "geometry": geometry.params.model_dump(),
        "fusion": config.fusion.model_dump(),
        "seed": config.seed,
        "concurrent": config.concurrent,
    }
