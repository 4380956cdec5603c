"""DGCNN's inference options: how a scan is cut into blocks and normalised.

Kept apart from :mod:`jointseg.network.dgcnn.predict` so that configuration (the pipeline's
``network.dgcnn``, the job service's validation) is checked without importing torch.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, model_validator


class DGCNNParams(BaseModel):
    """How a scan is cut into blocks and normalised for DGCNN.

    The block size and points per block are those the published weights were trained with;
    ``stride``, ``coverage`` and ``frame`` are inference choices.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    block_size: float = Field(1.0, gt=0, description="Column width, metres (training: 1 m).")
    stride: float = Field(
        0.5, gt=0, description="Distance between column corners, metres; < block_size overlaps."
    )
    num_points: int = Field(4096, ge=32, description="Points per sample (training: 4 096).")
    min_block_points: int = Field(100, ge=1, description="Smaller columns are skipped.")
    coverage: float | None = Field(
        1.0,
        gt=0,
        description="Predictions per point, roughly (samples per column grow with its share "
        "of points; points no sample holds take their nearest predicted neighbour's "
        "probabilities); None: every point of every column is predicted. Lower is faster on "
        "dense scans; columns sparser than one sample are unaffected.",
    )
    frame: Literal["room", "scan"] = Field(
        "room",
        description="'scan': the bounding box is the room (the reference); 'room': floor and "
        "ceiling measured, a typical height when the scan has no ceiling.",
    )
    room_height: float | None = Field(
        None, gt=0, description="Floor-to-ceiling height, metres ('room' frame; default measured)."
    )
    room_size: tuple[PositiveFloat, PositiveFloat] | None = Field(
        None,
        description="Room x and y size, metres, for scans larger than a room (whole floors): "
        "every column is then placed in the middle of a room of this size.",
    )

    @model_validator(mode="after")
    def _columns_touch(self) -> DGCNNParams:
        if self.stride > self.block_size:
            raise ValueError(
                f"stride {self.stride} m exceeds block_size {self.block_size} m: columns would "
                "leave gaps between them"
            )
        return self
