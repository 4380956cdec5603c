"""RandLA-Net's architecture and input conventions, apart from the model: what the torch-free
compiled path (:mod:`jointseg.network.randlanet.compiled`) needs to build a crop's inputs."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class RandLANetConfig(BaseModel):
    """Architecture and input conventions; defaults are RandLA-Net's S3DIS configuration."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    num_classes: int = Field(13, gt=1)
    in_channels: int = Field(6, description="xyz (crop-centred in x, y) + rgb in [0, 1]")
    d_stem: int = 8
    d_out: tuple[int, ...] = (16, 64, 128, 256, 512)
    ratios: tuple[int, ...] = (4, 4, 4, 4, 2)
    k: int = Field(16, gt=0, description="neighbours per point")
    num_points: int = Field(40_960, gt=0, description="points per crop")
    grid_size: float = Field(0.04, gt=0, description="grid sub-sampling, metres")
    keep_base_above: float | None = Field(
        None,
        gt=0,
        le=1,
        description="an adapted model's gate (jointseg.adapt): where the base head's top "
        "probability reaches this, its answer is kept; elsewhere the adapted head's",
    )
