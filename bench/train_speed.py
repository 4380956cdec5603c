"""Training speed: batches per second from worker processes, whole training steps per second,
and points trained per second from a crop bank.

Two tables, both measured in this one process against a baseline from the same run:

1. **Batch building** (the data side alone: draw crops from the sources, density and cut
   augmentation, grid sub-sampling, rotation, colour, and the five layers' KD-tree searches):
   batches per second with 1, 2, ... worker processes, the consumer doing nothing else.
2. **Training steps** (batches + forward, loss, backward, Adam): steps per second of the
   trainer as it was before workers (batches built a step ahead in one thread of the training
   process, neighbours searched on the CPU) against workers (and, on a GPU, neighbour searches
   on the device), with the GPU's utilisation sampled from ``nvidia-smi`` while the steps run.

Default data: the real S3DIS Area_6 and ScanNet scans when ../shared holds them, with synthetic
rooms; else synthetic rooms only.

``--points`` prints a third table instead (issue 65): **points trained per second** by today's
CPU recipe (the prepared run's colour network: one 4 096-point crop per step, built a step
ahead in a thread, two torch threads, fine-tuned from the bundled weights) against training
from a crop bank (``--bank-batch`` crops per step), each through the trainer's own stream and
step, in this one process; with the bank's build rate (crops/s by ``--bank-workers``
processes) and bytes per crop. Its data is a ``prepared pack`` folder (``--recipe-data``,
default ``.gpu/data``; synthetic rooms are packed when there is none).

    .venv/bin/python bench/train_speed.py [--workers 1 2] [--batch-size 2 --num-points 8192]
    .venv/bin/python bench/train_speed.py --device cuda --batch-size 4 --num-points 16384 \\
        --workers 4 8 12
    .venv/bin/python bench/train_speed.py --points --recipe-data .gpu/data --bank-crops 256
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import subprocess
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from helpers.inputs import AREA6, SCANNET
from helpers.report import header

from jointseg.network.randlanet.model import RandLANet, RandLANetConfig
from jointseg.training.batches import BatchMaker, batch_stream
from jointseg.training.config import TrainConfig, training_data
from jointseg.training.loop import train
from jointseg.training.run_state import TrainingRun, start_run
from jointseg.training.step import device_batch, train_mode, train_step
from jointseg.training.streams import bank_stream, crop_stream


def default_data() -> list[str]:
    if AREA6.is_dir() and SCANNET.is_dir():
        return [f"a6={AREA6}:0.45", f"scannet={SCANNET}:0.4", "synth:0.15"]
    return ["synth"]


class GpuSampler:
    """GPU utilisation (%) sampled from nvidia-smi every half second while active."""

    def __init__(self) -> None:
        self.samples: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.5):
            out = subprocess.run(
                ["nvidia-smi", "--query-gpu=utilization.gpu", "--format=csv,noheader,nounits"],
                capture_output=True,
                text=True,
                check=False,
            )
            if out.returncode == 0 and out.stdout.strip():
                self.samples.append(float(out.stdout.split()[0]))

    def __enter__(self) -> GpuSampler:
        if shutil.which("nvidia-smi"):
            self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def mean(self) -> str:
        return f"{np.mean(self.samples):.0f} %" if self.samples else "n/a"


def batch_rate(maker: BatchMaker, workers: int, warmup: int) -> float:
    """Batches per second from ``workers`` processes (0: built in this process, no thread)."""
    with batch_stream(maker, workers=workers, prefetch=False, pin=False) as batches:
        for i, _ in enumerate(batches):
            if i == warmup - 1:
                started = time.perf_counter()
        return (len(maker) - warmup) / (time.perf_counter() - started)


def step_rate(
    maker: BatchMaker, run: TrainingRun, workers: int, on_device: bool, warmup: int
) -> tuple[float, str]:
    """Training steps per second (and mean GPU utilisation) with the given batch source."""
    maker.neighbours_on_device = on_device
    loss_fn = torch.nn.CrossEntropyLoss(ignore_index=-1)
    pin = run.device.type == "cuda"
    stream = batch_stream(maker, workers=workers, prefetch=True, pin=pin)
    with stream as batches, GpuSampler() as gpu:
        for i, item in enumerate(batches):
            if i == warmup:
                if pin:
                    torch.cuda.synchronize()
                started = time.perf_counter()
                gpu.samples.clear()
            batch = device_batch(item, run)
            logits = run.model(
                batch.features, batch.coords, batch.neighbours, batch.pools, batch.upsamples
            )
            assert batch.labels is not None
            loss = loss_fn(logits.reshape(-1, logits.shape[-1]), batch.labels.reshape(-1))
            run.optimiser.zero_grad()
            loss.backward()
            run.optimiser.step()
        if pin:
            torch.cuda.synchronize()
        return (len(maker) - warmup) / (time.perf_counter() - started), gpu.mean()


def points_rate(cfg: TrainConfig, steps: int, warmup: int) -> tuple[float, float]:
    """Points trained per second (the crops' points as they came, a crop cut smaller than
    ``num_points`` counted as it is) and steps per second of ``cfg``'s run, by the trainer's own
    batch stream and step (validation left out)."""
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    run = start_run(cfg)
    data = training_data(cfg, run.model.config.grid_size)
    cfg = cfg.model_copy(update={"epochs": 1, "steps_per_epoch": steps + warmup})
    stream = bank_stream(cfg, run, data) if cfg.bank else crop_stream(cfg, run, data)
    loss_fn = torch.nn.CrossEntropyLoss(weight=data.loss_weights, ignore_index=-1)
    train_mode(run.model, cfg)
    points = 0
    with stream as batches:
        for i in range(steps + warmup):
            if i == warmup:
                started = time.perf_counter()
            batch = device_batch(next(batches), run)
            train_step(run, loss_fn, batch, cfg)
            points += batch.features.shape[0] * batch.features.shape[1] if i >= warmup else 0
    seconds = time.perf_counter() - started
    return points / seconds, steps / seconds


def points_run(cfg: TrainConfig, minutes: float) -> tuple[float, int]:
    """Points trained per wall-clock second of a whole run of ``minutes`` through
    :func:`train` (validation every epoch and checkpoints included, from its first step), and
    its steps: crops counted at ``num_points``."""
    steps: list[float] = []

    def progress(stage: str, fraction: float) -> None:
        if fraction > 0:
            steps.append(time.perf_counter())

    train(cfg.model_copy(update={"minutes": minutes}), progress=progress)
    ended = time.perf_counter()
    return len(steps) * cfg.batch_size * cfg.num_points / (ended - steps[0]), len(steps)


def points_table(args: argparse.Namespace) -> None:
    """Today's CPU recipe against training from a crop bank, points trained per second."""
    from jointseg.training import prepared
    from jointseg.training.bank import SHARD_CROPS

    scratch = Path(tempfile.mkdtemp(prefix="train-speed-"))
    os.environ["JOINTSEG_GPU_WORK"] = str(scratch / "work")
    data = args.recipe_data
    if not (data / "manifest.json").is_file():
        data = scratch / "data"
        prepared.pack(data, None, synth_rooms=4, synth_points=150_000)
    print(f"# points trained per second, {len(os.sched_getaffinity(0))} cores, "
          f"torch {torch.__version__}, data {data}, {time.strftime('%F %H:%M')}")  # fmt: skip
    print("\n## crop bank build\n")
    print("| workers | crops | crops/s | bytes per crop | bank size |")
    print("|---|---|---|---|---|")
    bank = scratch / "bank"
    for workers in args.bank_workers:
        folder = scratch / f"bank{workers}"
        count = args.bank_crops if workers == args.bank_workers[-1] else SHARD_CROPS * workers
        manifest = prepared.build(
            data, folder, count, gb=args.bank_gb, workers=workers, num_points=prepared.BANK_POINTS
        )
        rate = manifest["crops"] / manifest["build_seconds"]
        per = manifest["bytes"] / manifest["crops"]
        print(f"| {workers} | {manifest['crops']} | {rate:.2f} | {per / 1e3:.0f} kB "
              f"| {manifest['bytes'] / 1e6:.0f} MB |")  # fmt: skip
        bank = folder
    opts = prepared.RunOptions(data=data, out=scratch / "out", device="cpu", names=("colour",))
    opts.out.mkdir()
    today = prepared.train_config("colour", opts)
    print(f"\n## training steps ({today.threads} torch threads)\n")
    print("| recipe | crops x points per step | steps/s | points/s | vs today |")
    print("|---|---|---|---|---|")
    base, steps = points_rate(today, args.recipe_steps, args.warmup)
    shape = f"{today.batch_size} x {today.num_points}"
    print(f"| today: prepared CPU recipe, crops built a step ahead in a thread | {shape} "
          f"| {steps:.2f} | {base:.0f} | 1.00x |")  # fmt: skip
    for size in args.bank_batch:
        with_bank = prepared.train_config("colour", replace(opts, bank=bank))
        with_bank = with_bank.model_copy(update={"batch_size": size})
        rate, steps = points_rate(with_bank, max(8, args.recipe_steps // size), args.warmup)
        print(f"| crop bank ({bank.name}), read a step ahead in a thread "
              f"| {size} x {with_bank.num_points} | {steps:.2f} | {rate:.0f} "
              f"| {rate / base:.2f}x |")  # fmt: skip
    if not args.run_minutes:
        return
    print(
        f"\n## whole runs of {args.run_minutes} minutes (prepared 'one colour': validation "
        f"every {today.steps_per_epoch} steps, checkpoints every {today.save_minutes} min)\n"
    )
    print("| recipe | crops x points per step | steps | points/s | vs today |")
    print("|---|---|---|---|---|")
    base, count = points_run(today, args.run_minutes)
    print(f"| today | {shape} | {count} | {base:.0f} | 1.00x |")
    with_bank = prepared.train_config("colour", replace(opts, bank=bank))
    rate, count = points_run(with_bank, args.run_minutes)
    print(f"| crop bank | {with_bank.batch_size} x {with_bank.num_points} | {count} | {rate:.0f} "
          f"| {rate / base:.2f}x |")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", action="append", default=None)
    parser.add_argument("--batches", type=int, default=40, help="batches per worker setting")
    parser.add_argument("--steps", type=int, default=20, help="training steps per setting")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--batch-size", type=int, default=2)
    parser.add_argument("--num-points", type=int, default=8192)
    parser.add_argument("--threads", type=int, default=1, help="torch threads for the steps")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--skip-steps", action="store_true", help="only the batch table")
    parser.add_argument("--points", action="store_true", help="only the points/s table")
    parser.add_argument("--recipe-data", type=Path, default=Path(".gpu/data"))
    parser.add_argument("--recipe-steps", type=int, default=40, help="today's recipe's steps")
    parser.add_argument("--bank-crops", type=int, default=256)
    parser.add_argument("--bank-gb", type=float, default=2.0)
    parser.add_argument("--bank-workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--bank-batch", type=int, nargs="+", default=[4, 8])
    parser.add_argument("--run-minutes", type=float, default=2.0, help="0: no whole runs")
    args = parser.parse_args()
    header()
    logging.basicConfig(level=logging.WARNING)
    if args.points:
        points_table(args)
        return
    torch.set_num_threads(args.threads)
    cfg = TrainConfig(
        data=args.data or default_data(),
        out=Path("unused.pt"),
        num_points=args.num_points,
        batch_size=args.batch_size,
        synth_rooms=8,
        synth_floors=1,
        val_rooms=0,
    )
    model_cfg = RandLANetConfig(num_points=args.num_points)
    data = training_data(cfg, model_cfg.grid_size)
    maker = BatchMaker(
        data.clouds,
        data.draw_p,
        data.centre_p,
        model_cfg,
        cfg.augmentation(),
        batch_size=args.batch_size,
        num_points=args.num_points,
        seed=0,
        count=args.batches + args.warmup,
    )
    gpu_name = torch.cuda.get_device_name() if args.device == "cuda" else "no GPU"
    print(f"# training speed, {args.batch_size} x {args.num_points} points per batch, ")
    print(f"# {len(os.sched_getaffinity(0))} cores, {gpu_name}, torch {torch.__version__}, ")
    print(f"# sources: {', '.join(f'{s.spec.name} {s.share:.0%}' for s in data.sources)}, ")
    print(f"# {time.strftime('%F %H:%M')}")
    print("\n## batch building (no network)\n")
    print("| workers | batches/s | vs 1 worker |")
    print("|---|---|---|")
    rates = {w: batch_rate(maker, w, args.warmup) for w in args.workers}
    first = rates[args.workers[0]]
    for w, rate in rates.items():
        print(f"| {w} | {rate:.2f} | {rate / first:.2f}x |")
    if args.skip_steps:
        return
    device = torch.device(args.device)
    model = RandLANet(model_cfg).to(device)
    run = TrainingRun(model, device, torch.optim.Adam(model.parameters(), lr=1e-4), None, 0, [])  # type: ignore[arg-type]
    maker.count = args.steps + args.warmup
    print(f"\n## training steps on {args.device} (torch threads {args.threads})\n")
    print("| batches | steps/s | vs before | GPU utilisation |")
    print("|---|---|---|---|")
    base, util = step_rate(maker, run, 0, False, args.warmup)
    print(
        f"| before: one thread in the training process, CPU KD-trees | {base:.2f} | 1.00x "
        f"| {util} |"
    )
    settings = [(w, False) for w in args.workers]
    if device.type == "cuda":
        settings += [(w, True) for w in args.workers]
    for w, on_device in settings:
        rate, util = step_rate(maker, run, w, on_device, args.warmup)
        where = "device knn" if on_device else "CPU KD-trees"
        print(f"| {w} workers, {where} | {rate:.2f} | {rate / base:.2f}x | {util} |")


if __name__ == "__main__":
    main()
