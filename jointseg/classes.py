"""The 13 S3DIS classes in the standard order and the one palette used everywhere.

Defined once: the CLI, exports and the viewer all read these constants.
"""

from __future__ import annotations

import numpy as np

CLASS_NAMES: tuple[str, ...] = (
    "ceiling",
    "floor",
    "wall",
    "beam",
    "column",
    "window",
    "door",
    "table",
    "chair",
    "sofa",
    "bookcase",
    "board",
    "clutter",
)
NUM_CLASSES: int = len(CLASS_NAMES)
UNLABELLED: int = -1
CLASS_INDEX: dict[str, int] = {name: i for i, name in enumerate(CLASS_NAMES)}

#: RGB colour per class (uint8), distinct enough to tell apart side by side.
PALETTE: np.ndarray = np.array(
    [
        (233, 229, 107),  # ceiling: pale yellow
        (95, 156, 196),  # floor: steel blue
        (179, 116, 81),  # wall: brown
        (241, 149, 131),  # beam: salmon
        (81, 163, 148),  # column: teal
        (77, 174, 84),  # window: green
        (108, 135, 75),  # door: olive
        (41, 49, 101),  # table: navy
        (79, 79, 76),  # chair: dark grey
        (223, 52, 52),  # sofa: red
        (89, 47, 95),  # bookcase: purple
        (81, 109, 114),  # board: slate
        (233, 233, 229),  # clutter: off-white
    ],
    dtype=np.uint8,
)
PALETTE.setflags(write=False)

#: Colour for points labelled -1.
UNLABELLED_COLOUR: tuple[int, int, int] = (0, 0, 0)


def colourise(labels: np.ndarray) -> np.ndarray:
    """Map labels to palette colours.

    Parameters
    ----------
    labels : ndarray of shape (N,), int
        Class indices; -1 (unlabelled) and out-of-range values map to black.

    Returns
    -------
    ndarray of shape (N, 3), uint8
    """
    labels = np.asarray(labels)
    out = np.zeros((labels.shape[0], 3), dtype=np.uint8)
    ok = (labels >= 0) & (labels < NUM_CLASSES)
    out[ok] = PALETTE[labels[ok]]
    return out


def class_name(label: int) -> str:
    """Name of class ``label``, ``"unlabelled"`` for -1."""
    if label == UNLABELLED:
        return "unlabelled"
    if 0 <= label < NUM_CLASSES:
        return CLASS_NAMES[label]
    raise ValueError(f"label {label} is not an S3DIS class index (0..{NUM_CLASSES - 1} or -1)")
