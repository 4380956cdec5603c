"""The prepared GPU run: one command that, on a machine lent for a few minutes, trains the
colour network, the colour-free one and a smaller student distilled from the colour network,
at once, and leaves packed checkpoints where the lease hands files back.

A lent GPU machine has torch but not the rest of jointseg's dependencies, no ``../shared`` and a
15-minute budget, so everything is made here beforehand (``pack``): the training scans as
compact arrays (every real labelled scan of ``../shared/data`` but the judging ones, plus
synthetic rooms, which cannot be made there) and a manifest of where they came from. ``run``
then trains the three networks side by side on the one device, each within the minutes given,
writing ``NAME.pt`` (the latest, packed) every ``save_minutes`` and ``NAME.best.pt`` (the best
by validation) into the output folder, and at the end ``train.log`` and a ``summary.json`` of
the three: eight files, the most a lease hands back.

    python -m jointseg.training.prepared pack --shared ../shared/data --out .gpu/data
    python -m jointseg.training.pseudo_pack --shared ../shared/data --out .gpu/data
    python -m jointseg.training.prepared run --data .gpu/data --out $OUT --minutes 8

(The second line is optional: self-training on unlabelled scans the pipeline labelled.)

On a CPU, a crop bank (:mod:`jointseg.training.bank`) drawn once from the same data
keeps both cores on the steps: ``bank`` builds one, ``run --bank DIR`` trains from it.

    python -m jointseg.training.prepared bank --data .gpu/data --out runs/bank --crops 4000
    python -m jointseg.training.prepared run --only colour --device cpu --data .gpu/data \
        --out runs/cpu --bank runs/bank
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from fnmatch import fnmatch
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from jointseg.io.atomic import atomic_open
from jointseg.network.backends import WEIGHTS_DIR

if TYPE_CHECKING:
    from jointseg.training.config import TrainConfig

log = logging.getLogger(__name__)
MODULE = "jointseg.training.prepared"

COLOUR_WEIGHTS = WEIGHTS_DIR / "randlanet_indoor.pt"
NOCOLOUR_WEIGHTS = WEIGHTS_DIR / "randlanet_indoor_nocolour.pt"
#: The student's channel widths, as a share of the full network's.
STUDENT_CHANNELS = 0.5
#: Scans kept out of the carried data: the judging scans the networks are compared on.
JUDGING = ("scene0002_", "scene0007_")
#: Validation scans (one per source where present).
VALIDATION = ("area6_office_4", "scene0005_*", "synth_000")
#: Each source's share of the training crops (renormalised over the sources carried).
#: (Folders named as the datasets, so that the cards name the datasets' terms of use.)
#: ``pseudo``: unlabelled real scans labelled by the pipeline where it is sure
#: (:mod:`jointseg.training.pseudo_pack`; few scans, labels ~93 % right, so a small share).
SHARES = {"s3dis_area6": 0.5, "scannet": 0.35, "synth": 0.15, "pseudo": 0.15}
#: Coordinates are stored on a binary lattice (1/128 m) so that they compress well.
LATTICE = 128.0
#: What each network of the run starts from and how it learns.
RECIPE: dict[str, dict[str, object]] = {
    # fine-tuned: the batch norms keep the statistics learnt on whole crops, a gentle rate
    "colour": {"init": COLOUR_WEIGHTS, "lr": 0.0002, "freeze_norm": True},
    "nocolour": {"init": NOCOLOUR_WEIGHTS, "lr": 0.0002, "colour": False, "freeze_norm": True},
    "student": {
        "sliced_init": COLOUR_WEIGHTS,
        "teacher": COLOUR_WEIGHTS,
        "num_channels_scale": STUDENT_CHANNELS,
        "lr": 0.002,
    },
    # issue 65's campaign: the colour network fine-tuned with half its loss the bundled
    # network's softened outputs on the same crops, so what it knew is not traded away
    "colour_soft": {
        "init": COLOUR_WEIGHTS,
        "lr": 0.0002,
        "freeze_norm": True,
        "teacher": COLOUR_WEIGHTS,
        "distill_weight": 0.5,
    },
}
#: The networks a run trains unless told (the prepared GPU run: ``make gpu-train``).
DEFAULT_RUN = ("colour", "nocolour", "student")
#: Crops per step when training from a bank and the crops' size on a CPU: on the 2-core CPU 2 or
#: 4 crops a step trained the most points per second (1.57x and 1.52x today's one crop; 8:
#: 1.47x; docs/guide/training.md), and 4 trains 16 crops between validations where 2 trains 8.
BANK_BATCH = 4
#: The learning rate's decay per step: 0.97 per GPU epoch of 50 steps. Per epoch it was 0.97
#: whatever the epoch's length, so the CPU recipe's 4-step epochs had decayed it to 1e-6 of its
#: start within 500 epochs (25 minutes from a bank), and the rest of a run learnt nothing.
GAMMA_PER_STEP = 0.97 ** (1 / 50)
BANK_POINTS = 4_096


def write_arrays(xyz: np.ndarray, rgb: np.ndarray | None, labels: np.ndarray, path: Path) -> int:
    """One scan as a compressed ``.npz`` that :func:`jointseg.io.read_scan` reads: coordinates
    from the scan's lowest corner on the 1/128 m lattice, sorted (both compress well), colour
    as bytes, labels as int8. Returns the file's size."""
    q = np.round((xyz - xyz.min(axis=0)) * LATTICE).astype(np.int64)
    order = np.lexsort((q[:, 2], q[:, 1], q[:, 0]))
    arrays = {
        "xyz": (q[order] / LATTICE).astype(np.float32),
        "labels": np.asarray(labels)[order].astype(np.int8),
    }
    if rgb is not None:
        arrays["rgb"] = np.asarray(rgb)[order].astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path) as fh:  # a pack cut short leaves no half-written scan
        np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]
    return path.stat().st_size


def pack(out: Path, shared: Path | None, synth_rooms: int, synth_points: int) -> dict:
    """Write the carried training data under ``out`` (``s3dis_area6/``, ``scannet/``, ``synth/`` and
    ``manifest.json``); ``shared`` None packs synthetic rooms only (the test suite's run). A
    ``pseudo/`` folder already there (``pseudo_pack``) stays, with its manifest entry."""
    from jointseg.io import read_scan
    from jointseg.synth import make_room

    files: dict[str, list[str]] = {}
    total = 0
    folders = {"s3dis_area6": "s3dis_area6", "scannet": "scannet"}
    for name, folder in folders.items():
        if shared is None or not (shared / folder).is_dir():
            continue
        for path in sorted((shared / folder).glob("*.ply")):
            if path.stem.startswith(JUDGING):
                continue
            scan = read_scan(path)
            if scan.labels is None:
                raise SystemExit(f"{path}: no labels; the carried data must be labelled")
            total += write_arrays(scan.xyz, scan.rgb, scan.labels, out / name / f"{path.stem}.npz")
            files.setdefault(name, []).append(path.stem)
    for i in range(synth_rooms):
        room = make_room(9000 + i, points=synth_points)
        assert room.labels is not None  # synthetic rooms are labelled
        total += write_arrays(room.xyz, room.rgb, room.labels, out / "synth" / f"synth_{i:03d}.npz")
        files.setdefault("synth", []).append(f"synth_{i:03d} (seed {9000 + i})")
    manifest = {
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "shared": str(shared) if shared else None,
        "kept_out": [f"{p}*" for p in JUDGING],
        "synth_points": synth_points,
        "bytes": total,
        "scans": files,
        "terms": {name: source_terms(name) for name in files},
    }
    _keep_pseudo(out, manifest)
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    log.info(
        "packed %d scans, %.1f MiB, into %s", sum(map(len, files.values())), total / 2**20, out
    )
    return manifest


def source_terms(name: str) -> str:
    """The terms of use a packed source folder carries (as the model card names them)."""
    from jointseg.training.sources import SYNTH_TERMS, SourceSpec, terms_for

    return SYNTH_TERMS if name == "synth" else terms_for(SourceSpec(name, name, None))


def _keep_pseudo(out: Path, manifest: dict) -> None:
    """A pack written again keeps the ``pseudo/`` folder's entry (``pseudo_pack`` wrote it)."""
    old = _manifest(out)
    if (out / "pseudo").is_dir() and "pseudo" in old:
        manifest["scans"]["pseudo"] = old["scans"].get("pseudo", [])
        manifest["terms"]["pseudo"] = old["terms"]["pseudo"]
        manifest["pseudo"] = old["pseudo"]


@dataclass(frozen=True)
class RunOptions:
    """How a run trains: where, for how long, which networks."""

    data: Path
    out: Path
    minutes: float = 8.0
    device: str = "cpu"
    save_minutes: float = 2.0
    names: tuple[str, ...] = DEFAULT_RUN
    steps_per_epoch: int | None = None
    resume: bool = False
    alongside: int = 1  # networks training at once on this machine, which share its cores
    bank: Path | None = None  # train from this crop bank

    @property
    def gpu(self) -> bool:
        return self.device.startswith("cuda")


def train_config(name: str, opts: RunOptions) -> TrainConfig:
    """The :class:`~jointseg.training.config.TrainConfig` of one network of the run: the
    packed checkpoints in ``opts.out``, the full ones (with optimiser state) in
    :func:`work_dir`, from which ``opts.resume`` continues."""
    from jointseg.training.config import TrainConfig

    work = work_dir(opts.out)
    full = work / f"{name}.pt"
    recipe = dict(RECIPE[name])
    resume = full if opts.resume and full.is_file() else None
    if resume is not None:  # the run's own weights and optimiser, not the recipe's start
        for key in ("init", "sliced_init"):
            recipe.pop(key, None)
    cores = len(os.sched_getaffinity(0))
    steps = opts.steps_per_epoch or (50 if opts.gpu else 4)
    batches: dict[str, object] = {
        "batch_size": 4 if opts.gpu else 1,
        "num_points": 16_384 if opts.gpu else 4_096,
        "workers": max(1, (cores - 2) // opts.alongside) if opts.gpu else 0,
    }
    if opts.bank is not None:
        from jointseg.training.bank import read_manifest

        manifest = read_manifest(opts.bank)
        if manifest is None:
            raise SystemExit(f"{opts.bank}: no crop bank; build one with 'bank' first")
        batches = {"batch_size": BANK_BATCH, "num_points": manifest.spec.num_points,
                   "workers": 0, "bank": opts.bank}  # fmt: skip
    return TrainConfig(
        **data_fields(opts.data),
        out=full,
        resume=resume,
        packed_copy=opts.out / f"{name}.pt",
        epochs=10_000,
        steps_per_epoch=steps,
        **batches,  # type: ignore[arg-type]
        gamma=GAMMA_PER_STEP**steps,
        device=opts.device,
        threads=None if opts.gpu else max(1, cores // opts.alongside),
        minutes=opts.minutes,
        save_minutes=opts.save_minutes,
        seed=list(RECIPE).index(name),
        command=" ".join([Path(sys.executable).name, "-m", MODULE, *sys.argv[1:]]),
        **recipe,  # type: ignore[arg-type]
    )


def data_fields(data: Path) -> dict[str, object]:
    """The sources of the carried data with their shares, validation and judging scans."""
    present = [s for s in SHARES if (data / s).is_dir()]
    if not present:
        raise SystemExit(f"{data}: no s3dis_area6/, scannet/ or synth/ folder; run 'pack' first")
    total = sum(SHARES[s] for s in present)
    return {
        "data": [f"{s}={data / s}:{SHARES[s] / total:.4f}" for s in present],
        "val_scans": [
            v for v in VALIDATION if any(fnmatch(p.stem, v) for p in data.rglob("*.npz"))
        ],
        "exclude_scans": [f"{p}*" for p in JUDGING],
    }


def build(data: Path, out: Path, crops: int, *, gb: float, workers: int, num_points: int) -> dict:
    """Build (or extend) a crop bank of the carried data, with the colour network's
    augmentation and colour (it serves the colour-free network too, its colour held at zero)."""
    from jointseg.training.bank import build_bank
    from jointseg.training.config import TrainConfig

    cfg = TrainConfig(**data_fields(data), out=out / "unused.pt", num_points=num_points)  # type: ignore[arg-type]
    manifest = build_bank(cfg, out, crops, max_bytes=int(gb * 1e9), workers=workers)
    rate = manifest.crops / max(manifest.build_seconds, 1e-9)
    log.info("crop bank %s: %d crops, %.2f GB, %.2f crops/s with %d workers", out,
             manifest.crops, manifest.bytes / 1e9, rate, manifest.build_workers)  # fmt: skip
    return manifest.model_dump(mode="json")


def run(opts: RunOptions) -> int:
    """Train the networks side by side, each in a process of its own; 0 when each wrote a
    checkpoint. Each stops stepping a little before ``opts.minutes`` so that its last
    validation and checkpoint land in time."""
    out = opts.out
    out.mkdir(parents=True, exist_ok=True)
    margin = 0.75 if opts.gpu else 0.35
    started = time.monotonic()
    work = work_dir(out)
    procs = {}
    for name in opts.names:
        cmd = [sys.executable, "-m", MODULE, "one", name, "--data", str(opts.data),
               "--out", str(out), "--minutes", f"{max(opts.minutes - margin, 0.1):.3f}",
               "--device", opts.device, "--save-minutes", str(opts.save_minutes),
               "--alongside", str(len(opts.names))]  # fmt: skip
        if opts.steps_per_epoch:
            cmd += ["--steps", str(opts.steps_per_epoch)]
        if opts.resume:
            cmd.append("--resume")
        if opts.bank is not None:
            cmd += ["--bank", str(opts.bank)]
        logfile = (work / f"{name}.log").open("a" if opts.resume else "w")
        procs[name] = (subprocess.Popen(cmd, stdout=logfile, stderr=subprocess.STDOUT), logfile)
    codes = {}
    for name, (proc, logfile) in procs.items():
        codes[name] = proc.wait()
        logfile.close()
    networks = {name: _summary(out, name, codes[name]) for name in opts.names}
    logs = [f"== {n}\n" + (work / f"{n}.log").read_text() for n in opts.names]
    (out / "train.log").write_text("\n".join(logs))
    summary = {"device": opts.device, "minutes": opts.minutes,
               "seconds": time.monotonic() - started, "data": _manifest(opts.data),
               "networks": networks}  # fmt: skip
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    log.info("summary: %s", json.dumps(networks))
    return 0 if all(c == 0 and (out / f"{n}.pt").is_file() for n, c in codes.items()) else 1


def work_dir(out: Path) -> Path:
    """Where the full checkpoints (with optimiser state, for ``jointseg train --resume``) and
    each network's log go: ``$JOINTSEG_GPU_WORK`` or ``runs/gpu_work``, not ``out`` (a lease
    hands back at most eight files from its output folder: six packed checkpoints, the log and
    the summary)."""
    work = Path(os.environ.get("JOINTSEG_GPU_WORK", "runs/gpu_work")) / out.name
    work.mkdir(parents=True, exist_ok=True)
    return work


def _manifest(data: Path) -> dict:
    path = data / "manifest.json"
    return json.loads(path.read_text()) if path.is_file() else {}


def _summary(out: Path, name: str, code: int) -> dict:
    """What one network reached: its exit code, epochs, steps and validation."""
    from jointseg.network.randlanet.checkpoint import load_checkpoint

    entry: dict[str, object] = {"exit_code": code}
    path = out / f"{name}.pt"
    if path.is_file():
        model, card, _ = load_checkpoint(path)
        entry.update(
            epochs=card.get("epochs"),
            steps=card.get("steps"),
            validation=card.get("validation"),
            parameters=sum(p.numel() for p in model.parameters()),
            hardware=card.get("hardware"),
        )
    return entry


def main(argv: list[str] | None = None) -> int:
    """``pack``, ``run`` or ``one`` from the command line; the exit status."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    sub = ap.add_subparsers(dest="what", required=True)
    p = sub.add_parser("pack", help="write the carried training data")
    p.add_argument("--shared", type=Path, default=None, help="../shared/data (omit: synth only)")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--synth-rooms", type=int, default=4)
    p.add_argument("--synth-points", type=int, default=150_000)
    b = sub.add_parser("bank", help="build or extend a crop bank of the carried data")
    b.add_argument("--data", type=Path, required=True)
    b.add_argument("--out", type=Path, required=True, help="the bank's folder")
    b.add_argument("--crops", type=int, required=True, help="crops the bank holds at the end")
    b.add_argument("--bank-gb", type=float, default=4.0, help="bound on the bank's size (GB)")
    b.add_argument("--workers", type=int, default=len(os.sched_getaffinity(0)))
    b.add_argument("--num-points", type=int, default=BANK_POINTS)
    for what in ("run", "one"):
        r = sub.add_parser(what, help="train the networks" if what == "run" else "one of them")
        if what == "one":
            r.add_argument("name", choices=list(RECIPE))
        else:
            r.add_argument("--only", nargs="+", choices=list(RECIPE), default=list(DEFAULT_RUN))
        r.add_argument("--data", type=Path, required=True)
        r.add_argument("--out", type=Path, required=True)
        r.add_argument("--minutes", type=float, default=8.0)
        r.add_argument("--device", default=None, help="default: cuda when present")
        r.add_argument("--save-minutes", type=float, default=2.0)
        r.add_argument("--steps", type=int, default=None, help="steps per epoch")
        r.add_argument("--resume", action="store_true", help="continue the work folder's runs")
        r.add_argument("--bank", type=Path, default=None, help="train from this crop bank")
        if what == "one":
            r.add_argument("--alongside", type=int, default=1, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    if args.what == "pack":
        pack(args.out, args.shared, args.synth_rooms, args.synth_points)
        return 0
    if args.what == "bank":
        build(args.data, args.out, args.crops, gb=args.bank_gb, workers=args.workers,
              num_points=args.num_points)  # fmt: skip
        return 0
    import torch

    names = (args.name,) if args.what == "one" else tuple(args.only)
    opts = RunOptions(
        data=args.data,
        out=args.out,
        minutes=args.minutes,
        device=args.device or ("cuda" if torch.cuda.is_available() else "cpu"),
        save_minutes=args.save_minutes,
        names=names,
        steps_per_epoch=args.steps,
        resume=args.resume,
        alongside=getattr(args, "alongside", len(names)),
        bank=args.bank,
    )
    if args.what == "one":
        from jointseg.training.loop import train

        train(train_config(args.name, opts))
        return 0
    return run(opts)


if __name__ == "__main__":
    sys.exit(main())
