"""When and how a big scan is cut into tiles: the ``tiles`` section of the pipeline's
configuration.

Why apart from :mod:`jointseg.pipeline.tiled`: the configuration
(:mod:`jointseg.pipeline.config`) holds this section and the tiled run reads the configuration,
so the section sits below both and the imports between the two run one way only.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, PositiveInt


class TileParams(BaseModel):
    """When and how a scan is cut into tiles."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    max_points: PositiveInt = Field(
        4_000_000,
        description="A scan with more points is tiled; each tile's core holds about this many "
        "points at most.",
    )
    overlap: float = Field(
        2.0,
        ge=0,
        description="Margin (m) each tile reads beyond its core on every side: at least the "
        "network's crop radius (about 1.5-2 m for RandLA-Net on indoor scans), so a crop "
        "centred in the core finds all its points.",
    )
    geometry_overlap: float = Field(
        0.75,
        ge=0,
        description="Margin (m) the geometry segments beyond each core: enough for the "
        "segments of neighbouring tiles to overlap and be joined; the network's wider margin "
        "(overlap) costs only reading, the geometry's costs segmenting twice.",
    )

    def needs_tiles(self, points: int) -> bool:
        """Whether a scan of ``points`` points is cut into tiles: the one rule the CLI and the
        job service both follow."""
        return points > self.max_points
