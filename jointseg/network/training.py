"""Training RandLA-Net on synthetic rooms, S3DIS's own folder layout, a folder of labelled scans,
or real scans mixed with synthetic rooms.

Weighted cross-entropy, Adam with exponential decay, augmentation (rotation about z, mirror,
anisotropic scaling, elastic distortion, jitter, colour jitter and drop, point drop),
class-balanced crop centres, batches built a step ahead in a background thread,
validation mIoU per epoch, resumable checkpoints with a model card.
"""

from __future__ import annotations

import logging
import os
import platform
import time
from collections.abc import Iterator
from contextlib import nullcontext
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field
from scipy import ndimage

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.exceptions import ConfigError
from jointseg.metrics import evaluate
from jointseg.network.batches import Prefetcher, calls
from jointseg.network.checkpoint import load_checkpoint, save_checkpoint
from jointseg.network.crops import (
    MIN_CROP,
    Batch,
    GridCloud,
    build_batch,
    crop_indices,
    grid_subsample,
    pad_to,
)
from jointseg.network.predict import pick_device
from jointseg.network.randlanet import RandLANet, RandLANetConfig
from jointseg.network.train_data import (
    centre_weights,
    load_folder,
    mix_weights,
)
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report

log = logging.getLogger(__name__)
STAGE = "train"


class TrainConfig(BaseModel):
    """Everything a training run needs; stored in the checkpoint's model card."""

    model_config = ConfigDict(extra="forbid")

    data: str = Field(
        "synth",
        description="'synth', a Stanford3dDataset_v1.2 folder, or a folder of labelled scans",
    )
    out: Path
    test_area: int = Field(5, ge=1, le=6, description="S3DIS area held out for validation")
    synth_rooms: int = Field(40, ge=1, description="synthetic training rooms")
    synth_floors: int = Field(4, ge=0, description="synthetic training floors")
    synth_points: int = Field(300_000, ge=10_000, description="points per synthetic room")
    val_rooms: int = Field(4, ge=1, description="synthetic validation rooms")
    val_scans: list[str] = Field(
        default_factory=list,
        description="folder data: file stems kept out of training for validation",
    )
    val_count: int = Field(
        5, ge=1, description="folder data without val_scans: this many, in a name-hash order"
    )
    synth_share: float = Field(
        0.0, ge=0, lt=1, description="folder/S3DIS data: share of crops from synthetic rooms"
    )
    balanced_crops: bool = Field(True, description="centre crops on rare classes more often")
    init: Path | None = Field(None, description="start from these weights (fresh optimiser)")
    epochs: int = Field(20, ge=1)
    steps_per_epoch: int = Field(100, ge=1)
    batch_size: int = Field(2, ge=1)
    num_points: int = Field(16_384, ge=1024, description="points per training crop")
    lr: float = Field(0.01, gt=0)
    gamma: float = Field(0.95, gt=0, le=1, description="learning-rate decay per epoch")
    seed: int = 0
    resume: Path | None = None
    threads: int | None = None
    num_channels_scale: float = Field(
        1.0, gt=0, le=1, description="scale RandLA-Net's channel widths (lighter network)"
    )
    elastic: float = Field(
        0.3, ge=0, le=1, description="share of training crops given an elastic distortion"
    )
    prefetch: bool = Field(
        True, description="build the next batch in a background thread while the network runs"
    )
    device: str | None = Field(
        None,
        description="'cpu' or 'cuda' (default: cuda when present); crops and neighbour search "
        "stay on the CPU, a step ahead in the batch thread",
    )
    command: str | None = Field(
        None, description="the command line that started the run, kept in the model card"
    )


def _model_config(cfg: TrainConfig) -> RandLANetConfig:
    """The official configuration, channel widths scaled by ``num_channels_scale``."""
    base = RandLANetConfig(num_points=cfg.num_points)
    if cfg.num_channels_scale == 1.0:
        return base
    scale = cfg.num_channels_scale
    return base.model_copy(
        update={
            "d_stem": max(4, round(base.d_stem * scale)),
            "d_out": tuple(max(8, round(d * scale)) for d in base.d_out),
        }
    )


def class_weights(labels: list[np.ndarray]) -> torch.Tensor:
    """RandLA-Net's weights 1 / (frequency + 0.02), so rare classes are not ignored."""
    counts = np.bincount(np.concatenate([lab[lab >= 0] for lab in labels]), minlength=NUM_CLASSES)
    freq = counts / max(counts.sum(), 1)
    return torch.tensor(1.0 / (freq + 0.02), dtype=torch.float32)


def _synthetic(cfg: TrainConfig, grid: float) -> tuple[list[GridCloud], list[GridCloud], str]:
    from jointseg.synth import make_floor, make_room

    train: list[GridCloud] = []
    val: list[GridCloud] = []
    for i in range(cfg.synth_rooms):
        scan = make_room(1000 + i, points=cfg.synth_points, shape="L" if i % 3 == 2 else "box")
        train.append(grid_subsample(scan.xyz, scan.rgb, scan.labels, grid))
    for i in range(cfg.synth_floors):
        scan = make_floor(3000 + i, points=cfg.synth_points * 3)
        train.append(grid_subsample(scan.xyz, scan.rgb, scan.labels, grid))
    for i in range(cfg.val_rooms):
        scan = make_room(2000 + i, points=cfg.synth_points, shape="L" if i % 2 else "box")
        val.append(grid_subsample(scan.xyz, scan.rgb, scan.labels, grid))
    text = (
        f"jointseg.synth: {cfg.synth_rooms} rooms (seeds 1000+, box and L, random yaw, "
        f"{cfg.synth_points} points) and {cfg.synth_floors} floors (seeds 3000+)"
    )
    return train, val, text


def load_clouds(
    cfg: TrainConfig, grid: float
) -> tuple[list[GridCloud], np.ndarray, list[GridCloud], str]:
    """Training clouds, their draw probabilities, validation clouds and a card description.

    Validation is on real scans whenever there are any; synthetic rooms mixed into a real
    source only train.
    """
    if cfg.data == "synth":
        train, val, text = _synthetic(cfg, grid)
        return (
            train,
            mix_weights(len(train), 0, 0.0),
            val,
            text + "; validation rooms seeds 2000+; no real scans",
        )
    root = Path(cfg.data)
    if root.is_dir() and any(root.glob("Area_*/*/Annotations")):
        train, val, text = _load_s3dis(root, cfg.test_area, grid)
    else:
        train, val, train_names, val_names = load_folder(
            root, grid, val=cfg.val_scans, val_count=cfg.val_count
        )
        text = (
            f"{len(train_names)} labelled scans from {root} ({', '.join(train_names)}); "
            f"validation (never trained on): {', '.join(val_names)}"
        )
    n_real = len(train)
    if cfg.synth_share > 0:
        synth, _, synth_text = _synthetic(cfg, grid)
        train += synth
        text += f"; mixed with {synth_text} at {cfg.synth_share:.0%} of the crops"
    return train, mix_weights(n_real, len(train) - n_real, cfg.synth_share), val, text


def _load_s3dis(
    root: Path, test_area: int, grid: float
) -> tuple[list[GridCloud], list[GridCloud], str]:
    from jointseg.io import read_scan

    rooms = sorted(root.glob("Area_*/*/Annotations"))
    if not rooms:
        raise ConfigError(
            f"{root}: no Area_N/<room>/Annotations folders (expected the "
            "Stanford3dDataset_v1.2_Aligned_Version layout)"
        )
    train: list[GridCloud] = []
    val: list[GridCloud] = []
    for ann in rooms:
        scan = read_scan(ann.parent)
        cloud = grid_subsample(scan.xyz, scan.rgb, scan.labels, grid)
        (val if ann.parent.parent.name == f"Area_{test_area}" else train).append(cloud)
    return train, val, f"S3DIS at {root}, Area_{test_area} held out ({len(train)} rooms)"


#: Elastic distortion: a random displacement field on a grid of this pitch (m), smoothed over
#: neighbouring grid cells, scaled to about this many metres of displacement.
ELASTIC_PITCH = 0.4
ELASTIC_MAGNITUDE = 0.02


def elastic_distortion(
    xyz: np.ndarray,
    rng: np.random.Generator,
    pitch: float = ELASTIC_PITCH,
    magnitude: float = ELASTIC_MAGNITUDE,
) -> np.ndarray:
    """Points moved by a smooth random field: walls bow and tables tilt a little, as in real
    scans whose registration is not perfect (grid noise, box-smoothed, trilinearly sampled)."""
    lo = xyz.min(axis=0) - pitch
    shape = tuple(int(n) for n in np.ceil((xyz.max(axis=0) - lo) / pitch) + 3)
    moved = xyz.astype(np.float32).copy()
    coords = ((xyz - lo) / pitch).T
    for axis in range(3):
        field = ndimage.uniform_filter(rng.normal(0, 1, shape), size=3, mode="nearest")
        field *= magnitude / max(float(field.std()), 1e-6)
        moved[:, axis] += ndimage.map_coordinates(field, coords, order=1, mode="nearest")
    return moved


def augment(
    xyz: np.ndarray, rgb: np.ndarray, rng: np.random.Generator, *, elastic: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Rotation about z, a mirror half of the time, scaling 0.9-1.1 per axis, an elastic
    distortion for a share ``elastic`` of the crops, 1 mm jitter, brightness, per-channel gain
    and colour noise; one crop in ten loses its colour (grey), so a scan with poor colour does
    not throw the network."""
    theta = rng.uniform(0, 2 * np.pi)
    c, s = np.cos(theta), np.sin(theta)
    centre = xyz.mean(axis=0)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float32)
    scale = rng.uniform(0.9, 1.1, 3)
    if rng.random() < 0.5:
        scale[0] = -scale[0]
    xyz = (xyz - centre) @ rot.T * scale.astype(np.float32) + centre
    if elastic and rng.random() < elastic:
        xyz = elastic_distortion(xyz, rng)
    xyz = xyz + rng.normal(0, 0.001, xyz.shape).astype(np.float32)
    rgb = rgb * rng.uniform(0.8, 1.2) * rng.uniform(0.95, 1.05, 3) + rng.normal(0, 0.02, rgb.shape)
    if rng.random() < 0.1:
        rgb = np.repeat(rgb.mean(axis=1, keepdims=True), 3, axis=1)
    return xyz.astype(np.float32), np.clip(rgb, 0, 1).astype(np.float32)


def random_crop(
    cloud: GridCloud,
    num_points: int,
    rng: np.random.Generator,
    *,
    train: bool,
    centre_p: np.ndarray | None = None,
    elastic: float = 0.0,
):
    """A shuffled crop around a random point (drawn with ``centre_p`` when given), augmented
    for training, where up to a tenth of its points are also dropped (then re-padded)."""
    centre = (
        rng.choice(len(cloud.xyz), p=centre_p)
        if centre_p is not None
        else rng.integers(len(cloud.xyz))
    )
    idx = crop_indices(cloud, cloud.xyz[centre], num_points)
    if train and len(idx) > MIN_CROP:
        idx = idx[rng.random(len(idx)) >= rng.uniform(0, 0.1)]
    idx = rng.permutation(pad_to(idx, min(num_points, max(len(idx), MIN_CROP)), rng))
    xyz, rgb = cloud.xyz[idx], cloud.rgb[idx]
    if train:
        xyz, rgb = augment(xyz, rgb, rng, elastic=elastic)
    assert cloud.labels is not None
    return xyz, rgb, cloud.labels[idx], idx


def validate(model: RandLANet, clouds: list[GridCloud], cfg: TrainConfig) -> float | None:
    """mIoU on deterministic crops of each validation cloud (about twice its points)."""
    rng = np.random.default_rng(12345)
    gts, preds = [], []
    device = next(model.parameters()).device
    model.eval()
    with torch.no_grad():
        for cloud in clouds:
            for _ in range(max(2, int(np.ceil(2 * len(cloud.xyz) / cfg.num_points)))):
                xyz, rgb, lab, idx = random_crop(cloud, cfg.num_points, rng, train=False)
                batch = build_batch([(xyz, rgb, lab, idx)], model.config).to(device)
                logits = model(
                    batch.features, batch.coords, batch.neighbours, batch.pools, batch.upsamples
                )
                preds.append(logits.argmax(-1).cpu().numpy().ravel())
                gts.append(lab)
    model.train()
    return evaluate(np.concatenate(gts), np.concatenate(preds)).miou


def train(
    cfg: TrainConfig, progress: ProgressFn | None = None, cancel: CancelToken | None = None
) -> Path:
    """Train, writing ``cfg.out`` after every epoch (with optimiser state, for ``resume``).

    Returns
    -------
    Path of the checkpoint.
    """
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    history: list[dict] = []
    start_epoch = 0
    body: dict | None = None
    if cfg.resume is not None:
        model, card, body = load_checkpoint(cfg.resume)
        # A packed checkpoint (models pack) has no optimiser state or epoch: continue its
        # weights from the epoch its card records, with a fresh optimiser.
        start_epoch = int(body.get("epoch", card.get("epochs", 0)))
        history = list(card.get("history", []))
    elif cfg.init is not None:
        model, _, _ = load_checkpoint(cfg.init)
    else:
        model = RandLANet(_model_config(cfg))
    model_cfg = model.config
    device = pick_device(cfg.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {cfg.device!r}: this machine's torch sees no CUDA device")
    model.to(device)
    optimiser = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    scheduler = torch.optim.lr_scheduler.ExponentialLR(optimiser, cfg.gamma)
    if body is not None and "optimizer" in body:
        optimiser.load_state_dict(body["optimizer"])
        scheduler.load_state_dict(body["scheduler"])
    report(progress, STAGE, 0.0)
    train_clouds, draw_p, val_clouds, data_text = load_clouds(cfg, model_cfg.grid_size)
    if cfg.init is not None:
        data_text += f"; started from {cfg.init.name}"
    weights = class_weights([c.labels for c in train_clouds if c.labels is not None])
    centre_p = [
        centre_weights(c.labels, weights.numpy())
        if cfg.balanced_crops and c.labels is not None
        else None
        for c in train_clouds
    ]
    loss_fn = torch.nn.CrossEntropyLoss(weight=weights.to(device), ignore_index=-1)
    model.train()

    def make() -> Batch:
        return draw_batch(train_clouds, draw_p, centre_p, cfg, model_cfg, rng).to(device)

    count = (cfg.epochs - start_epoch) * cfg.steps_per_epoch
    source = calls(make, count)
    batches = Prefetcher(source) if cfg.prefetch else nullcontext(source)
    with batches as stream:
        _train_epochs(
            cfg,
            model,
            optimiser,
            scheduler,
            loss_fn,
            stream,
            val_clouds,
            data_text,
            history,
            start_epoch,
            progress,
            cancel,
        )
    return cfg.out


#: What a network trained on S3DIS-derived rooms carries with it (S3DIS's terms of use).
S3DIS_TERMS = (
    "trained on data derived from the Stanford Large-Scale 3D Indoor Spaces Dataset (S3DIS; "
    "Armeni et al., CVPR 2016), whose terms allow non-commercial research and educational use "
    "and ask users to cite the dataset paper; weights derived from it carry the same terms"
)


SYNTH_TERMS = "synthetic rooms only (jointseg.synth); no third-party data"


def card_facts(cfg: TrainConfig, history: list[dict]) -> dict[str, object]:
    """What a user deciding whether to trust the weights wants: the hardware, the command, the
    validation figures and the data's terms of use."""
    scores = [(h["val_miou"], h["epoch"]) for h in history if h.get("val_miou") is not None]
    best = max(scores) if scores else None
    real = cfg.data != "synth"
    device = pick_device(cfg.device)
    gpu = torch.cuda.get_device_name(device) if device.type == "cuda" else "no GPU"
    return {
        "hardware": (
            f"{platform.machine()} CPU, {os.cpu_count()} cores, torch {torch.__version__}, "
            f"{torch.get_num_threads()} torch threads, {gpu}"
        ),
        "command": cfg.command,
        "validation": {
            "last_miou": scores[-1][0] if scores else None,
            "best_miou": best[0] if best else None,
            "best_epoch": best[1] if best else None,
            "what": "mIoU on random crops of the held-out scans named in 'data'"
            if real
            else "mIoU on random crops of held-out synthetic rooms",
        },
        "synthetic_share": cfg.synth_share if real else 1.0,
        "terms": S3DIS_TERMS
        if real
        else "synthetic rooms only (jointseg.synth); no third-party data",
    }


def draw_batch(
    clouds: list[GridCloud],
    draw_p: np.ndarray,
    centre_p: list[np.ndarray | None],
    cfg: TrainConfig,
    model_cfg: RandLANetConfig,
    rng: np.random.Generator,
) -> Batch:
    """One training batch: ``cfg.batch_size`` augmented crops from rooms drawn by ``draw_p``,
    cut to a common size, with their per-layer neighbour indices."""
    picks = rng.choice(len(clouds), size=cfg.batch_size, p=draw_p)
    crops = [
        random_crop(
            clouds[k], cfg.num_points, rng, train=True, centre_p=centre_p[k], elastic=cfg.elastic
        )
        for k in picks
    ]
    size = min(len(c[0]) for c in crops)
    crops = [(x[:size], r[:size], lab[:size], i[:size]) for x, r, lab, i in crops]
    return build_batch(crops, model_cfg)


def _train_epochs(
    cfg: TrainConfig,
    model: RandLANet,
    optimiser: torch.optim.Optimizer,
    scheduler: torch.optim.lr_scheduler.LRScheduler,
    loss_fn: torch.nn.Module,
    batches: Iterator[Batch],
    val_clouds: list[GridCloud],
    data_text: str,
    history: list[dict],
    start_epoch: int,
    progress: ProgressFn | None,
    cancel: CancelToken | None,
) -> None:
    """The epochs from ``start_epoch``: steps on ``batches``, validation, a checkpoint each."""
    total_steps = cfg.epochs * cfg.steps_per_epoch
    for epoch in range(start_epoch, cfg.epochs):
        started, losses, hits, seen = time.perf_counter(), [], 0, 0
        for step in range(cfg.steps_per_epoch):
            check_cancel(cancel)
            batch = next(batches)
            logits = model(
                batch.features, batch.coords, batch.neighbours, batch.pools, batch.upsamples
            )
            assert batch.labels is not None
            loss = loss_fn(logits.reshape(-1, NUM_CLASSES), batch.labels.reshape(-1))
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            losses.append(float(loss.detach()))
            known = batch.labels >= 0
            hits += int((logits.detach().argmax(-1) == batch.labels)[known].sum())
            seen += int(known.sum())
            report(progress, STAGE, (epoch * cfg.steps_per_epoch + step + 1) / total_steps)
        scheduler.step()
        miou = validate(model, val_clouds, cfg)
        history.append(
            {
                "epoch": epoch + 1,
                "loss": float(np.mean(losses)),
                "train_accuracy": hits / max(seen, 1),
                "val_miou": miou,
                "seconds": time.perf_counter() - started,
            }
        )
        log.info(
            "epoch %d loss %.3f train accuracy %.3f val mIoU %s",
            epoch + 1,
            np.mean(losses),
            hits / max(seen, 1),
            miou,
        )
        card = {
            "architecture": "RandLA-Net (Hu et al. 2020), S3DIS configuration",
            "classes": list(CLASS_NAMES),
            "data": data_text,
            "epochs": epoch + 1,
            "steps": (epoch + 1) * cfg.steps_per_epoch,
            "history": history,
            "train_config": cfg.model_dump(mode="json"),
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            **card_facts(cfg, history),
        }
        extra = {
            "optimizer": optimiser.state_dict(),
            "scheduler": scheduler.state_dict(),
            "epoch": epoch + 1,
        }
        save_checkpoint(cfg.out, model, card, extra=extra)
