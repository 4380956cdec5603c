"""RandLA-Net's inference options (kept torch-free so configuration is checked without it)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class RandLANetParams(BaseModel):
    """What RandLA-Net's whole-scan inference does beyond averaging its crops."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    absent_share: float = Field(
        0.005,
        ge=0,
        lt=0.5,
        description="A class the network gives to fewer than this share of a scan's "
        "sub-sampled cells (and fewer than absent_max_cells) is taken as absent from the scan: "
        "its points get their next most likely class. Scattered labels of classes a room does "
        "not hold are the network's commonest error on other sensors; 0 turns this off.",
    )
    absent_max_cells: int = Field(
        2000,
        ge=0,
        description="A class on more cells than this is never taken as absent (about 3 m² of "
        "surface at the 4 cm grid), so a real small object on a whole floor keeps its class.",
    )
    engine: Literal["auto", "torch", "openvino"] = Field(
        "auto",
        description="What runs the forward pass on the CPU: OpenVINO (1.3-1.5x faster per crop "
        "than torch, the same labels on 99.5 % of points or more), torch, or auto: OpenVINO "
        "where it is installed (it is a dependency of jointseg) and torch otherwise. On a GPU it "
        "is always torch.",
    )
    views: int = Field(
        1,
        ge=1,
        le=16,
        description="Test-time views of every crop averaged (turned about the up axis, odd ones "
        "mirrored): 1 is the plain network; the best quality preset takes 4.",
    )
    coverage: float = Field(
        0.5,
        gt=0,
        le=2,
        description="Crops are added until every sub-sampled point's possibility (1 - d²/r² "
        "summed over the crops that hold it) reaches this: 0.5 covers each point about three "
        "times; the fast quality preset takes 0.05 (a crop's rim counts too: about 2.4 times).",
    )
    grid: float | None = Field(
        None,
        gt=0,
        le=0.2,
        description="Side (m) of the grid the network sub-samples a scan on; default: the "
        "model's own (0.04 for the bundled ones). The fast quality preset takes 0.05: about "
        "two thirds of the cells and crops (the network was trained with densities of 1-6 cm).",
    )
    projection: Literal["nearest", "cell"] = Field(
        "cell",
        description="How every point takes the network's output from the sub-sample: from its "
        "own grid cell's sub-sampled point (a sorted lookup: 0.1-0.2 s a million points), or "
        "from the nearest sub-sampled point (RandLA-Net's own projection, a KD-tree search of "
        "every point: 0.4-0.6 s a million points on 2 cores). The two differ only for points "
        "near a cell's side, where the neighbour cell's centroid is nearer; fused mIoU moved "
        "by 0.02 points or less on the judging scans and the 1 M-point room.",
    )
