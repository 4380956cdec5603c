"""The room frame behind DGCNN's room-normalised coordinates.

The published S3DIS weights see, for every point, its position divided by the size of its room
(``x / max x`` etc. with the room shifted to start at 0), and build their first neighbour graph in
those coordinates. For a whole S3DIS room the scan's bounding box *is* the room. For anything
else it is not: a 1 m slice of a room would be stretched three times in z (a table top would
look like a point near the ceiling, and the neighbour graph becomes flat and wide), a scan
without ceiling or with noise below the floor shifts every height. ``room_frame`` measures the
room instead: the floor as the lowest horizontal layer that covers the footprint, the ceiling
likewise at the top when there is one, and a typical room height when there is not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Floor-to-ceiling height assumed when a scan shows no ceiling: S3DIS rooms are about 3 m.
DEFAULT_ROOM_HEIGHT = 3.0
#: Grid (metres) on which the footprint and a layer's coverage of it are measured.
FOOTPRINT_CELL = 0.25
#: A horizontal layer is a floor or ceiling when it covers this share of the footprint.
MIN_LAYER_COVERAGE = 0.3
#: Thickness (metres) of the horizontal layers searched for floor and ceiling.
LAYER_THICKNESS = 0.04
#: How far (metres) above the lowest / below the highest point floor and ceiling are searched.
SEARCH_DEPTH = 0.3


@dataclass(frozen=True)
class RoomFrame:
    """Where the room starts and how large it is.

    Attributes
    ----------
    origin : ndarray of shape (3,), metres
        Subtracted from the coordinates: x and y minimum, floor height.
    extent : ndarray of shape (3,), metres
        What the shifted coordinates are divided by for the normalised features.
    floor, ceiling : bool
        Whether a floor / ceiling layer was found (always False for the scan frame).
    """

    origin: np.ndarray
    extent: np.ndarray
    floor: bool = False
    ceiling: bool = False


def scan_frame(xyz: np.ndarray) -> RoomFrame:
    """The reference's frame: the scan's bounding box is the room."""
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    return RoomFrame(lo, np.maximum(hi - lo, 1e-6))


def _layer(
    xyz: np.ndarray, cells: np.ndarray, n_cells: int, *, top: bool
) -> tuple[float, float] | None:
    """Height of the horizontal layer near the bottom (or top) that covers most footprint
    cells, and its coverage; None when there is no point in the search range."""
    z = xyz[:, 2]
    edge = float(z.max() if top else z.min())
    near = (z >= edge - SEARCH_DEPTH) if top else (z <= edge + SEARCH_DEPTH)
    if not near.any():
        return None
    layer = np.floor((z[near] - (edge - SEARCH_DEPTH if top else edge)) / LAYER_THICKNESS)
    layer = layer.astype(np.int64)
    n_layers = int(layer.max()) + 1
    # distinct footprint cells per layer
    pairs = np.unique(layer * n_cells + cells[near])
    coverage = np.bincount(pairs // n_cells, minlength=n_layers) / n_cells
    best = int(np.argmax(coverage))
    base = edge - SEARCH_DEPTH if top else edge
    return base + (best + 0.5) * LAYER_THICKNESS, float(coverage[best])


def room_frame(
    xyz: np.ndarray,
    *,
    height: float | None = None,
    default_height: float = DEFAULT_ROOM_HEIGHT,
) -> RoomFrame:
    """The room a scan belongs to, measured instead of assumed to be the bounding box.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), metres, z up
    height : float, optional, metres
        Floor-to-ceiling height when known; default: measured from a ceiling layer when the
        scan has one, else ``default_height`` (or the scan's own height if that is larger).
    default_height : float, metres

    Returns
    -------
    RoomFrame
        x, y: the scan's extent; z: from the floor (the lowest horizontal layer covering at
        least 30 % of the footprint, else the lowest point) over the room height.
    """
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    grid = np.floor((xyz[:, :2] - lo[:2]) / FOOTPRINT_CELL).astype(np.int64)
    ny = int(grid[:, 1].max()) + 1
    flat = grid[:, 0] * ny + grid[:, 1]
    occupied, cells = np.unique(flat, return_inverse=True)
    n_cells = len(occupied)
    floor_z, found_floor = float(lo[2]), False
    bottom = _layer(xyz, cells, n_cells, top=False)
    if bottom is not None and bottom[1] >= MIN_LAYER_COVERAGE:
        floor_z, found_floor = bottom[0], True
    found_ceiling = False
    if height is None:
        top = _layer(xyz, cells, n_cells, top=True)
        if top is not None and top[1] >= MIN_LAYER_COVERAGE and top[0] - floor_z > 1.5:
            height, found_ceiling = top[0] - floor_z, True
        else:
            height = max(default_height, float(hi[2]) - floor_z)
    origin = np.array([lo[0], lo[1], floor_z])
    extent = np.maximum(np.array([hi[0] - lo[0], hi[1] - lo[1], height]), 1e-6)
    return RoomFrame(origin, extent, found_floor, found_ceiling)
