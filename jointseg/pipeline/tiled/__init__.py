"""Big scans in bounded memory: a scan cut into x-y tiles, each run on its own, then joined.

Three public calls: ``plan`` spills the scan and cuts it, ``run_tile`` runs one tile, ``finish``
joins, votes and writes. Inside: ``grid`` (where the
cuts go), ``store`` (the work folder), ``run`` (one tile), ``merge`` (joining the tiles).
Names are imported on first use, so the configuration (``TileParams``) stays light.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from jointseg.lazy import lazy_attributes

if TYPE_CHECKING:
    from jointseg.pipeline.tile_params import TileParams
    from jointseg.pipeline.tiled.run import run_tile
    from jointseg.pipeline.tiled.steps import TiledRun, TileProgress, finish, plan
    from jointseg.pipeline.tiled.store import TilePlan

_LAZY = {
    "TileParams": "jointseg.pipeline.tile_params",
    "TilePlan": "jointseg.pipeline.tiled.store",
    "TiledRun": "jointseg.pipeline.tiled.steps",
    "TileProgress": "jointseg.pipeline.tiled.steps",
    "finish": "jointseg.pipeline.tiled.steps",
    "plan": "jointseg.pipeline.tiled.steps",
    "run_tile": "jointseg.pipeline.tiled.run",
}

__all__ = ["TilePlan", "TileParams", "TileProgress", "TiledRun", "finish", "plan", "run_tile"]

__getattr__ = lazy_attributes(__name__, _LAZY)
