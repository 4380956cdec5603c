"""RandLA-Net for semantic segmentation, with the official S3DIS configuration by default."""

from __future__ import annotations

import torch
from torch import nn

from jointseg.network.randlanet.config import RandLANetConfig as RandLANetConfig
from jointseg.network.randlanet.layers import (
    BN_MOMENTUM,
    DilatedResidualBlock,
    SharedMLP,
    batch_norm_last,
    nearest_upsample,
    random_pool,
)


def make_head(channels: int, classes: int) -> nn.Sequential:
    """The point-wise layers that turn the last decoder layer's features into class scores."""
    return nn.Sequential(
        SharedMLP(channels, 64),
        SharedMLP(64, 32),
        nn.Dropout(0.5),
        SharedMLP(32, classes, bn=False, slope=None),
    )


def gated(base: torch.Tensor, adapted: torch.Tensor, keep_above: float) -> torch.Tensor:
    """The base head's scores where it is sure (top probability >= ``keep_above``), the
    adapted head's elsewhere: corrections change what the bundled network was unsure of, and
    leave alone what it already knew (a model adapted on one room must not unlearn others)."""
    sure = torch.softmax(base, dim=-1).amax(dim=-1, keepdim=True) >= keep_above
    return torch.where(sure, base, adapted)


def decoder_inputs(cfg: RandLANetConfig) -> list[tuple[int, int]]:
    """Each decoder layer's input as (skip channels, upsampled channels), concatenated in that
    order: the layout a channel-sliced copy of the network must follow."""
    skips = [2 * cfg.d_out[0]] + [2 * d for d in cfg.d_out]
    inputs, d = [], 2 * cfg.d_out[-1]
    for i in range(len(cfg.d_out)):
        skip = skips[-i - 2]
        inputs.append((skip, d))
        d = skip
    return inputs


class RandLANet(nn.Module):
    """Encoder of dilated residual blocks with random sampling, decoder with nearest-neighbour
    upsampling and skip connections, per-point class logits.

    Shapes
    ------
    features (B, N, in_channels); per layer i: coords[i] (B, N_i, 3), neighbours[i] (B, N_i, k),
    pools[i] (B, N_{i+1}, k), upsamples[i] (B, N_i, 1) -> logits (B, N, num_classes)
    """

    def __init__(self, config: RandLANetConfig | None = None) -> None:
        super().__init__()
        self.config = cfg = config or RandLANetConfig()
        if len(cfg.d_out) != len(cfg.ratios):
            raise ValueError("d_out and ratios must have one entry per layer")
        self.stem = nn.Linear(cfg.in_channels, cfg.d_stem)
        self.stem_bn = nn.BatchNorm2d(cfg.d_stem, eps=1e-6, momentum=BN_MOMENTUM)
        blocks, d = [], cfg.d_stem
        for d_out in cfg.d_out:
            blocks.append(DilatedResidualBlock(d, d_out))
            d = 2 * d_out
        self.encoder = nn.ModuleList(blocks)
        self.bottleneck = SharedMLP(d, d)
        self.decoder = nn.ModuleList(SharedMLP(skip + up, skip) for skip, up in decoder_inputs(cfg))
        d = decoder_inputs(cfg)[-1][0]
        self.head = make_head(d, cfg.num_classes)
        #: The bundled head an adapted model keeps beside its own (see ``keep_base_above``).
        self.base_head: nn.Sequential | None = (
            None if cfg.keep_base_above is None else make_head(d, cfg.num_classes)
        )

    def forward(
        self,
        features: torch.Tensor,
        coords: list[torch.Tensor],
        neighbours: list[torch.Tensor],
        pools: list[torch.Tensor],
        upsamples: list[torch.Tensor],
    ) -> torch.Tensor:
        x = nn.functional.leaky_relu(batch_norm_last(self.stem(features), self.stem_bn), 0.2)
        skips = []
        for i, block in enumerate(self.encoder):
            x = block(coords[i], x, neighbours[i])
            if i == 0:
                skips.append(x)
            x = random_pool(x, pools[i])
            skips.append(x)
        x = self.bottleneck(x)
        for i, layer in enumerate(self.decoder):
            up = nearest_upsample(x, upsamples[-i - 1])
            x = layer(torch.cat([skips[-i - 2], up], dim=2))
        logits = self.head(x)
        if self.base_head is None or self.config.keep_base_above is None:
            return logits
        return gated(self.base_head(x), logits, self.config.keep_base_above)

    def extra_repr(self) -> str:
        c = self.config
        return f"classes={c.num_classes}, d_out={c.d_out}, ratios={c.ratios}, k={c.k}"
