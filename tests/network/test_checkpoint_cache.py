"""Packed weights unpacked into the cache once and memory-mapped after: the same network bit for
bit, a stale or broken copy replaced, a cache that cannot be written only slower."""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path

import numpy as np
import pytest
import torch

from jointseg.network.randlanet import checkpoint
from jointseg.network.randlanet.checkpoint import load_checkpoint, save_checkpoint, unpacked_path
from jointseg.network.randlanet.model import RandLANet, RandLANetConfig
from jointseg.network.randlanet.predict import load_randlanet
from jointseg.network.registry import REGISTRY
from jointseg.network.torch_files import read_torch_file
from jointseg.synth import make_room

CARD = {"data": "random initialisation (tests)", "history": [{"epoch": 1, "val_miou": 0.1}]}


def _packed(path: Path, seed: int = 0) -> Path:
    """A small random network written as ``models pack`` writes one: float16, gzip."""
    torch.manual_seed(seed)
    model = RandLANet(RandLANetConfig(num_points=4096))
    save_checkpoint(path, model, CARD, half=True, compress=True)
    return path


def _reference(path: Path) -> dict[str, torch.Tensor]:
    """The state the packed file holds, loaded as before the cache: read whole, floats made
    float32, copied into a model built on the CPU."""
    body = read_torch_file(path)
    model = RandLANet(RandLANetConfig(**body["config"]))
    state = {k: v.float() if v.is_floating_point() else v for k, v in body["state_dict"].items()}
    model.load_state_dict(state)
    return model.state_dict()


def _same_state(model: torch.nn.Module, reference: dict[str, torch.Tensor]) -> None:
    state = model.state_dict()
    assert list(state) == list(reference)
    for name, tensor in reference.items():
        got = state[name]
        assert got.dtype == tensor.dtype and got.shape == tensor.shape, name
        assert got.is_contiguous() and torch.equal(got, tensor), name


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "cache"
    monkeypatch.setenv("JOINTSEG_CACHE", str(folder))
    return folder


def _no_source_read(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the packed file was read although its copy is current")

    monkeypatch.setattr(checkpoint, "read_torch_file", refuse)


def test_the_copy_loads_the_same_network_and_spares_reading_the_packed_file(
    tmp_path: Path, cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _packed(tmp_path / "net.pt")
    reference = _reference(path)
    first, card, body = load_checkpoint(path)  # reads the packed file, writes the copy
    copy = unpacked_path(path)
    assert copy.is_file() and copy.parent == cache / "unpacked"
    _no_source_read(monkeypatch)
    second, card2, body2 = load_checkpoint(path)
    for model in (first, second):
        _same_state(model, reference)
        assert not model.training
        assert all(p.requires_grad and not p.is_meta for p in model.parameters())
    assert card == card2 and card2["history"] == CARD["history"] and card2["input_conventions"]
    assert set(body2) == set(body) == {"format", "config", "state_dict", "card"}
    assert body2["config"] == body["config"]


@pytest.mark.slow
def test_the_bundled_network_labels_the_same_from_its_copy(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The bundled weights: the same tensors and the same probabilities, to the bit, from the
    packed file and from the mapped copy."""
    bundled = REGISTRY["randlanet"].bundled
    if bundled is None or not bundled.is_file():
        pytest.skip("no bundled weights")
    scan = make_room(5, points=6_000)
    packed = load_randlanet(bundled, device="cpu", batch_size=1)
    assert unpacked_path(bundled).is_file()
    _no_source_read(monkeypatch)
    mapped = load_randlanet(bundled, device="cpu", batch_size=1)
    _same_state(mapped.model, _reference_of(packed.model))
    a, b = packed.predict(scan, seed=0), mapped.predict(scan, seed=0)
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_array_equal(a.probs, b.probs)


def _reference_of(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in model.state_dict().items()}


@pytest.mark.parametrize("damage", ["garbage", "truncated", "empty"])
def test_a_broken_copy_is_ignored_and_written_again(
    tmp_path: Path, cache: Path, damage: str, caplog: pytest.LogCaptureFixture
) -> None:
    path = _packed(tmp_path / "net.pt")
    reference = _reference(path)
    load_checkpoint(path)
    copy = unpacked_path(path)
    good = copy.read_bytes()
    broken = {"garbage": b"not a torch file" * 100, "truncated": good[: len(good) // 2]}
    copy.write_bytes(broken.get(damage, b""))
    with caplog.at_level(logging.INFO, logger="jointseg.network.randlanet.checkpoint"):
        model, _, _ = load_checkpoint(path)
    _same_state(model, reference)
    assert "ignored the unpacked copy" in caplog.text
    assert copy.stat().st_size == len(good)  # written again
    _same_state(load_checkpoint(path)[0], reference)


def test_changed_weights_are_unpacked_again(tmp_path: Path, cache: Path) -> None:
    path = _packed(tmp_path / "net.pt", seed=0)
    load_checkpoint(path)
    stat = path.stat()
    _packed(tmp_path / "other.pt", seed=1).replace(path)  # new weights, same name
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))  # even with the old time
    reference = _reference(path)
    _same_state(load_checkpoint(path)[0], reference)
    _same_state(load_checkpoint(path)[0], reference)  # from the new copy
    assert len(list((cache / "unpacked").iterdir())) == 1  # replaced, not added


def test_a_cache_that_cannot_be_written_still_loads(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("the cache folder cannot be made under a file")
    monkeypatch.setenv("JOINTSEG_CACHE", str(blocker / "cache"))
    path = _packed(tmp_path / "net.pt")
    with caplog.at_level(logging.INFO, logger="jointseg.network.randlanet.checkpoint"):
        model, card, _ = load_checkpoint(path)
    _same_state(model, _reference(path))
    assert card["data"] == CARD["data"]
    assert "could not keep an unpacked copy" in caplog.text


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes anyway")
def test_a_read_only_cache_folder_still_loads(tmp_path: Path, cache: Path) -> None:
    (cache / "unpacked").mkdir(parents=True)
    (cache / "unpacked").chmod(0o500)
    try:
        path = _packed(tmp_path / "net.pt")
        _same_state(load_checkpoint(path)[0], _reference(path))
        assert not unpacked_path(path).exists()
    finally:
        (cache / "unpacked").chmod(0o700)


def test_loads_at_the_same_time_leave_one_good_copy(tmp_path: Path, cache: Path) -> None:
    """Writers replace the copy at once (a temporary file renamed), so readers meanwhile see a
    whole copy or none."""
    path = _packed(tmp_path / "net.pt")
    reference = _reference(path)
    models: list[torch.nn.Module] = []
    errors: list[BaseException] = []

    def load() -> None:
        try:
            models.append(load_checkpoint(path)[0])
        except BaseException as exc:  # noqa: BLE001 - reported by the assertion below
            errors.append(exc)

    threads = [threading.Thread(target=load) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and len(models) == 4
    for model in models:
        _same_state(model, reference)
    assert [p.name for p in (cache / "unpacked").iterdir()] == [unpacked_path(path).name]
    _same_state(load_checkpoint(path)[0], reference)


def test_training_checkpoints_are_not_copied(tmp_path: Path, cache: Path) -> None:
    """A checkpoint with training state, or one stored float32 uncompressed, is read as it is:
    only packed weights are worth a copy."""
    torch.manual_seed(0)
    model = RandLANet(RandLANetConfig(num_points=4096))
    resumable, plain = tmp_path / "resume.pt", tmp_path / "plain.pt"
    save_checkpoint(resumable, model, CARD, extra={"epoch": 3}, half=True, compress=True)
    save_checkpoint(plain, model, CARD)
    loaded, _, body = load_checkpoint(resumable)
    _same_state(loaded, _reference(resumable))
    assert body["epoch"] == 3
    _same_state(load_checkpoint(plain)[0], model.state_dict())
    assert not (cache / "unpacked").exists()
