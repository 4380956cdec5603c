"""Objects and rooms of a tiled run, found once for the whole scan (not per tile), in bounded
memory.

The merged labels of every point are known; their positions are streamed. One pass reduces the
scan to 5 cm voxels of the levelled work frame on one global grid (a voxel's majority label,
its centroid, its points and mean confidence), :func:`jointseg.objects.layout.find_layout` runs
on the voxels, and the writing pass gives each point its voxel's object when it carries the
voxel's label. An object that spans two tiles is one object, because voxels know no tiles.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from jointseg.objects.layout import find_layout
from jointseg.objects.params import ObjectParams
from jointseg.objects.records import LayoutReport
from jointseg.spacing import estimate_spacing

#: Voxel side, metres: the room grid's cell, and small beside the objects' contact distance.
CELL = 0.05
#: Bits per axis of a voxel key (cells from -2**17 to 2**17: +-6.5 km at 5 cm around the work
#: frame's origin), so a key times 16 (a label beside it) still fits an int64.
_BITS = 18
_HALF = 1 << (_BITS - 1)


def voxel_keys(work: np.ndarray) -> np.ndarray:
    """One int64 key per point for its 5 cm voxel on the global grid of the work frame."""
    cells = np.floor(work / CELL).astype(np.int64) + _HALF
    np.clip(cells, 0, (1 << _BITS) - 1, out=cells)
    return (cells[:, 0] << (2 * _BITS)) | (cells[:, 1] << _BITS) | cells[:, 2]


@dataclass(frozen=True)
class TiledLayout:
    """The layout found on the voxels, and how to give points their object."""

    keys: np.ndarray  # sorted voxel keys
    labels: np.ndarray  # each voxel's majority label
    instances: np.ndarray  # each voxel's object id, -1 none
    report: LayoutReport

    def point_instances(self, work: np.ndarray, labels: np.ndarray) -> np.ndarray:
        """Object ids of points (work coordinates, fused labels): their voxel's object when
        they carry its label, else -1."""
        keys = voxel_keys(work)
        at = np.clip(np.searchsorted(self.keys, keys), 0, len(self.keys) - 1)
        found = (self.keys[at] == keys) & (self.labels[at] == labels)
        return np.where(found, self.instances[at], -1).astype(np.int32)


def tiled_layout(
    chunks: Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    to_user: np.ndarray,
    params: ObjectParams,
) -> TiledLayout | None:
    """Objects, rooms and walls from chunks of (work xyz, fused labels, confidence, kept mask).

    Returns None for a scan without any kept point.
    """
    parts = []
    spacing = None
    for work, labels, confidence, kept in chunks:
        if kept.any():
            if spacing is None:  # the scan's density, from its first chunk
                spacing = estimate_spacing(work[kept])
            parts.append(
                _reduce(voxel_keys(work[kept]), labels[kept], work[kept], confidence[kept])
            )
    if not parts:
        return None
    key, label, count, xyz_sum, conf_sum = (np.concatenate(p) for p in zip(*parts, strict=True))
    key, label, count, xyz_sum, conf_sum = _merge(key, label, count, xyz_sum, conf_sum)
    # each voxel: its majority label (the row with the most points of that voxel)
    order = np.lexsort((-count, key))
    first = np.r_[True, key[order][1:] != key[order][:-1]]
    starts = np.flatnonzero(first)
    winner = order[starts]
    totals = np.add.reduceat(count[order], starts)
    sums = np.add.reduceat(xyz_sum[order], starts, axis=0)
    centroids = sums / totals[:, None]
    confidence = conf_sum[winner] / count[winner]
    # voxel centroids sit up to half a cell from their points: contact reaches that much further
    contact = max(params.min_contact, params.contact * (spacing or 0.0))
    voxel_params = params.model_copy(update={"min_points": 3, "min_contact": contact + CELL / 2})
    layout = find_layout(
        centroids, label[winner], confidence, CELL, to_user=to_user, params=voxel_params
    )
    report = layout.report
    points = np.bincount(
        layout.instances[layout.instances >= 0],
        weights=count[winner][layout.instances >= 0],
        minlength=len(report.objects),
    )
    for obj in report.objects:
        obj.points = int(points[obj.id]) if obj.id < len(points) else obj.points
    # objects are judged by their points, as in an untiled run, not by their voxels
    small = {o.id for o in report.objects if o.points < params.min_points}
    instances = layout.instances.copy()
    if small:
        instances[np.isin(instances, list(small))] = -1
        report.objects = [o for o in report.objects if o.id not in small]
        for room in report.rooms:
            room.objects = [i for i in room.objects if i not in small]
    return TiledLayout(key[winner], label[winner], instances, report)


def _reduce(
    keys: np.ndarray, labels: np.ndarray, xyz: np.ndarray, confidence: np.ndarray
) -> tuple[np.ndarray, ...]:
    """Per (voxel, label): key, label, points, sum of positions, sum of confidences."""
    combined = keys * 16 + labels.astype(np.int64).clip(-1, 14) + 1
    uniq, inverse, count = np.unique(combined, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    xyz_sum = np.stack(
        [np.bincount(inverse, weights=xyz[:, a], minlength=uniq.size) for a in range(3)], axis=1
    )
    conf_sum = np.bincount(inverse, weights=confidence.astype(np.float64), minlength=uniq.size)
    return uniq // 16, (uniq % 16 - 1).astype(np.int32), count, xyz_sum, conf_sum


def _merge(
    key: np.ndarray, label: np.ndarray, count: np.ndarray, xyz_sum: np.ndarray, conf_sum: np.ndarray
) -> tuple[np.ndarray, ...]:
    """The chunks' (voxel, label) rows summed where one voxel spans chunks."""
    combined = key * 16 + label.astype(np.int64) + 1
    uniq, inverse = np.unique(combined, return_inverse=True)
    inverse = inverse.reshape(-1)
    n = uniq.size
    xyz = np.stack([np.bincount(inverse, weights=xyz_sum[:, a], minlength=n) for a in range(3)], 1)
    return (
        uniq // 16,
        (uniq % 16 - 1).astype(np.int32),
        np.bincount(inverse, weights=count, minlength=n).astype(np.int64),
        xyz,
        np.bincount(inverse, weights=conf_sum, minlength=n),
    )


def chunk_inputs(
    coordinates: Iterator[np.ndarray],
    fused: np.ndarray,
    confidence: np.ndarray,
    stream: object | None,
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """(work xyz, fused labels, confidence, kept) per chunk of the input's coordinates
    (:meth:`~jointseg.io.chunks.ScanChunks.coordinates`), in the scan's order."""
    start = 0
    for xyz in coordinates:
        stop = start + len(xyz)
        if stream is None:
            work, kept = xyz, np.ones(len(xyz), dtype=bool)
        else:
            work = stream.work_xyz(xyz)  # type: ignore[attr-defined]
            kept = ~stream.stray(xyz)  # type: ignore[attr-defined]
        yield work, fused[start:stop], confidence[start:stop], kept
        start = stop
