"""`jointseg predict`, `jointseg train` and `jointseg models`: the network stage."""

from __future__ import annotations

import shlex
import sys
import time
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import typer
from rich.console import Console
from rich.table import Column, Table

from jointseg.cli.progress_bar import progress_bar
from jointseg.exceptions import ConfigError
from jointseg.io import DEFAULT_MAX_POINTS, read_scan, write_scan
from jointseg.network.registry import BACKENDS, DEFAULT_BACKEND

models_app = typer.Typer(help="Network backends and weights.", no_args_is_help=True)

#: The registered backends as choices (the registry imports no torch, so --help stays quick);
#: mypy cannot list members that come from the registry.
Network = StrEnum("Network", {name: name for name in BACKENDS})  # type: ignore[misc]


class ImportSource(StrEnum):
    """Where `jointseg models import` takes foreign weights from (only Open3D-ML's RandLA-Net
    checkpoints so far)."""

    open3d_ml = "open3d-ml"


def predict(
    source: Path = typer.Argument(..., help="Input scan."),
    output: Path = typer.Option(..., "-o", "--output", help="Output scan with network fields."),
    network: Network = typer.Option(Network(DEFAULT_BACKEND), help="Network backend."),
    weights: Path | None = typer.Option(
        None,
        help="Weights file (default: $JOINTSEG_DGCNN_WEIGHTS for dgcnn, bundled for randlanet).",
    ),
    device: str | None = typer.Option(None, help="cpu or cuda (default: cuda when present)."),
    batch_size: int | None = typer.Option(
        None,
        min=1,
        help="Crops (randlanet) or 4 096-point blocks (dgcnn) per forward pass "
        "(default: 1 on the CPU, 8 on CUDA).",
    ),
    seed: int = typer.Option(0, help="Sampling randomness; the same seed gives the same labels."),
    max_points: int = typer.Option(DEFAULT_MAX_POINTS, help="Refuse larger scans."),
    up: str = typer.Option("auto", help="auto, +z, -z, +y, -y, +x or -x: the axis that points up."),
    units: str = typer.Option("auto", help="auto, m, cm, mm, ft, us-ft or in."),
) -> None:
    """Label every point with the network; writes network_label, network_confidence and
    stray (the scan is levelled and put in metres first, as `jointseg segment` does)."""
    from jointseg.network import load

    frame_params = _frame_params(up, units)
    predictor = load(network.value, weights, device=device, batch_size=batch_size)
    started = time.perf_counter()
    with progress_bar() as progress:
        scan = read_scan(source, max_points=max_points, progress=progress)
        labels, confidence, stray, crops = _predict_in_frame(
            scan, predictor, frame_params, network.value, weights, seed, progress
        )
        out = scan.with_fields(
            network_label=labels.astype(np.int32),
            network_confidence=confidence.astype(np.float32),
            stray=stray.astype(np.uint8),
        )
        write_scan(out, output, progress=progress)
    seconds = time.perf_counter() - started
    typer.echo(
        f"{len(scan):,} points labelled with {network.value} in {seconds:.1f} s "
        f"({crops} crops) -> {output}",
        err=True,
    )


def _frame_params(up: str, units: str) -> Any:
    """The frame options, validated before any work (a bad value is one line, exit 2)."""
    from pydantic import ValidationError

    from jointseg.frame.params import FrameParams

    try:
        return FrameParams.model_validate({"up": up, "units": units})
    except ValidationError as exc:
        first = exc.errors()[0]
        raise ConfigError(f"--{first['loc'][0]}: {first['msg']}") from None


def _predict_in_frame(
    scan: Any,
    predictor: Any,
    params: Any,
    name: str,
    weights: Path | None,
    seed: int,
    progress: Any,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The network's labels and confidence for every point of ``scan``, run in the levelled
    metric frame (strays set aside, then given their nearest kept point's), and the stray mask."""
    from jointseg.frame.colour import decide_colour
    from jointseg.frame.decide import decide_frame, work_scan
    from jointseg.network.choice import colour_free_if_needed
    from jointseg.network.judge import crop_labeller
    from jointseg.pipeline.config import NetworkConfig

    config = NetworkConfig(name=name, weights=weights)
    usable = decide_colour(scan.rgb, params.colour).usable
    chosen = colour_free_if_needed(predictor, config.choice(), usable)
    frame = decide_frame(scan, params, judge=crop_labeller(chosen))
    typer.echo(frame.summary(), err=True)
    for warning in frame.warnings:
        typer.echo(f"warning: {warning}", err=True)
    work, index = work_scan(scan, frame)
    result = chosen.predict(work, progress=progress, seed=seed)
    labels, confidence = result.labels, result.confidence
    if index is not None:
        labels, confidence = labels[index], confidence[index]
    return labels, confidence, frame.stray, result.crops


COLOUR_HELP = (
    "Feed the scans' colour; --no-colour trains a colour-free network (for scans without "
    "colour, chosen automatically for them)."
)


#: ``jointseg train``'s crop-bank and worker options (module level: the command's option list
#: is long enough).
BANK_OPTION = typer.Option(
    None,
    help="Train on the crops of this crop bank (crops and their neighbour indices drawn "
    "once, read per step; see docs/guide/training.md).",
)
BANK_CROPS_OPTION = typer.Option(
    None, min=1, help="First build or extend --bank to this many crops, from --data."
)
BANK_GB_OPTION = typer.Option(4.0, min=0.001, help="Bound on the bank's size on disk (GB).")
WORKERS_OPTION = typer.Option(
    None,
    min=0,
    max=64,
    help="Processes building batches (0: in this process; default: one per spare core, "
    "at most 8). The batches are the same for any number.",
)


def train(
    data: list[str] = typer.Option(
        ["synth"],
        help="A source, '[NAME=]PATH[:SHARE]' or 'synth[:SHARE]': a folder of labelled scans "
        "(any format jointseg reads, with a label field) or a Stanford3dDataset_v1.2 folder; "
        "repeat to mix sources (shares add up to 1; sources without one split the rest).",
    ),
    out: Path = typer.Option(
        ..., "--out", help="Checkpoint to write after every epoch (the best one beside it)."
    ),
    epochs: int = typer.Option(20, min=1),
    steps: int = typer.Option(100, min=1, help="Steps per epoch."),
    batch_size: int = typer.Option(2, min=1),
    num_points: int | None = typer.Option(
        None, min=1024, help="Points per training crop (default 16384, or the bank's)."
    ),
    lr: float = typer.Option(0.01, min=0.0),
    gamma: float = typer.Option(0.95, min=0.01, max=1.0, help="Learning-rate decay per epoch."),
    test_area: int = typer.Option(5, min=1, max=6, help="S3DIS area held out."),
    synth_rooms: int = typer.Option(40, min=1, help="Synthetic training rooms."),
    synth_floors: int = typer.Option(4, min=0, help="Synthetic training floors."),
    synth_val_rooms: int = typer.Option(4, min=0, help="Synthetic validation rooms."),
    val_scan: list[str] = typer.Option(
        [],
        help="Folder data: a scan (file stem, or a pattern such as 'scene0002_*' to keep every "
        "re-scan of a room together) kept out of training for validation; repeat.",
    ),
    val_count: int = typer.Option(
        5, min=1, help="Folder data without --val-scan: hold out this many scans per folder."
    ),
    exclude_scan: list[str] = typer.Option(
        [],
        help="Folder data: a scan (stem or pattern) kept out of training and validation, to "
        "judge the result on; repeat.",
    ),
    synth_share: float = typer.Option(
        0.0, min=0.0, max=0.95, help="Share of crops from synthetic rooms (or --data synth:S)."
    ),
    balanced: bool = typer.Option(True, help="Centre crops on rare classes more often."),
    channels: float = typer.Option(
        1.0, min=0.1, max=1.0, help="Scale of the channel widths (1 = official configuration)."
    ),
    elastic: float = typer.Option(
        0.3, min=0.0, max=1.0, help="Share of crops given an elastic distortion."
    ),
    density: float = typer.Option(
        0.5, min=0.0, max=1.0, help="Share of crops sub-sampled at a random 1-6 cm first."
    ),
    partial: float = typer.Option(
        0.15, min=0.0, max=1.0, help="Share of crops cut by a vertical plane (partial rooms)."
    ),
    slices: float = typer.Option(
        0.1, "--slice", min=0.0, max=1.0, help="Share of crops keeping only a band above floor."
    ),
    tilt: float = typer.Option(3.0, min=0.0, max=15.0, help="Largest tilt in degrees."),
    colour: bool = typer.Option(True, help=COLOUR_HELP),
    workers: int | None = WORKERS_OPTION,
    prefetch: bool = typer.Option(
        True, help="Without workers: build the next batch in a background thread."
    ),
    threads: int | None = typer.Option(None, min=1, help="CPU threads for torch."),
    device: str | None = typer.Option(
        None,
        help="cpu or cuda (default: cuda when present); on cuda the neighbour searches "
        "run there too.",
    ),
    seed: int = typer.Option(0),
    init: Path | None = typer.Option(None, help="Start from these weights (fresh optimiser)."),
    resume: Path | None = typer.Option(None, help="Continue from this checkpoint."),
    bank: Path | None = BANK_OPTION,
    bank_crops: int | None = BANK_CROPS_OPTION,
    bank_gb: float = BANK_GB_OPTION,
) -> None:
    """Train RandLA-Net on synthetic rooms, S3DIS, folders of labelled scans, or a mix."""
    # every option by name, as typer passed it (nothing else is bound yet)
    _run_train(**locals())


def _run_train(**o: Any) -> None:
    """Body of ``jointseg train``, apart from its long option list so both stay readable."""
    from jointseg.training.augment import AugmentParams
    from jointseg.training.checkpoints import best_path
    from jointseg.training.config import TrainConfig
    from jointseg.training.loop import train as run_training
    from jointseg.training.streams import default_workers

    num_points = o["num_points"]
    if num_points is None:
        num_points = 16_384
        if o["bank"] is not None and o["bank_crops"] is None:
            from jointseg.training.bank import read_manifest

            manifest = read_manifest(o["bank"])
            num_points = manifest.spec.num_points if manifest else num_points
    cfg = TrainConfig(
        data=o["data"],
        out=o["out"],
        epochs=o["epochs"],
        steps_per_epoch=o["steps"],
        batch_size=o["batch_size"],
        num_points=num_points,
        lr=o["lr"],
        gamma=o["gamma"],
        test_area=o["test_area"],
        synth_rooms=o["synth_rooms"],
        synth_floors=o["synth_floors"],
        val_rooms=o["synth_val_rooms"],
        seed=o["seed"],
        resume=o["resume"],
        init=o["init"],
        val_scans=o["val_scan"],
        val_count=o["val_count"],
        exclude_scans=o["exclude_scan"],
        synth_share=o["synth_share"],
        balanced_crops=o["balanced"],
        num_channels_scale=o["channels"],
        threads=o["threads"],
        elastic=o["elastic"],
        augment=AugmentParams(
            density=o["density"], partial=o["partial"], slice=o["slices"], tilt_degrees=o["tilt"]
        ),
        workers=default_workers() if o["workers"] is None else o["workers"],
        prefetch=o["prefetch"],
        colour=o["colour"],
        device=o["device"],
        bank=o["bank"],
        bank_crops=o["bank_crops"],
        bank_gb=o["bank_gb"],
        command="jointseg " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
    )
    with progress_bar() as progress:
        path = run_training(cfg, progress=progress)
    typer.echo(f"wrote {path} (best by validation: {best_path(path)})", err=True)


@models_app.command("list")
def list_models() -> None:
    """Show the network backends and their weights."""
    from jointseg.network import available_backends

    table = Table("backend", "weights", "installed", "trained on", "from")
    backends = available_backends()
    for info in backends:
        table.add_row(
            info.name,
            "-" if info.weights is None else str(info.weights),
            "yes" if info.available else "no",
            info.trained_on,
            info.source,
        )
    Console().print(table)
    for info in backends:
        if not info.available:  # unwrapped, so links and paths stay whole
            typer.echo(f"{info.name}: no weights installed; {info.where_to_get}")
        elif info.card:
            typer.echo(f"{info.name} card: {info.card}")
    from jointseg.network import published

    pulled = Table("backend", "pulled", "checksum", "trained on")
    pulled.columns.insert(0, Column("published weights", no_wrap=True))
    for entry in published.catalogue().values():
        path = published.pulled_path(entry.name)
        pulled.add_row(
            entry.name,
            entry.backend,
            "no" if path is None else str(path),
            "SHA-256 pinned" if entry.sha256 else "none published",
            entry.description,
        )
    Console().print(pulled)
    typer.echo(
        f"`jointseg models pull NAME` fetches one into {published.cache_dir()} "
        f"(${published.CACHE_ENV}); use it with --weights NAME"
    )


@models_app.command("pull")
def pull_weights(
    name: str = typer.Argument(..., help="Published weights, e.g. dgcnn-s3dis-5."),
    unverified: bool = typer.Option(
        False, help="Accept a file whose publisher gives no SHA-256 (its hash is logged)."
    ),
    force: bool = typer.Option(False, help="Download again even when already pulled."),
    retries: int = typer.Option(3, min=0, help="Resumed attempts after a broken connection."),
) -> None:
    """Download published weights into the cache, resuming a broken download, SHA-256 checked."""
    from jointseg.network.published import pull

    with progress_bar() as progress:
        path = pull(name, progress=progress, retries=retries, unverified=unverified, force=force)
    typer.echo(f"{name}: {path}; use it with --weights {name}", err=True)


@models_app.command("import")
def import_weights(
    source: ImportSource = typer.Argument(..., help="Where the checkpoint comes from."),
    file: Path = typer.Argument(..., help="The checkpoint file."),
    output: Path = typer.Option(
        Path("randlanet_s3dis.pt"), "-o", "--output", help="jointseg checkpoint to write."
    ),
    allow_pickle: bool = typer.Option(
        False, help="Also read files holding Python objects (can run code stored in the file)."
    ),
) -> None:
    """Convert a checkpoint from another framework (Open3D-ML's RandLA-Net)."""
    from jointseg.network.convert import import_open3d_ml

    path = import_open3d_ml(file, output, allow_pickle=allow_pickle)
    typer.echo(f"wrote {path}; use it with --weights {path}", err=True)


@models_app.command("pack")
def pack_weights(
    source: Path = typer.Argument(..., help="A training checkpoint (jointseg train --out)."),
    output: Path = typer.Option(..., "-o", "--output", help="Checkpoint to ship."),
    half: bool = typer.Option(True, help="Store float16 weights (half the size)."),
    command: str | None = typer.Option(
        None, help="The training command, for a card written without one."
    ),
) -> None:
    """Strip optimiser state from a training checkpoint and store its weights compactly."""
    from jointseg.training.shipping import pack_checkpoint

    path = pack_checkpoint(source, output, half=half, command=command)
    typer.echo(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)", err=True)


@models_app.command("blend")
def blend_weights(
    base: Path = typer.Argument(..., help="The network before fine-tuning."),
    tuned: Path = typer.Argument(..., help="Its fine-tuned copy (same architecture)."),
    weight: float = typer.Option(..., min=0.0, max=1.0, help="Share of the tuned weights."),
    output: Path = typer.Option(..., "-o", "--output", help="Checkpoint to ship."),
) -> None:
    """Blend a network with its fine-tuned copy in weight space (packed like `models pack`)."""
    from jointseg.training.shipping import blend_checkpoints

    path = blend_checkpoints(base, tuned, weight, output)
    typer.echo(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)", err=True)


def register(app: typer.Typer) -> None:
    """Add this module's commands to ``app``."""
    app.command()(predict)
    app.command()(train)
    app.add_typer(models_app, name="models")
