"""Open3D-ML's RandLA-Net weights give the same logits in jointseg's RandLA-Net once converted."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

try:  # open3d.ml.torch imports lazily and raises ImportError on first use without its extras
    import open3d.ml.torch as ml3d

    ml3d.models.RandLANet  # noqa: B018
except ImportError as exc:
    pytest.skip(
        f"Open3D-ML's PyTorch models cannot be imported ({exc}); pip install 'jointseg[ml3d]'",
        allow_module_level=True,
    )

from jointseg.exceptions import ConfigError  # noqa: E402
from jointseg.network.convert import (  # noqa: E402
    ZOO_FILE,
    convert_open3d_ml_state,
    import_open3d_ml,
    open3d_ml_config,
)
from jointseg.network.randlanet.checkpoint import load_checkpoint  # noqa: E402
from jointseg.network.randlanet.crops import Batch, build_batch, crop_indices, grid_subsample  # noqa: E402
from jointseg.network.randlanet.model import RandLANet, RandLANetConfig  # noqa: E402
from jointseg.synth import make_room  # noqa: E402

CROP = 4096
TOLERANCE = 1e-4
S3DIS = {  # Open3D-ML's ml3d/configs/randlanet_s3dis.yml, model section
    "num_neighbors": 16,
    "num_layers": 5,
    "num_points": 40960,
    "num_classes": 13,
    "ignored_label_inds": [],
    "sub_sampling_ratio": [4, 4, 4, 4, 2],
    "in_channels": 6,
    "dim_features": 8,
    "dim_output": [16, 64, 128, 256, 512],
    "grid_size": 0.04,
}
SEMANTICKITTI = {  # Open3D-ML's RandLANet defaults (randlanet_semantickitti.yml)
    "num_neighbors": 16,
    "num_layers": 4,
    "num_points": 45056,
    "num_classes": 19,
    "sub_sampling_ratio": [4, 4, 4, 4],
    "in_channels": 3,
    "dim_features": 8,
    "dim_output": [16, 64, 128, 256],
    "grid_size": 0.06,
}


@pytest.fixture(autouse=True)
def _one_thread() -> Any:
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def open3d_ml_model(seed: int = 0, **overrides: Any) -> torch.nn.Module:
    """Open3D-ML's RandLA-Net with random weights and random BatchNorm statistics, in eval mode."""
    torch.manual_seed(seed)
    model = ml3d.models.RandLANet(**{**S3DIS, **overrides})
    with torch.no_grad():
        for module in model.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.uniform_(-0.5, 0.5)
                module.running_var.uniform_(0.5, 2.0)
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.2, 0.2)
                module.num_batches_tracked.fill_(1000)
    model.device = torch.device("cpu")  # set by Open3D-ML's pipeline; forward() reads it
    return model.eval()


@pytest.fixture(scope="module")
def theirs() -> torch.nn.Module:
    return open3d_ml_model()


@pytest.fixture(scope="module")
def batch() -> Batch:
    """One shuffled crop of a synthetic room with all per-layer indices, jointseg's conventions."""
    scan = make_room(0, points=50_000)
    cloud = grid_subsample(scan.xyz, scan.rgb, None, 0.04)
    rng = np.random.default_rng(0)
    idx = crop_indices(cloud, cloud.xyz[rng.integers(len(cloud.xyz))], CROP)
    assert len(idx) == CROP
    idx = rng.permutation(idx)
    return build_batch([(cloud.xyz[idx], cloud.rgb[idx], None, idx)], RandLANetConfig())


def open3d_ml_logits(model: torch.nn.Module, batch: Batch) -> torch.Tensor:
    """Open3D-ML's forward on the same crop and indices, colour in 0-255 as it was trained."""
    features = batch.features.clone()
    features[..., 3:6] *= 255.0
    inputs = {
        "features": features,
        "coords": batch.coords,
        "neighbor_indices": batch.neighbours,
        "sub_idx": batch.pools,
        "interp_idx": batch.upsamples,
    }
    with torch.no_grad():
        return model(inputs)


def our_logits(model: RandLANet, batch: Batch) -> torch.Tensor:
    with torch.no_grad():
        return model(batch.features, batch.coords, batch.neighbours, batch.pools, batch.upsamples)


@pytest.fixture(scope="module")
def reference(theirs: torch.nn.Module, batch: Batch) -> torch.Tensor:
    return open3d_ml_logits(theirs, batch)


def test_same_architecture_and_parameter_count(theirs: torch.nn.Module) -> None:
    ours = RandLANet()
    count = sum(p.numel() for p in ours.parameters())
    assert count == sum(p.numel() for p in theirs.parameters()) == 4_995_093
    assert len(ours.state_dict()) == len(theirs.state_dict())


def test_converted_weights_give_open3d_ml_logits(
    theirs: torch.nn.Module, batch: Batch, reference: torch.Tensor
) -> None:
    state = theirs.state_dict()
    config = open3d_ml_config(state)
    assert config == RandLANetConfig()
    ours = RandLANet(config)
    ours.load_state_dict(convert_open3d_ml_state(state), strict=True)
    ours.eval()
    logits = our_logits(ours, batch)

    assert reference.shape == logits.shape == (1, CROP, 13)
    assert reference.abs().max() > 1.0  # not a degenerate all-zero output
    assert reference.argmax(-1).unique().numel() > 1
    diff = (logits - reference).abs().max().item()
    assert diff <= TOLERANCE, f"max abs logit difference {diff:.3g}"


def test_colour_is_folded_into_the_first_layer(theirs: torch.nn.Module, batch: Batch) -> None:
    """Without the x255 fold the outputs differ: the test above really checks the colour path."""
    state = convert_open3d_ml_state(theirs.state_dict())
    state["stem.weight"][:, 3:6] /= 255.0
    ours = RandLANet()
    ours.load_state_dict(state)
    ours.eval()
    assert (our_logits(ours, batch) - open3d_ml_logits(theirs, batch)).abs().max() > 1e-2


def test_module_prefix_is_stripped(theirs: torch.nn.Module) -> None:
    plain = convert_open3d_ml_state(theirs.state_dict())
    wrapped = convert_open3d_ml_state({f"module.{k}": v for k, v in theirs.state_dict().items()})
    assert plain.keys() == wrapped.keys()
    assert all(torch.equal(plain[k], wrapped[k]) for k in plain)


def test_import_round_trips_through_a_file(
    theirs: torch.nn.Module, batch: Batch, reference: torch.Tensor, tmp_path: Path
) -> None:
    src = tmp_path / ZOO_FILE
    torch.save({"model_state_dict": theirs.state_dict(), "epoch": 1}, src)
    dst = import_open3d_ml(src, tmp_path / "out" / "randlanet_s3dis.pt")

    model, card, body = load_checkpoint(dst)
    assert not model.training
    assert (our_logits(model, batch) - reference).abs().max().item() <= TOLERANCE
    assert ZOO_FILE in card["source"]
    assert len(card["source_sha256"]) == 64
    assert "70.9" in card["published_miou"]
    assert card["source_epoch"] == 1
    assert len(card["classes"]) == 13
    assert body["config"]["num_classes"] == 13


@pytest.mark.parametrize("layout", ["state_dict", "bare"])
def test_import_accepts_other_layouts(theirs: torch.nn.Module, tmp_path: Path, layout: str) -> None:
    state = theirs.state_dict()
    src = tmp_path / "mine.pth"
    torch.save({"state_dict": state} if layout == "state_dict" else state, src)
    _, card, _ = load_checkpoint(import_open3d_ml(src, tmp_path / "mine.pt"))
    assert "published_miou" not in card  # not the model zoo file: no score is claimed


def test_text_file_is_rejected(tmp_path: Path) -> None:
    src = tmp_path / "notes.pth"
    src.write_text("not a checkpoint\n")
    with pytest.raises(ConfigError, match="notes.pth.*not a readable PyTorch checkpoint"):
        import_open3d_ml(src, tmp_path / "out.pt")
    assert not (tmp_path / "out.pt").exists()


def test_missing_file_is_rejected(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        import_open3d_ml(tmp_path / "absent.pth", tmp_path / "out.pt")


def test_wrong_content_is_rejected(tmp_path: Path) -> None:
    src = tmp_path / "other.pth"
    torch.save({"model_state_dict": {"linear.weight": torch.zeros(2, 2)}}, src)
    with pytest.raises(ConfigError, match="other.pth.*'fc0.weight'"):
        import_open3d_ml(src, tmp_path / "out.pt")
    torch.save([1, 2, 3], src)
    with pytest.raises(ConfigError, match="other.pth.*not a state dict"):
        import_open3d_ml(src, tmp_path / "out.pt")


def test_missing_key_is_named(theirs: torch.nn.Module, tmp_path: Path) -> None:
    state = dict(theirs.state_dict())
    del state["encoder.2.lse2.mlp.batch_norm.running_var"]
    with pytest.raises(ConfigError, match=r"missing keys: 'encoder\.2\.lse2\.mlp\.batch_norm"):
        convert_open3d_ml_state(state)
    src = tmp_path / "broken.pth"
    torch.save({"model_state_dict": state}, src)
    with pytest.raises(ConfigError, match="broken.pth.*encoder.2.lse2.mlp.batch_norm.running_var"):
        import_open3d_ml(src, tmp_path / "out.pt")


def test_unexpected_key_and_wrong_shape_are_named(theirs: torch.nn.Module) -> None:
    state = dict(theirs.state_dict())
    with pytest.raises(ConfigError, match="unexpected keys: 'extra.weight'"):
        convert_open3d_ml_state({**state, "extra.weight": torch.zeros(1)})
    bad = {**state, "decoder.1.conv.weight": torch.zeros(768, 255, 1, 1)}
    with pytest.raises(ConfigError, match=r"shape mismatch for 'decoder\.1\.conv\.weight'"):
        convert_open3d_ml_state(bad)


def test_semantickitti_checkpoint_is_rejected_clearly(tmp_path: Path) -> None:
    """xyz-only input and 4 layers: no colour to fold in, and the sub-sampling ratios are not in
    the weights, so it cannot be imported, and the message says why."""
    state = ml3d.models.RandLANet(**SEMANTICKITTI).state_dict()
    with pytest.raises(ConfigError, match=r"3 input channels.*4 encoder layers.*19 classes"):
        convert_open3d_ml_state(state)
    src = tmp_path / "randlanet_semantickitti_202201071330utc.pth"
    torch.save({"model_state_dict": state}, src)
    with pytest.raises(ConfigError, match="randlanet_semantickitti.*3 input channels"):
        import_open3d_ml(src, tmp_path / "out.pt")


def test_other_class_count_converts_but_is_not_imported(tmp_path: Path) -> None:
    """The S3DIS architecture with a 19-class head converts with the right head, but jointseg
    labels with the 13 S3DIS classes, so importing it is refused."""
    state = open3d_ml_model(num_classes=19).state_dict()
    config = open3d_ml_config(state)
    assert config.num_classes == 19
    converted = convert_open3d_ml_state(state)
    assert converted["head.3.conv.weight"].shape == (19, 32, 1, 1)
    RandLANet(config).load_state_dict(converted, strict=True)
    src = tmp_path / "nineteen.pth"
    torch.save({"model_state_dict": state}, src)
    with pytest.raises(ConfigError, match="nineteen.pth.*19 classes.*13 S3DIS classes"):
        import_open3d_ml(src, tmp_path / "out.pt")


def test_jointseg_checkpoint_is_not_reimported(theirs: torch.nn.Module, tmp_path: Path) -> None:
    src = tmp_path / ZOO_FILE
    torch.save({"model_state_dict": theirs.state_dict()}, src)
    ours = import_open3d_ml(src, tmp_path / "ours.pt")
    with pytest.raises(ConfigError, match="already a jointseg checkpoint"):
        import_open3d_ml(ours, tmp_path / "again.pt")


def test_pickled_objects_need_consent(theirs: torch.nn.Module, tmp_path: Path) -> None:
    """A file holding arbitrary Python objects is only unpickled when allowed."""
    import argparse

    src = tmp_path / "with_args.pth"
    torch.save({"model_state_dict": theirs.state_dict(), "args": argparse.Namespace(a=1)}, src)
    with pytest.raises(ConfigError, match="with_args.pth.*Python objects"):
        import_open3d_ml(src, tmp_path / "refused.pt", allow_pickle=False)
    assert import_open3d_ml(src, tmp_path / "allowed.pt", allow_pickle=True).is_file()


def test_export_is_the_inverse_of_import(theirs: torch.nn.Module) -> None:
    from jointseg.network.convert import convert_open3d_ml_state, to_open3d_ml_state

    original = {k: v.clone() for k, v in theirs.state_dict().items()}
    back = to_open3d_ml_state(convert_open3d_ml_state(original))
    assert set(back) == set(original)
    for key, value in original.items():
        if value.is_floating_point():
            assert torch.allclose(back[key], value, atol=1e-6), key
