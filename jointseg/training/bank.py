"""Crop bank: augmented training crops drawn once, with every layer's neighbour, pooling and
up-sampling indices, stored on disk so that a training step only reads them.

Why: on a 2-core CPU the trainer spent about one core cutting, augmenting and KD-tree-searching
each batch while the other computed. A bank is built once by both cores (worker processes) and
then serves any number of runs; training steps read memory-mapped crops and add cheap
augmentations that leave the neighbours as they are (:mod:`jointseg.training.bank_batches`).

Layout of a bank folder: ``manifest.json`` (:class:`BankManifest`: what the crops were drawn
from, how, how many, how many bytes) and shards ``shard_FIRST.npy``, each a numpy array of
records (:func:`record_dtype`): the crop's points as the trainer draws them (float32), colour
(float16: 1/2048 steps, finer than 8-bit colour), labels (int8), every layer's neighbour indices
(uint16 up to 65 536 points) and up-sampling indices. A layer's pooling indices are the first
rows of its neighbour indices and its coordinates the first points of the crop, so neither is
stored. Crop ``j`` is drawn from a generator seeded with ``(seed, j)``: a bank extended later
holds the crops one built at once would, whichever worker drew them.

Each shard is written to a temporary file and renamed into place, and the manifest (rewritten
the same way after every shard) lists only finished shards, so an interrupted build leaves no
half shard and is resumed by asking for the same bank again.
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import shutil
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from jointseg.exceptions import ConfigError
from jointseg.io.atomic import atomic_open
from jointseg.network.randlanet.crops import build_batch, pad_to, set_search_threads
from jointseg.network.randlanet.model import RandLANetConfig
from jointseg.training.augment import AugmentParams
from jointseg.training.batches import Crop, training_crop

if TYPE_CHECKING:
    from jointseg.training.config import TrainConfig, TrainingData

log = logging.getLogger(__name__)

MANIFEST = "manifest.json"
VERSION = 1
#: Crops per shard file (about 17 MB at 4 096 points).
SHARD_CROPS = 64
#: Room left per shard for the .npy header when checking the disk bound.
HEADER_BYTES = 4096
#: Keeps the bank's generators apart from the batches' (seeded with (seed, i)).
STREAM = 0xBA4C


class BankSpec(BaseModel):
    """What a bank's crops are drawn from and how: a bank is only extended with the same."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    sources: list[str]
    source_options: dict[str, object] = Field(
        description="validation and exclusion patterns, S3DIS test area, synthetic rooms"
    )
    balanced_crops: bool
    colour: bool = Field(description="False: colour inputs zero in every crop")
    augment: AugmentParams = Field(
        description="the trainer's augmentation, drawn at build time (colour drops are drawn "
        "per step instead)"
    )
    num_points: int
    grid: float
    ratios: tuple[int, ...]
    k: int
    seed: int


class ShardInfo(BaseModel):
    """One finished shard: its file, the index of its first crop, its crops and bytes."""

    name: str
    first: int
    crops: int
    bytes: int


class BankManifest(BaseModel):
    """``manifest.json``: the spec, the finished shards and what building them cost."""

    version: int = VERSION
    spec: BankSpec
    crops: int = 0
    bytes: int = 0
    bytes_per_crop: int
    shards: list[ShardInfo] = Field(default_factory=list)
    build_seconds: float = 0.0
    build_workers: int = 0
    created: str = Field(default_factory=lambda: datetime.now(UTC).isoformat(timespec="seconds"))
    updated: str | None = None
    data: str = ""

    def summary(self, path: Path) -> dict[str, object]:
        """What a model card keeps of the bank it was trained from."""
        return {
            "path": str(path),
            "crops": self.crops,
            "bytes": self.bytes,
            "num_points": self.spec.num_points,
            "seed": self.spec.seed,
            "sources": self.spec.sources,
            "created": self.created,
        }


def layer_sizes(num_points: int, ratios: Sequence[int]) -> list[int]:
    """Points per encoder layer, as :func:`~jointseg.network.randlanet.crops.build_batch`
    sub-samples them, and the size after the last pooling."""
    sizes = [num_points]
    for ratio in ratios:
        sizes.append(max(1, sizes[-1] // ratio))
    return sizes


def record_dtype(num_points: int, ratios: Sequence[int], k: int) -> np.dtype:
    """One crop's record in a shard."""
    m = sum(layer_sizes(num_points, ratios)[:-1])
    index = np.uint16 if num_points <= 2**16 else np.int32
    return np.dtype(
        [
            ("xyz", "<f4", (num_points, 3)),
            ("rgb", "<f2", (num_points, 3)),
            ("labels", "i1", (num_points,)),
            ("neighbours", index, (m, k)),
            ("upsamples", index, (m,)),
        ]
    )


def bank_spec(cfg: TrainConfig) -> BankSpec:
    """The bank a training configuration's crops would fill (RandLA-Net's layers)."""
    net = RandLANetConfig(num_points=cfg.num_points)
    aug = cfg.augmentation()
    return BankSpec(
        sources=cfg.sources(),
        source_options={
            "val_scans": list(cfg.val_scans),
            "val_count": cfg.val_count,
            "exclude_scans": list(cfg.exclude_scans),
            "test_area": cfg.test_area,
            "synth_rooms": cfg.synth_rooms,
            "synth_floors": cfg.synth_floors,
            "synth_val_rooms": cfg.val_rooms,
            "synth_points": cfg.synth_points,
        },
        balanced_crops=cfg.balanced_crops,
        colour=cfg.colour,
        augment=aug.model_copy(update={"colour_drop": 0.0 if cfg.colour else 1.0}),
        num_points=cfg.num_points,
        grid=net.grid_size,
        ratios=net.ratios,
        k=net.k,
        seed=cfg.seed,
    )


def read_manifest(folder: Path) -> BankManifest | None:
    """The folder's manifest, None when there is none yet."""
    path = folder / MANIFEST
    if not path.is_file():
        return None
    return BankManifest.model_validate_json(path.read_text())


def _write_manifest(folder: Path, manifest: BankManifest) -> None:
    with atomic_open(folder / MANIFEST) as fh:
        fh.write((json.dumps(manifest.model_dump(mode="json"), indent=1) + "\n").encode())


@dataclass
class _Drawer:
    """What drawing crop ``j`` needs; the worker processes inherit it (fork)."""

    spec: BankSpec
    clouds: list
    draw_p: np.ndarray
    centre_p: list[np.ndarray | None]

    def crop(self, j: int) -> Crop:
        """Crop ``j``: drawn as the trainer draws one, padded (repeated points) to the bank's
        size and shuffled, as the trainer pads small crops."""
        spec = self.spec
        rng = np.random.default_rng([STREAM, spec.seed, j])
        k = int(rng.choice(len(self.clouds), p=self.draw_p))
        crop = training_crop(
            self.clouds[k], spec.num_points, spec.grid, rng, spec.augment, self.centre_p[k]
        )
        if len(crop.xyz) < spec.num_points:
            order = rng.permutation(pad_to(np.arange(len(crop.xyz)), spec.num_points, rng))
            crop = Crop(crop.xyz[order], crop.rgb[order], crop.labels[order])
        return crop

    def records(self, first: int, stop: int) -> np.ndarray:
        """Crops ``first`` to ``stop - 1`` with their layers' indices (build_batch's own)."""
        spec = self.spec
        net = RandLANetConfig(num_points=spec.num_points, ratios=spec.ratios, k=spec.k)
        out = np.zeros(stop - first, dtype=record_dtype(spec.num_points, spec.ratios, spec.k))
        for row, j in enumerate(range(first, stop)):
            crop = self.crop(j)
            n = len(crop.xyz)
            batch = build_batch([(crop.xyz, crop.rgb, crop.labels, np.arange(n))], net)
            rec = out[row]
            rec["xyz"] = crop.xyz
            rec["rgb"] = crop.rgb
            rec["labels"] = crop.labels
            rec["neighbours"] = np.concatenate([t[0].numpy() for t in batch.neighbours])
            rec["upsamples"] = np.concatenate([t[0, :, 0].numpy() for t in batch.upsamples])
        return out


_drawer: _Drawer | None = None


def _worker_init() -> None:
    import torch

    torch.set_num_threads(1)
    set_search_threads(1)


def _write_shard(task: tuple[Path, int, int]) -> ShardInfo:
    """Draw and write one shard (in a worker process); atomic, so never half a shard."""
    folder, first, stop = task
    assert _drawer is not None
    records = _drawer.records(first, stop)
    name = f"shard_{first:09d}.npy"
    with atomic_open(folder / name) as fh:
        np.save(fh, records)
    return ShardInfo(
        name=name, first=first, crops=stop - first, bytes=(folder / name).stat().st_size
    )


def _tidy(folder: Path, manifest: BankManifest | None) -> None:
    """Remove what an interrupted build left outside the manifest (shards renamed into place
    before the manifest listed them, temporary files)."""
    listed = {s.name for s in manifest.shards} if manifest else set()
    for path in folder.glob("shard_*.npy"):
        if path.name not in listed:
            log.info("removing %s: not in the manifest (an interrupted build)", path.name)
            path.unlink()
    for path in folder.glob(".shard_*"):
        path.unlink()


def check_room(
    folder: Path, spec: BankSpec, have: BankManifest | None, crops: int, max_bytes: int
) -> None:
    """Refuse a build that would pass ``max_bytes`` or the free disk, before any work."""
    per_crop = record_dtype(spec.num_points, spec.ratios, spec.k).itemsize
    done = have.crops if have else 0
    used = have.bytes if have else 0
    shards = -(-(crops - done) // SHARD_CROPS)
    need = (crops - done) * per_crop + shards * HEADER_BYTES
    if used + need > max_bytes:
        fit = done + max(0, (max_bytes - used - shards * HEADER_BYTES) // per_crop)
        raise ConfigError(
            f"crop bank {folder}: {crops} crops of {per_crop / 1e6:.2f} MB need "
            f"{(used + need) / 1e6:.1f} MB, beyond the bound of {max_bytes / 1e6:.1f} MB "
            f"(at most about {fit} crops fit; raise --bank-gb or ask for fewer crops)"
        )
    free = shutil.disk_usage(folder).free
    if need > free:
        raise ConfigError(
            f"crop bank {folder}: {need / 1e6:.1f} MB more needed, {free / 1e6:.1f} MB free"
        )


def build_bank(
    cfg: TrainConfig,
    folder: Path,
    crops: int,
    *,
    max_bytes: int,
    workers: int = 2,
    data: TrainingData | None = None,
) -> BankManifest:
    """Fill ``folder`` with ``crops`` crops of ``cfg``'s sources and augmentation (extending
    what is there; the same spec or a :class:`ConfigError`), by ``workers`` processes.

    ``max_bytes`` bounds the whole bank: a build that would pass it is refused before any crop
    is drawn. ``data`` saves loading the sources again when the caller has them.
    """
    global _drawer
    spec = bank_spec(cfg)
    folder.mkdir(parents=True, exist_ok=True)
    have = read_manifest(folder)
    if have is not None and have.spec != spec:
        raise ConfigError(
            f"crop bank {folder} was drawn from other sources, augmentation, crop size or seed "
            f"than this configuration's ({_differences(have.spec, spec)}): use another folder"
        )
    _tidy(folder, have)
    manifest = have or BankManifest(
        spec=spec, bytes_per_crop=record_dtype(spec.num_points, spec.ratios, spec.k).itemsize
    )
    if crops <= manifest.crops:
        log.info("crop bank %s holds %d crops already", folder, manifest.crops)
        return manifest
    check_room(folder, spec, have, crops, max_bytes)
    if data is None:
        from jointseg.training.config import training_data

        data = training_data(cfg, spec.grid)
    manifest.data = data.description
    _drawer = _Drawer(spec, data.clouds, data.draw_p, data.centre_p)
    tasks = [
        (folder, first, min(first + SHARD_CROPS, crops))
        for first in range(manifest.crops, crops, SHARD_CROPS)
    ]
    started = time.perf_counter()
    try:
        for shard in _shards(tasks, workers):
            manifest.shards.append(shard)
            manifest.crops += shard.crops
            manifest.bytes += shard.bytes
            manifest.build_seconds += time.perf_counter() - started
            manifest.build_workers = max(1, workers)
            manifest.updated = datetime.now(UTC).isoformat(timespec="seconds")
            started = time.perf_counter()
            _write_manifest(folder, manifest)
            log.info(
                "crop bank %s: %d of %d crops, %.1f MB", folder, manifest.crops, crops,
                manifest.bytes / 1e6,
            )  # fmt: skip
    finally:
        _drawer = None
    return manifest


def _shards(tasks: list[tuple[Path, int, int]], workers: int) -> Iterator[ShardInfo]:
    """The tasks' shards in order, drawn in ``workers`` processes (fork; 0 or 1: here)."""
    if workers <= 1:
        yield from map(_write_shard, tasks)
        return
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(workers, initializer=_worker_init) as pool:
        yield from pool.imap(_write_shard, tasks)


def _differences(have: BankSpec, want: BankSpec) -> str:
    a, b = have.model_dump(), want.model_dump()
    return ", ".join(f"{key}: {a[key]!r} there, {b[key]!r} here" for key in a if a[key] != b[key])


class CropBank:
    """A bank's crops, memory-mapped: ``record(j)`` reads crop ``j`` from its shard."""

    def __init__(self, folder: Path) -> None:
        manifest = read_manifest(folder)
        if manifest is None or manifest.crops == 0:
            raise ConfigError(
                f"crop bank {folder}: no manifest or no crops (build one with 'prepared bank' "
                "or 'jointseg train --bank DIR --bank-crops N')"
            )
        self.folder = folder
        self.manifest = manifest
        self.spec = manifest.spec
        self._shards = [np.load(folder / s.name, mmap_mode="r") for s in manifest.shards]
        self._starts = np.array([s.first for s in manifest.shards])

    def __len__(self) -> int:
        return self.manifest.crops

    def record(self, j: int) -> np.void:
        """Crop ``j``'s record (a view into its shard's memory map)."""
        s = int(np.searchsorted(self._starts, j, side="right")) - 1
        return self._shards[s][j - int(self._starts[s])]
