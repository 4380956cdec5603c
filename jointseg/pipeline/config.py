"""Everything the pipeline can be told, in one pydantic model that a JSON file can fill.

Unknown keys are rejected at every level, so a misspelt parameter fails loudly instead of being
silently ignored.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, PositiveInt

from jointseg.fusion import FusionParams
from jointseg.geometry import GeometryParams
from jointseg.network.dgcnn_predict import DGCNNParams


class NetworkConfig(BaseModel):
    """Which network labels the points, and where it runs."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(
        "randlanet", description="Network backend: randlanet or dgcnn (`jointseg models list`)."
    )
    weights: Path | None = Field(
        None,
        description="Weights file; default: the backend's environment variable "
        "(JOINTSEG_DGCNN_WEIGHTS, ...), else the weights bundled for it.",
    )
    device: str | None = Field(None, description="'cpu' or 'cuda'; default: cuda when present.")
    batch_size: PositiveInt = Field(
        4,
        description="Crops (RandLA-Net) or 4 096-point blocks (DGCNN) per forward pass: memory, "
        "and how often cancellation is checked.",
    )
    dgcnn: DGCNNParams = Field(
        default_factory=DGCNNParams,
        description="DGCNN's blocks and room normalisation (used when name is dgcnn).",
    )


class PipelineConfig(BaseModel):
    """Network, geometry and fusion settings of one pipeline run.

    Examples
    --------
    ``{"network": {"weights": "model.pt"}, "geometry": {"cluster_distance": 0.05},
    "fusion": {"mode": "paper", "ratio_threshold": 0.3}, "seed": 1}``
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    network: NetworkConfig = Field(default_factory=NetworkConfig)
    geometry: GeometryParams = Field(default_factory=GeometryParams)
    fusion: FusionParams = Field(default_factory=FusionParams)
    seed: int = Field(0, description="Crop and RANSAC randomness; a seed gives one result.")
    concurrent: bool = Field(
        True,
        description="Run the network and the geometry at the same time (two threads; both "
        "release the GIL in their heavy parts).",
    )

    def with_network(
        self, *, name: str | None = None, weights: Path | None = None
    ) -> PipelineConfig:
        """A copy with the network name and/or weights replaced (command-line overrides)."""
        update: dict[str, object] = {}
        if name is not None:
            update["name"] = name
        if weights is not None:
            update["weights"] = weights
        return self.model_copy(update={"network": self.network.model_copy(update=update)})
