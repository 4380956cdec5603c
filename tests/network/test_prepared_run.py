"""The prepared GPU run (issue 42): the whole command, as a lent machine runs it, for half a
minute on this CPU; and the pieces it adds to the trainer (time budget, timed and packed
checkpoints, distillation, a narrow network started from a wide one)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from jointseg.io import read_scan
from jointseg.network.randlanet.checkpoint import load_checkpoint
from jointseg.network.randlanet.knn import layer_indices
from jointseg.network.randlanet.model import RandLANet
from jointseg.network.randlanet.slicing import channel_maps, sliced_init
from jointseg.training.config import model_config
from jointseg.training.loop import train
from jointseg.training.prepared import (
    COLOUR_WEIGHTS,
    DEFAULT_RUN,
    LATTICE,
    RunOptions,
    pack,
    train_config,
    write_arrays,
)
from jointseg.training.step import distillation_loss

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def carried(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Carried data as ``make gpu-pack`` writes it, synthetic rooms only."""
    data = tmp_path_factory.mktemp("gpu") / "data"
    pack(data, None, synth_rooms=2, synth_points=40_000)
    return data


@pytest.mark.slow
def test_the_half_minute_run_leaves_eight_files_and_three_networks(carried: Path, tmp_path) -> None:
    out = tmp_path / "out"
    env = {**os.environ, "PYTHON": sys.executable, "GPU_DATA": str(carried), "OUT": str(out),
           "SAVE_MINUTES": "0.2", "JOINTSEG_GPU_WORK": str(tmp_path / "work")}  # fmt: skip
    started = time.monotonic()
    done = subprocess.run(
        ["bash", "scripts/gpu_train.sh", "0.5"], cwd=ROOT, env=env, capture_output=True, text=True
    )
    seconds = time.monotonic() - started
    assert done.returncode == 0, done.stderr[-2000:]
    assert seconds < 60, f"a half-minute run took {seconds:.0f} s"
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(
        [f"{n}{s}.pt" for n in DEFAULT_RUN for s in ("", ".best")] + ["summary.json", "train.log"]
    )
    summary = json.loads((out / "summary.json").read_text())
    nets = summary["networks"]
    assert all(nets[n]["exit_code"] == 0 and nets[n]["steps"] > 0 for n in DEFAULT_RUN)
    assert nets["student"]["parameters"] < nets["colour"]["parameters"] / 3
    assert summary["data"]["scans"]["synth"][0].startswith("synth_000")
    for name in DEFAULT_RUN:
        model, card, body = load_checkpoint(out / f"{name}.pt")
        assert card["weights_dtype"] == "float16" and "optimizer" not in body
        assert card["train_config"]["minutes"] < 0.5 and card["colour"] == (name != "nocolour")
        assert "no GPU" in card["hardware"]
    student_card = load_checkpoint(out / "student.pt")[1]
    assert student_card["train_config"]["teacher"].endswith("randlanet_indoor.pt")
    # the full checkpoints, with optimiser state for --resume, stay out of the output folder
    assert "optimizer" in torch.load(tmp_path / "work" / "out" / "colour.pt", weights_only=False)


def test_the_run_refuses_to_start_without_carried_data(tmp_path) -> None:
    env = {**os.environ, "PYTHON": sys.executable, "GPU_DATA": str(tmp_path / "none"),
           "OUT": str(tmp_path / "out")}  # fmt: skip
    done = subprocess.run(
        ["bash", "scripts/gpu_train.sh", "1"], cwd=ROOT, env=env, capture_output=True, text=True
    )
    assert done.returncode == 2
    assert "make gpu-pack" in done.stderr and len(done.stderr.strip().splitlines()) == 1


def test_packed_arrays_read_back_on_the_lattice(tmp_path) -> None:
    rng = np.random.default_rng(0)
    xyz = rng.uniform(-3, 5, (5000, 3))
    rgb = rng.integers(0, 256, (5000, 3))
    labels = rng.integers(-1, 13, 5000)
    write_arrays(xyz, rgb, labels, tmp_path / "a.npz")
    scan = read_scan(tmp_path / "a.npz")
    order = np.lexsort(np.round((xyz - xyz.min(0)) * LATTICE).T[::-1])
    assert np.abs(scan.xyz - (xyz - xyz.min(0))[order]).max() <= 0.5 / LATTICE + 1e-6
    assert (scan.labels == labels[order]).all() and (scan.rgb == rgb[order]).all()


@pytest.mark.slow
def test_a_time_budget_stops_a_long_run_and_saves_it(tiny_training, tmp_path) -> None:
    cfg = tiny_training(epochs=10_000, steps_per_epoch=3, minutes=0.08, save_minutes=0.02,
                        packed_copy=tmp_path / "packed.pt")  # fmt: skip
    started = time.monotonic()
    train(cfg)
    assert time.monotonic() - started < 40
    _, card, body = load_checkpoint(cfg.out)
    assert 0 < card["epochs"] < 10_000 and "optimizer" in body
    assert load_checkpoint(tmp_path / "packed.pt")[1]["epochs"] == card["epochs"]


def test_distillation_loss_is_zero_only_when_the_student_agrees() -> None:
    rng = torch.Generator().manual_seed(0)
    teacher = torch.randn(2, 50, 13, generator=rng)
    assert float(distillation_loss(teacher, teacher, 2.0)) == pytest.approx(0.0, abs=1e-6)
    assert float(distillation_loss(torch.randn(2, 50, 13, generator=rng), teacher, 2.0)) > 0.1


def _zero_outside(wide: RandLANet, narrow: RandLANet) -> None:
    """Zero every weight of ``wide`` on a channel the narrow copy leaves out: the wide network
    then carries nothing on those channels, and a right slicing computes the same logits."""
    state = wide.state_dict()
    for name, small in narrow.state_dict().items():
        if small.dim() == 0 or name.endswith(("running_mean", "running_var")):
            continue
        keep = torch.zeros_like(state[name], dtype=torch.bool)
        index = channel_maps(name, tuple(small.shape), wide.config, narrow.config)
        keep[torch.meshgrid(*index, indexing="ij")] = True
        state[name] = torch.where(keep, state[name], torch.zeros_like(state[name]))
    wide.load_state_dict(state)


@pytest.mark.slow
def test_a_sliced_narrow_network_computes_what_the_wide_one_does_on_its_channels(
    tiny_training,
) -> None:
    wide, _, _ = load_checkpoint(COLOUR_WEIGHTS)
    narrow = RandLANet(model_config(tiny_training(num_channels_scale=0.5)))
    _zero_outside(wide, narrow)
    sliced_init(narrow, wide)
    wide.eval(), narrow.eval()
    gen = torch.Generator().manual_seed(0)
    xyz = torch.rand(1, 2048, 3, generator=gen) * 3
    features = torch.cat([xyz, torch.rand(1, 2048, 3, generator=gen)], dim=2)
    indices = layer_indices(xyz, wide.config)
    with torch.no_grad():
        expected, got = wide(features, *indices), narrow(features, *indices)
    assert expected.abs().max() > 0.1  # the zeroed network still says something
    torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-4)
    with pytest.raises(Exception, match="wider in the student"):
        sliced_init(wide, narrow)


def test_a_leading_block_copy_would_not_do(tiny_training) -> None:
    """The decoder reads a skip beside the upsampled features: the narrow network's second part
    sits at the wide one's offset, not right after its own first part."""
    wide = RandLANet(model_config(tiny_training()))
    narrow = RandLANet(model_config(tiny_training(num_channels_scale=0.5)))
    index = channel_maps("decoder.0.conv.weight", (1, 768, 1, 1), wide.config, narrow.config)[1]
    assert index[:256].tolist() == list(range(256))
    assert index[256:].tolist() == list(range(512, 1024))


def test_a_resumed_run_continues_its_own_weights_not_the_recipes_start(
    carried: Path, tmp_path, monkeypatch
) -> None:
    monkeypatch.setenv("JOINTSEG_GPU_WORK", str(tmp_path / "work"))
    opts = RunOptions(data=carried, out=tmp_path / "out", resume=True, alongside=3)
    fresh = train_config("student", opts)
    assert fresh.resume is None and fresh.sliced_init == COLOUR_WEIGHTS
    assert fresh.teacher == COLOUR_WEIGHTS and fresh.num_channels_scale == 0.5
    fresh.out.write_bytes(b"a checkpoint")  # what an earlier run left in the work folder
    again = train_config("student", opts)
    assert again.resume == fresh.out and again.sliced_init is None and again.init is None
    assert again.teacher == COLOUR_WEIGHTS  # still distilled
    assert train_config("student", replace(opts, resume=False)).resume is None
    # on a CPU the three networks share the cores; on a GPU each gets a share of batch workers
    assert fresh.threads == max(1, len(os.sched_getaffinity(0)) // 3) and fresh.workers == 0


@pytest.mark.slow
@pytest.mark.parametrize("frozen", [True, False])
def test_frozen_norms_keep_their_statistics_while_the_weights_learn(tiny_training, frozen) -> None:
    cfg = tiny_training(init=COLOUR_WEIGHTS, freeze_norm=frozen, lr=0.001)
    start = load_checkpoint(COLOUR_WEIGHTS)[0].state_dict()
    train(cfg)
    after = load_checkpoint(cfg.out)[0].state_dict()
    stats = [k for k in start if k.endswith(("running_mean", "running_var"))]
    weights = [k for k in start if k.endswith("conv.weight")]
    assert any(not torch.equal(start[k], after[k]) for k in weights)
    kept = all(torch.equal(start[k], after[k]) for k in stats)
    assert kept == frozen


def test_the_carried_folders_name_their_datasets_terms(tmp_path: Path) -> None:
    """The cards of the run's checkpoints name S3DIS's and ScanNet's terms of use: the carried
    folders are named as the datasets (a folder called 'a6' read as user data)."""
    from jointseg.training.sources import (
        S3DIS_TERMS,
        SCANNET_TERMS,
        parse_source,
        terms_for,
    )

    rng = np.random.default_rng(0)
    for folder in ("s3dis_area6", "scannet"):
        xyz = rng.uniform(0, 3, (500, 3))
        write_arrays(xyz, None, np.zeros(500, np.int64), tmp_path / folder / "room.npz")
    cfg = train_config("colour", RunOptions(data=tmp_path, out=tmp_path / "out"))
    terms = {terms_for(parse_source(spec)) for spec in cfg.data}
    assert terms == {S3DIS_TERMS, SCANNET_TERMS}


def test_the_learning_rate_decays_per_step_alike_on_the_cpu_and_the_gpu(tmp_path: Path) -> None:
    """The CPU recipe's epochs are 4 steps, the GPU's 50: at 0.97 an epoch either way, a CPU
    run's rate fell to a millionth of its start in 500 epochs (25 minutes) and it learnt no
    more. The decay is per step now: after 1 000 steps both are where the GPU's always was."""
    rng = np.random.default_rng(0)
    write_arrays(rng.uniform(0, 3, (500, 3)), None, np.zeros(500, np.int64),
                 tmp_path / "s3dis_area6" / "room.npz")  # fmt: skip
    after = {}
    for device in ("cpu", "cuda"):
        cfg = train_config(
            "colour", RunOptions(data=tmp_path, out=tmp_path / device, device=device)
        )
        after[device] = cfg.gamma ** (1000 / cfg.steps_per_epoch)
    assert after["cpu"] == pytest.approx(0.97**20, rel=1e-9)
    assert after["cuda"] == pytest.approx(0.97**20, rel=1e-9)
