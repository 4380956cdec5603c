"""The network as a judge of the frame: label a small part of the scan in each of the few most
likely frames, and see in which the labels are confident and make a room.

A network trained on upright rooms knows what an upright chair, a floor under furniture and a
ceiling above it look like. Turned the wrong way, the same points give it shapes it never saw:
its confidence drops, furniture turns to clutter, and a floor (which nearly every indoor scan
has, unlike a ceiling) goes missing. The features below measure that; how much each counts is
fitted with the other evidence in :mod:`jointseg.frame.weigh`.

The frame stage never imports the network: the caller passes a
:data:`~jointseg.labeller.LabelFn` (see :func:`jointseg.network.judge.crop_labeller`).
"""

from __future__ import annotations

import numpy as np

from jointseg.labeller import LabelFn

#: The features of one candidate frame, in order.
FEATURES: tuple[str, ...] = (
    "confidence",
    "floor",
    "ceiling",
    "furniture",
    "clutter",
    "floor_low",
    "wall",
    "ceiling_high",
)
#: S3DIS class indices.
CEILING, FLOOR, WALL, CLUTTER = 0, 1, 2, 12
FURNITURE = (7, 8, 9, 10)  # table, chair, sofa, bookcase
#: Points the judge labels at most (a random subsample; the network grid-subsamples it).
JUDGE_POINTS = 60_000


def net_features(xyz: np.ndarray, probs: np.ndarray) -> np.ndarray:
    """(len(FEATURES),): mean top probability, the shares labelled floor, ceiling, furniture and
    clutter, the share of floor-labelled points in the lowest tenth of the height, the share
    labelled wall, and the share of ceiling-labelled points in the highest tenth."""
    if len(probs) == 0:
        return np.zeros(len(FEATURES))
    labels = probs.argmax(axis=1)
    h = xyz[:, 2]
    lo, hi = np.quantile(h, [0.01, 0.99])
    low = h <= lo + 0.1 * max(hi - lo, 1e-9)
    high = h >= hi - 0.1 * max(hi - lo, 1e-9)
    floor = labels == FLOOR
    ceiling = labels == CEILING
    return np.array(
        [
            float(probs.max(axis=1).mean()),
            float(floor.mean()),
            float(ceiling.mean()),
            float(np.isin(labels, FURNITURE).mean()),
            float((labels == CLUTTER).mean()),
            float((floor & low).sum() / max(int(low.sum()), 1)),
            float((labels == WALL).mean()),
            float((ceiling & high).sum() / max(int(high.sum()), 1)),
        ]
    )


def judge_frames(
    label: LabelFn,
    xyz: np.ndarray,
    rgb: np.ndarray | None,
    rotations: dict[str, np.ndarray],
) -> dict[str, np.ndarray]:
    """The features of each candidate frame.

    Parameters
    ----------
    label : LabelFn
    xyz : ndarray of shape (N, 3)
        The points in metres (any origin), in the file's axes.
    rgb : ndarray of shape (N, 3), optional
        Their colour as the network takes it (None: no usable colour).
    rotations : dict of str to ndarray of shape (3, 3)
        Candidate name to the rotation taking the file's axes to that frame's z up.
    """
    rng = np.random.default_rng(0)
    if len(xyz) > JUDGE_POINTS:
        keep = np.sort(rng.choice(len(xyz), JUDGE_POINTS, replace=False))
        xyz = xyz[keep]
        rgb = None if rgb is None else rgb[keep]
    centred = xyz - np.median(xyz, axis=0)
    out = {}
    for name, rotation in rotations.items():
        judged, probs = label(centred @ rotation.T, rgb)
        out[name] = net_features(judged, probs)
    return out
