"""Training steps per second with and without the background batch builder, in one process.

A step is: draw crops, augment, five KD-tree searches per crop (the data side), then forward,
loss, backward and the optimiser (the network side). Runs the same steps twice on the same
rooms, once building each batch in the loop and once a step ahead in a thread
(`TrainConfig.prefetch`), and prints steps per second and the share of a plain step spent on
data. Default data: the real S3DIS Area_6 rooms when ../shared holds them, else synthetic rooms.

    .venv/bin/python bench/train_speed.py [--steps 20] [--threads 1] [--num-points 8192]
"""

from __future__ import annotations

import argparse
import logging
import os
import time
from pathlib import Path

import numpy as np
import torch

from jointseg.network.batches import Prefetcher, calls
from jointseg.network.checkpoint import load_checkpoint
from jointseg.network.registry import DEFAULT_WEIGHTS
from jointseg.network.train_data import centre_weights
from jointseg.network.training import TrainConfig, class_weights, draw_batch, load_clouds

AREA6 = Path(__file__).resolve().parents[2] / "shared" / "data" / "s3dis_area6"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--threads", type=int, default=max(1, len(os.sched_getaffinity(0)) - 1))
    parser.add_argument("--num-points", type=int, default=8192)
    parser.add_argument("--batch-size", type=int, default=2)
    parser.add_argument("--data", default=str(AREA6) if AREA6.is_dir() else "synth")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(args.threads)
    cfg = TrainConfig(
        data=args.data,
        out=Path("unused.pt"),
        num_points=args.num_points,
        batch_size=args.batch_size,
        synth_rooms=8,
        synth_floors=0,
    )
    model, _, _ = load_checkpoint(DEFAULT_WEIGHTS["randlanet"])
    clouds, draw_p, _, text = load_clouds(cfg, model.config.grid_size)
    weights = class_weights([c.labels for c in clouds if c.labels is not None])
    centre_p = [centre_weights(c.labels, weights.numpy()) for c in clouds]
    loss_fn = torch.nn.CrossEntropyLoss(weight=weights, ignore_index=-1)
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-4)
    model.train()
    print(f"# training speed, {text}; {args.batch_size} x {args.num_points} points per step,")
    print(f"# torch threads {args.threads}, {os.cpu_count()} cores, {time.strftime('%F')}")
    print()
    print("| batches | steps/s | s per step | data s per step |")
    print("|---|---|---|---|")
    rows = {}
    for mode in ("in the loop", "a step ahead (thread)"):
        rng = np.random.default_rng(0)
        spent = [0.0]

        def make(rng: np.random.Generator = rng, spent: list[float] = spent):
            t = time.perf_counter()
            batch = draw_batch(clouds, draw_p, centre_p, cfg, model.config, rng)
            spent[0] += time.perf_counter() - t
            return batch

        n = args.steps + args.warmup
        stream = Prefetcher(calls(make, n)) if "thread" in mode else calls(make, n)
        for i, batch in enumerate(stream):
            if i == args.warmup:
                started, spent[0] = time.perf_counter(), 0.0
            logits = model(
                batch.features, batch.coords, batch.neighbours, batch.pools, batch.upsamples
            )
            loss = loss_fn(logits.reshape(-1, logits.shape[-1]), batch.labels.reshape(-1))
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        seconds = (time.perf_counter() - started) / args.steps
        rows[mode] = seconds
        print(f"| {mode} | {1 / seconds:.2f} | {seconds:.3f} | {spent[0] / args.steps:.3f} |")
    speedup = rows["in the loop"] / rows["a step ahead (thread)"]
    print()
    print(f"**{speedup:.2f}x** steps per second with the batch built a step ahead")


if __name__ == "__main__":
    main()
