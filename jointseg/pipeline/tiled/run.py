"""One tile of a big scan: network and geometry on its outer box, kept for the merge.

A tile reads its outer box (its core plus the overlap margin) so the network's crops and the
geometry's neighbourhoods near the core's edge see what lies beyond it, and keeps:

- for every outer point: its segment in this tile and whether it lies on a main plane (the
  margin's segments are what joins segments across tile borders);
- for the core points only: the network's label, confidence and probabilities (float16, for
  the vote), since a point takes its network output from the tile whose core holds it.

The result is written to ``tiles/NNNN/result.npz`` through a temporary file and a rename, and
is a function of the plan, the tile and the seed only: a tile run twice (a worker killed after
writing, its task re-queued) leaves the same file.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, cast

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.fusion.offers import normalised_entropy
from jointseg.geometry import GeometryResult
from jointseg.network.anchored import CropPlan, crops_inside
from jointseg.network.backends import Predictor, TilePredictor
from jointseg.network.choice import network_for
from jointseg.network.results import CellSums, NetworkResult
from jointseg.pipeline.config import PipelineConfig
from jointseg.pipeline.side_by_side import network_and_geometry
from jointseg.pipeline.tiled.store import TileBox, TilePlan, load_tile, read_plan, tile_folder
from jointseg.progress import CancelToken, ProgressFn, check_cancel
from jointseg.scan import Scan

log = logging.getLogger(__name__)
RESULT_FILE = "result.npz"
PROBS_FILE = "probs.npy"
CELLS_FILE = "cells.npz"
#: The steps a tile's timings record.
STEPS = ("load", "network", "geometry")


@dataclass(frozen=True)
class TileNetwork:
    """A tile's network output at its core points, in one of its two forms.

    Why one type: the tile's run writes it and the merge reads it, and neither should have to
    ask which network made it. With a shared crop plan (RandLA-Net) each core point names the
    sub-sampled cell it takes its outputs from (``point_cell``) and the sums per cell are added
    over tiles by the merge; a network that runs each tile on its own gives per-point labels,
    confidences and probabilities.

    Attributes
    ----------
    point_cell : ndarray of shape (C,), int64, optional
        The cell of every core point (shared crop plan).
    cells : CellSums, optional
        The tile's sums per cell, only while it is being written.
    labels, confidence : ndarray of shape (C,), optional
        The network's label (uint8) and confidence (float32) at the core points.
    probs : ndarray of shape (C, 13), float16, optional
        The probabilities at the core points (memory-mapped, read-only, once loaded).
    entropy_sum : float
        The normalised entropy of the probabilities summed over the core points.
    """

    point_cell: np.ndarray | None = None
    cells: CellSums | None = None
    labels: np.ndarray | None = None
    confidence: np.ndarray | None = None
    probs: np.ndarray | None = None
    entropy_sum: float = 0.0

    @classmethod
    def of_points(cls, net: NetworkResult, core: np.ndarray) -> TileNetwork:
        """The per-point form, kept at the core points."""
        probs = net.probs[core]
        return cls(
            labels=net.labels[core].astype(np.uint8),
            confidence=probs.max(axis=1).astype(np.float32),
            probs=probs,
            entropy_sum=float(normalised_entropy(probs).sum()),
        )

    @classmethod
    def of_cells(cls, cells: CellSums, core: np.ndarray) -> TileNetwork:
        """The per-cell form of a shared crop plan."""
        return cls(point_cell=cells.point_cell[core], cells=cells)

    @property
    def per_cell(self) -> bool:
        """Whether the outputs are per sub-sampled cell (summed over tiles by the merge)."""
        return self.point_cell is not None

    def save(self, workdir: Path, index: int) -> dict[str, Any]:
        """Write the big arrays beside the tile's result; return the small ones for it."""
        if self.per_cell:
            cells = self.cells
            assert cells is not None
            _save(
                cells_path(workdir, index),
                lambda fh: np.savez(fh, ids=cells.ids, sums=cells.sums, seen=cells.seen),
            )
            return {"point_cell": cast(np.ndarray, self.point_cell)}
        probs = cast(np.ndarray, self.probs)
        _save(probs_path(workdir, index), lambda fh: np.save(fh, probs.astype(np.float16)))
        return {
            "labels": cast(np.ndarray, self.labels),
            "confidence": cast(np.ndarray, self.confidence),
            "entropy_sum": np.float64(self.entropy_sum),
        }

    @classmethod
    def load(cls, arrays: dict[str, np.ndarray], workdir: Path, index: int) -> TileNetwork:
        """The form :meth:`save` wrote, from the tile's result arrays."""
        if "point_cell" in arrays:
            return cls(point_cell=arrays["point_cell"])
        return cls(
            labels=arrays["labels"],
            confidence=arrays["confidence"],
            probs=np.load(probs_path(workdir, index), mmap_mode="r"),
            entropy_sum=float(arrays["entropy_sum"]),
        )


@dataclass(frozen=True)
class TileResult:
    """What one tile's run left, as loaded by the merge.

    Attributes
    ----------
    index : ndarray of shape (M,), int64
        The outer points' indices in the scan (ascending).
    core : ndarray of shape (M,), bool
        Outer points inside the core.
    segments : ndarray of shape (M,), int32
        Segment 0..S-1 of every outer point in this tile, -1 beyond the geometry's margin
        (``TileParams.geometry_overlap``).
    main_plane : ndarray of shape (M,), bool
    structure, structure_confidence : ndarray of shape (M,), int8 and float32
        The geometry's structure reading (-1 and 0 where it reads none, or was switched off).
    network : TileNetwork
        The network's outputs at the core points.
    timings : dict of str to float
    """

    index: np.ndarray
    core: np.ndarray
    segments: np.ndarray
    main_plane: np.ndarray
    structure: np.ndarray
    structure_confidence: np.ndarray
    network: TileNetwork
    timings: dict[str, float]

    @property
    def n_segments(self) -> int:
        """Segments of this tile."""
        return int(self.segments.max()) + 1 if len(self.segments) else 0

    @property
    def core_index(self) -> np.ndarray:
        """The core points' indices in the scan (ascending)."""
        return self.index[self.core]


def result_path(workdir: Path, index: int) -> Path:
    """Where tile ``index``'s result is written."""
    return tile_folder(workdir, index) / RESULT_FILE


def probs_path(workdir: Path, index: int) -> Path:
    """Where tile ``index``'s core probabilities are written (float16, memory-mappable)."""
    return tile_folder(workdir, index) / PROBS_FILE


def cells_path(workdir: Path, index: int) -> Path:
    """Where tile ``index``'s summed network outputs per sub-sampled cell are written."""
    return tile_folder(workdir, index) / CELLS_FILE


def _save(target: Path, write: Callable[[BinaryIO], None]) -> None:
    """Write ``target`` through a temporary file of this process and a rename."""
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        write(fh)
    os.replace(tmp, target)


def tile_done(workdir: Path, index: int) -> bool:
    """Whether tile ``index`` has a complete result (results appear only by rename)."""
    return result_path(workdir, index).is_file()


def run_tile(
    workdir: Path,
    index: int,
    config: PipelineConfig,
    *,
    predictor: Predictor,
    plan: TilePlan | None = None,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
    skip_done: bool = False,
) -> bool:
    """Run the network and the geometry on tile ``index`` and write its result.

    Parameters
    ----------
    workdir : Path
        A folder made by :func:`jointseg.pipeline.tiled.plan`.
    index : int
    config : PipelineConfig
        The run's configuration (its seed, geometry and network); the geometry's thresholds
        are the plan's, resolved once for the whole scan.
    predictor : Predictor
    plan : TilePlan, optional
        Read from ``workdir`` when not given.
    progress : callable, optional
        ``progress("network" | "geometry", fraction)`` within this tile.
    cancel : object with ``is_set()``, optional
    skip_done : bool
        Leave a tile that already has its result alone (an earlier attempt wrote it, by a
        rename, and a tile's result is a function of the plan, the tile and the seed only).

    Returns
    -------
    bool
        Whether the tile was run (False: skipped). Seconds per step (``load``, ``network``,
        ``geometry``) go into its result.

    Raises
    ------
    ConfigError
        For a tile the plan lacks.
    Cancelled
        When ``cancel`` was set (no result is written).
    """
    if skip_done and tile_done(workdir, index):
        return False
    plan = plan or read_plan(workdir)
    if plan.frame is not None:
        usable = plan.frame["colour"] == "rgb"
        predictor = network_for(predictor, config.network.choice(), usable)
    timings: dict[str, float] = {}
    t = time.perf_counter()
    scan, box, core, segmented = _load_outer(workdir, plan, index)
    geometry_scan = scan.subset(segmented) if not segmented.all() else scan
    timings["load"] = time.perf_counter() - t
    check_cancel(cancel)
    network = _network_fn(workdir, plan, predictor, scan, box, core, config.seed)
    net, geo = network_and_geometry(
        scan,
        config,
        network,
        progress,
        cancel,
        timings,
        resolved=plan.geometry,
        geometry_scan=geometry_scan,
    )
    check_cancel(cancel)
    _save_result(workdir, index, len(scan), core, segmented, net, geo, timings)
    log.info(
        "tile %d: %d points (%d core), %d segments",
        index,
        len(scan),
        int(core.sum()),
        geo.n_segments,
    )
    return True


def _load_outer(
    workdir: Path, plan: TilePlan, index: int
) -> tuple[Scan, TileBox, np.ndarray, np.ndarray]:
    """Tile ``index``'s outer points, its box, its core mask and the points the geometry
    segments (the core plus the geometry's margin, which joins segments across borders).

    Raises
    ------
    ConfigError
        For a tile with too few points to segment.
    """
    scan, _ = load_tile(workdir, plan, index)
    if len(scan) < 10:
        raise ConfigError(f"tile {index} holds {len(scan)} points, too few to segment")
    box = plan.tiles[index]
    core = box.tile().core_mask(scan.xyz[:, :2])
    margin = min(plan.params.geometry_overlap, plan.params.overlap)
    segmented = box.tile().near_core_mask(scan.xyz[:, :2], margin) | core
    return scan, box, core, segmented


def _network_fn(
    workdir: Path,
    plan: TilePlan,
    predictor: Predictor,
    scan: Scan,
    box: TileBox,
    core: np.ndarray,
    seed: int,
) -> Callable[[ProgressFn, CancelToken], TileNetwork]:
    """The tile's network stage: per sub-sampled cell of the shared crop plan when there is
    one (so tiles add up to an untiled run), else the predictor on the tile on its own."""
    network: Callable[[ProgressFn, CancelToken], TileNetwork]
    if plan.anchoring is not None and isinstance(predictor, TilePredictor):
        crops = read_crops(workdir, plan)
        lower = np.array(plan.lower)
        mine = np.flatnonzero(
            crops_inside(crops, lower, np.array(box.core_min), np.array(box.core_max))
        )
        tile_predictor = predictor

        def network(progress: ProgressFn, cancel: CancelToken) -> TileNetwork:
            cells = tile_predictor.predict_cells(
                scan,
                crops,
                lower,
                mine,
                progress,
                cancel,
                seed=seed,
            )
            return TileNetwork.of_cells(cells, core)
    else:

        def network(progress: ProgressFn, cancel: CancelToken) -> TileNetwork:
            return TileNetwork.of_points(predictor.predict(scan, progress, cancel, seed=seed), core)

    return network


def _save_result(
    workdir: Path,
    index: int,
    n_points: int,
    core: np.ndarray,
    segmented: np.ndarray,
    net: TileNetwork,
    geo: GeometryResult,
    timings: dict[str, float],
) -> None:
    """Write the tile's files, the big arrays first and ``result.npz`` last: its rename marks
    the tile done."""
    segments = np.full(n_points, -1, dtype=np.int32)
    segments[segmented] = geo.segments
    main_plane = np.zeros(n_points, dtype=bool)
    main_plane[segmented] = geo.main_plane
    structure = np.full(n_points, -1, dtype=np.int8)
    structure_confidence = np.zeros(n_points, dtype=np.float32)
    if geo.structure is not None and geo.structure_confidence is not None:
        structure[segmented] = geo.structure
        structure_confidence[segmented] = geo.structure_confidence
    common = {
        "segments": segments,
        "main_plane": main_plane,
        "structure": structure,
        "structure_confidence": structure_confidence,
        "core": core,
        "timings": np.array([timings.get(k, 0.0) for k in STEPS]),
    }
    # the big arrays first, the small result last: its rename marks the tile done
    extra = net.save(workdir, index)
    savez = cast(Any, np.savez)  # numpy's stubs take ** arrays for its own keywords
    _save(result_path(workdir, index), lambda fh: savez(fh, **common, **extra))


def load_result(workdir: Path, index: int) -> TileResult:
    """Tile ``index``'s result with its point indices.

    Raises
    ------
    ConfigError
        When the tile has not been run.
    """
    path = result_path(workdir, index)
    try:
        with np.load(path) as data:
            arrays = {k: data[k] for k in data.files}
    except FileNotFoundError as exc:
        raise ConfigError(f"tile {index} has no result yet ({path})") from exc
    index_in_scan = np.fromfile(tile_folder(workdir, index) / "index.i64", dtype="<i8")
    steps = dict(zip(STEPS, arrays["timings"].tolist(), strict=True))
    common = {
        "index": index_in_scan,
        "core": arrays["core"],
        "segments": arrays["segments"],
        "main_plane": arrays["main_plane"],
        # a tile run before the structure reading existed reads none
        "structure": arrays.get("structure", np.full(len(index_in_scan), -1, np.int8)),
        "structure_confidence": arrays.get(
            "structure_confidence", np.zeros(len(index_in_scan), np.float32)
        ),
        "timings": steps,
    }
    return TileResult(**common, network=TileNetwork.load(arrays, workdir, index))


def read_crops(workdir: Path, plan: TilePlan) -> CropPlan:
    """The whole-scan crop plan :func:`~jointseg.pipeline.tiled.store.prepare` saved.

    Raises
    ------
    ConfigError
        When the plan has none (a network that runs each tile on its own).
    """
    if plan.anchoring is None:
        raise ConfigError(f"{workdir}: this tile plan has no crop plan")
    with np.load(workdir / "crops.npz") as data:
        return CropPlan(data["centres"], data["radius"], plan.anchoring.crop_size)


def load_cells(workdir: Path, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tile ``index``'s summed network outputs: cell ids, sums (K, 13) and crop counts."""
    with np.load(cells_path(workdir, index)) as data:
        return data["ids"], data["sums"], data["seen"]
