"""An adapted model's gate (``--keep-base-above``): the bundled head's answer where it is sure,
the adapted head's elsewhere, kept through a checkpoint's round trip."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from jointseg.adapt.learn import with_head
from jointseg.network.checkpoint import load_checkpoint, save_checkpoint
from jointseg.network.randlanet.model import RandLANet, gated, make_head


def test_the_gate_keeps_the_base_answer_only_where_the_base_is_sure() -> None:
    base = torch.tensor([[[4.0, 0.0, 0.0], [0.2, 0.1, 0.0]]])  # sure of 0; unsure
    adapted = torch.tensor([[[0.0, 5.0, 0.0], [0.0, 0.0, 5.0]]])
    out = gated(base, adapted, 0.9)
    assert out.argmax(-1).tolist() == [[0, 2]]
    assert gated(base, adapted, 1.0).argmax(-1).tolist() == [[1, 2]]  # never sure enough


def test_a_gated_model_keeps_both_heads_through_its_checkpoint(tmp_path: Path) -> None:
    torch.manual_seed(0)
    base = RandLANet().eval()
    head = make_head(base.head[0].in_channels, base.config.num_classes).eval()
    model = with_head(base, head, 0.9)
    assert model.config.keep_base_above == 0.9 and model.base_head is not None
    x = torch.randn(1, 50, base.head[0].in_channels)
    for a, b in zip(
        model.base_head.state_dict().values(), base.head.state_dict().values(), strict=True
    ):
        assert torch.equal(a, b)
    save_checkpoint(tmp_path / "m.pt", model, {"name": "gated"})
    loaded, _, _ = load_checkpoint(tmp_path / "m.pt")
    assert loaded.config.keep_base_above == 0.9 and loaded.base_head is not None
    with torch.no_grad():
        want = gated(base.head(x), head(x), 0.9)
        got = gated(loaded.base_head(x), loaded.head(x), 0.9)
    assert torch.allclose(want, got, atol=1e-6)
    # adapted again, it keeps the bundled head it started from, not the adapted one
    again = with_head(loaded, make_head(head[0].in_channels, 13).eval(), 0.9)
    assert again.base_head is not None
    for a, b in zip(
        again.base_head.state_dict().values(), base.head.state_dict().values(), strict=True
    ):
        assert torch.allclose(a, b)
    # without the gate the model is an ordinary one
    plain = with_head(base, head, None)
    assert plain.base_head is None and plain.config.keep_base_above is None


def test_models_of_one_weights_and_another_gate_do_not_share_an_openvino_export(
    tmp_path: Path,
) -> None:
    """The export cache is keyed by what the model computes: the same weights with another
    gate (or none) must not reuse a gated model's export."""
    pytest.importorskip("openvino")
    from jointseg.network.randlanet.engine import CompiledForward

    torch.manual_seed(0)
    base = RandLANet().eval()
    head = make_head(base.head[0].in_channels, base.config.num_classes).eval()
    digests = {
        gate: CompiledForward(with_head(base, head, gate), 1, tmp_path).digest
        for gate in (None, 0.9, 0.97)
    }
    assert len(set(digests.values())) == 3, digests
