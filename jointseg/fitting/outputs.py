"""The networks' and the geometry's outputs on tuning scans, optionally cached on disk.

Why a cache: a fit (and the benchmarks that judge one) labels the same scans with the same
networks again and again, and a network pass over a few hundred scans takes CPU hours. The
probabilities are stored as float16 whether cached or not, so a cached and a fresh run fit the
same model. Keys hold the scan's content, the network and its weights file, and a version to
bump when inference or the structure reading change what they compute.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.fitting.provenance import LabellerRecord, file_sha256, portable_path
from jointseg.fitting.scans import TuningScan, content_key

#: Part of every cached network output's key: bump it when whole-scan inference changes what it
#: computes (2: RandLA-Net's linear possibility weight; 3: classes a scan does not hold taken
#: out, RandLANetParams.absent_share), so no stale labels are reused.
INFERENCE_VERSION = 3
#: Part of every cached geometry output's key: bump it when the structure reading or how the
#: thresholds are derived changes (9, 10: the voxel and plane tolerance capped at a
#: SPARSE_SPACING of 1.6, then 2 cm; 11: no floor level above a sizeable surface, which reads
#: every bench room as 10 did).
STRUCTURE_VERSION = 11

#: A labeller that needs no network: the scan's own labels with patchy, confident mistakes
#: (:func:`jointseg.synth.label_noise.corrupt_labels`), for tests and for measuring what a fit
#: does on a network that errs in patches.
STAND_IN = "stand-in"
#: Loaded networks by spec, shared across scans (loading DGCNN takes seconds).
Predictors = dict[str, Any]


def cached(
    path: Path | None, compute: Callable[[], dict[str, np.ndarray]]
) -> dict[str, np.ndarray]:
    """Arrays from ``path`` (npz) if there, else ``compute()``, saved there unless ``path`` is
    None."""
    if path is not None and path.is_file():
        with np.load(path) as data:
            return {k: data[k] for k in data.files}
    out = compute()
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, allow_pickle=False, **out)
        tmp.replace(path)
    return out


def network_spec(network: str, base: Path | None = None) -> str:
    """``backend[:weights]`` with the weights made a full path: relative to ``base`` (the
    plan's folder) when written with a folder or found there, else a file of the package's
    own weights folder, else as written (a published name). An unknown backend is a
    ConfigError listing the known ones (and the stand-in)."""
    from jointseg.network.backends import WEIGHTS_DIR
    from jointseg.network.registry import REGISTRY

    if network == STAND_IN:
        return STAND_IN
    name, _, weights = network.partition(":")
    if name not in REGISTRY:
        known = ", ".join([*REGISTRY, STAND_IN])
        raise ConfigError(f"labeller {network!r}: unknown network {name!r}; known: {known}")
    if not weights:
        return name
    path = Path(weights)
    if (
        not path.is_absolute()
        and base is not None
        and (os.sep in weights or (base / path).exists())
    ):
        path = base / path
    elif not path.is_absolute() and (WEIGHTS_DIR / weights).is_file():
        path = WEIGHTS_DIR / weights
    return f"{name}:{path.resolve() if path.exists() else path}"


def network_name(spec: str) -> str:
    """A network spec as tables and model cards name it: its weights file, or the backend."""
    return spec.rpartition("/")[2] or spec


def weights_path(spec: str) -> Path | None:
    """The weights file ``spec`` resolves to (the backend's default for a bare backend)."""
    from jointseg.network.registry import resolve_weights

    backend, _, weights = spec.partition(":")
    return resolve_weights(backend, weights or None)


def labeller_record(spec: str, name: str | None = None) -> LabellerRecord:
    """The provenance of a network: its weights file and their sha256; a ConfigError when
    the file is missing (a fit must not name weights it did not read)."""
    if spec == STAND_IN:
        return LabellerRecord(name=name or spec, network=spec, sha256="no weights")
    path = weights_path(spec)
    if path is None or not path.is_file():
        raise ConfigError(f"labeller {spec!r}: no weights file at {path}")
    backend, _, weights = spec.partition(":")
    shown = f"{backend}:{portable_path(weights)}" if weights else spec
    return LabellerRecord(
        name=name or network_name(spec),
        network=shown,
        weights=portable_path(path),
        sha256=file_sha256(path),
    )


@functools.cache
def weights_fingerprint(spec: str) -> str:
    """Size and modification time of the weights file ``spec`` resolves to: a spec without a
    path ("randlanet") names whatever weights are bundled now, so the cache key must follow
    them."""
    if spec == STAND_IN:
        return "none"
    path = weights_path(spec)
    if path is None or not path.is_file():
        return "none"
    stat = path.stat()
    return f"{stat.st_size}-{stat.st_mtime_ns}"


def network_output(
    spec: str, item: TuningScan, predictors: Predictors, cache: Path | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Labels and probabilities (float16 precision) of network ``spec`` on a scan; under
    ``cache/net`` when a cache folder is given."""

    def compute() -> dict[str, np.ndarray]:
        from jointseg.network import load

        if spec == STAND_IN:
            return stand_in(item)
        if spec not in predictors:
            backend, _, weights = spec.partition(":")
            predictors[spec] = load(backend, weights or None)
        result = predictors[spec].predict(item.scan, seed=0)
        return {"labels": result.labels.astype(np.int8), "probs": result.probs.astype(np.float16)}

    key = content_key(spec, weights_fingerprint(spec), INFERENCE_VERSION)
    path = None if cache is None else cache / "net" / f"{item.key}-{key}.npz"
    out = cached(path, compute)
    return out["labels"].astype(np.int64), out["probs"].astype(np.float32)


def stand_in(item: TuningScan) -> dict[str, np.ndarray]:
    """The stand-in network's labels and probabilities, seeded by the scan's content."""
    from jointseg.synth.label_noise import corrupt_labels

    if item.scan.labels is None:
        raise ConfigError(f"the stand-in labeller needs labels; {item.name} has none")
    rng = np.random.default_rng(int(item.key, 16))
    labels, probs = corrupt_labels(item.scan.xyz, item.scan.labels, rng=rng)
    return {"labels": labels.astype(np.int8), "probs": probs.astype(np.float16)}


def geometry_output(
    item: TuningScan, params: Any = None, cache: Path | None = None
) -> dict[str, np.ndarray]:
    """Segments, main-plane ids and the structure reading of the geometry (``params``:
    GeometryParams, default its defaults) on a scan; under ``cache/geo`` when given."""
    from jointseg.geometry import GeometryParams, segment

    params = params or GeometryParams()

    def compute() -> dict[str, np.ndarray]:
        result = segment(item.scan, params, seed=0)
        out = {"segments": result.segments, "plane_id": result.plane_id}
        if result.structure is not None and result.structure_confidence is not None:
            out |= {"structure": result.structure, "structure_conf": result.structure_confidence}
        return out

    key = content_key(params.model_dump_json(), STRUCTURE_VERSION)
    return cached(None if cache is None else cache / "geo" / f"{item.key}-{key}.npz", compute)
