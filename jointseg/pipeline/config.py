"""Everything the pipeline can be told, in one pydantic model that a JSON file can fill.

Unknown keys are rejected at every level, so a misspelt parameter fails loudly instead of being
silently ignored.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, PositiveInt, create_model, model_validator

from jointseg.frame.params import FrameParams
from jointseg.fusion import FusionParams
from jointseg.geometry import GeometryParams
from jointseg.network.choice import Choice
from jointseg.network.devices import DEVICE_NAMES, check_device_name
from jointseg.network.registry import BACKENDS, DEFAULT_BACKEND, REGISTRY
from jointseg.objects.params import ObjectParams
from jointseg.pipeline.quality import Quality, with_preset
from jointseg.pipeline.tile_params import TileParams


class NetworkSettings(BaseModel):
    """Which network labels the points, and where it runs: the fields every backend shares.

    :data:`NetworkConfig` adds one section per backend that takes options, named after it
    (``{"name": "dgcnn", "dgcnn": {"stride": 1.0}}``) and validated by that backend's params
    model, so a misspelt option of any backend is rejected whichever backend is chosen.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(
        DEFAULT_BACKEND,
        description=f"Network backend: {' or '.join(BACKENDS)} (`jointseg models list`).",
    )
    weights: Path | None = Field(
        None,
        description="Weights file; default: the backend's environment variable "
        "(JOINTSEG_DGCNN_WEIGHTS, ...), else the weights bundled for it.",
    )
    device: str | None = Field(
        None,
        pattern=rf"^({DEVICE_NAMES})$",
        description="'cpu', 'cuda' or 'cuda:N'; default: cuda when present.",
    )
    batch_size: PositiveInt | None = Field(
        None,
        description="Crops (RandLA-Net) or 4 096-point blocks (DGCNN) per forward pass; default "
        "1 on the CPU (fastest there), 8 on CUDA.",
    )
    ensemble: bool = Field(
        False,
        description="Average the chosen network's class probabilities with those of every "
        "other network whose weights are on this machine (DGCNN once pulled); the colour-free "
        "RandLA-Net only stands in for the colour one on a scan without colour. The best "
        "quality preset turns this on.",
    )
    colour_free: Literal["auto", "on", "off"] = Field(
        "auto",
        description="The colour-free RandLA-Net (trained with colour withheld): auto takes it for "
        "a scan without usable colour when the bundled RandLA-Net is chosen; on: always; off: "
        "never.",
    )

    def options(self) -> BaseModel | None:
        """The chosen backend's options (its section), None for a backend that takes none."""
        record = REGISTRY.get(self.name)
        if record is None or record.params is None:
            return None
        return getattr(self, record.name, None)

    def choice(self) -> Choice:
        """This section as :mod:`jointseg.network.choice` takes it."""
        params = {r.name: getattr(self, r.name, None) for r in REGISTRY.values() if r.params}
        return Choice(
            name=self.name,
            weights=self.weights,
            device=self.device,
            batch_size=self.batch_size,
            colour_free=self.colour_free,
            ensemble=self.ensemble,
            params=params,
        )


def _backend_sections() -> dict[str, Any]:
    """One field per backend with options: its params model, defaulting to its defaults."""
    return {
        record.name: (
            record.params,
            Field(
                default_factory=record.params,
                description=f"{record.params_help} (used when name is {record.name}).",
            ),
        )
        for record in REGISTRY.values()
        if record.params is not None
    }


if TYPE_CHECKING:
    NetworkConfig = NetworkSettings
else:
    NetworkConfig = create_model(
        "NetworkConfig",
        __base__=NetworkSettings,
        __module__=__name__,
        __doc__=NetworkSettings.__doc__,
        **_backend_sections(),
    )


class PipelineConfig(BaseModel):
    """Network, geometry and fusion settings of one pipeline run.

    Examples
    --------
    ``{"network": {"weights": "model.pt"}, "geometry": {"cluster_distance": 0.05},
    "fusion": {"mode": "paper", "ratio_threshold": 0.3}, "seed": 1}``
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    quality: Quality = Field(
        "standard",
        description="fast (previews, big floors: fewer crops, coarser geometry), standard, or "
        "best (four views of every crop, every installed network averaged): defaults under "
        "the other settings here (jointseg.pipeline.quality).",
    )
    frame: FrameParams = Field(
        default_factory=FrameParams,
        description="Up axis, units, stray points and colour: decided from the scan unless set.",
    )
    network: NetworkConfig = Field(default_factory=NetworkConfig)
    geometry: GeometryParams = Field(default_factory=GeometryParams)
    fusion: FusionParams = Field(default_factory=FusionParams)
    tiles: TileParams = Field(
        default_factory=TileParams,
        description="When a big scan is cut into tiles, and how (bounded memory; issue 16).",
    )
    objects: ObjectParams = Field(
        default_factory=ObjectParams,
        description="Objects, rooms and walls found from the fused labels (issue 33).",
    )
    seed: int = Field(0, description="Crop and RANSAC randomness; a seed gives one result.")
    concurrent: bool = Field(
        True,
        description="Run the network and the geometry at the same time (two threads; both "
        "release the GIL in their heavy parts).",
    )

    @model_validator(mode="before")
    @classmethod
    def _preset(cls, data: Any) -> Any:
        """The quality preset's values under the ones given."""
        return with_preset(data) if isinstance(data, dict) else data

    def with_network(
        self, *, name: str | None = None, weights: Path | None = None, device: str | None = None
    ) -> PipelineConfig:
        """A copy with the network name, weights and/or device replaced (command-line overrides).

        The device is validated like the config file's (``model_copy`` checks nothing), so a
        bad ``--device`` is refused before any work.
        """
        update: dict[str, object] = {}
        if name is not None:
            update["name"] = name
        if weights is not None:
            update["weights"] = weights
        if device is not None:
            check_device_name(device)
            update["device"] = device
        return self.model_copy(update={"network": self.network.model_copy(update=update)})
