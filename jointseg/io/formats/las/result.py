"""A segmented scan's result where LAS tools look for it: the standard ``classification``.

ASPRS gives classes 0..63 fixed meanings (2 ground, 6 building, ...) and leaves 64..255 to the
user (LAS 1.4, point formats 6-10, whose classification is a full byte). jointseg writes the
fused class there, S3DIS class ``i`` as ``64 + i`` (ceiling 64 ... clutter 76), and 1
("unclassified") for a point with no fused class and for a stray point (set aside by the frame
stage; its fused class is only its nearest kept point's). The class names go into the LAS
Classification Lookup record (``LASF_Spec`` record 0), and a ``jointseg`` record 2 marks the
file, so jointseg reading it back does not take the result for the scan's ground truth: the
input's own classification is kept in the extra dimension ``input_classification``.

Point formats 0-5 hold only 5 bits of class (0..31): the result classes do not fit there, which
is why jointseg always writes LAS 1.4 point format 6 or 7.
"""

from __future__ import annotations

import struct
from pathlib import Path

import laspy
import numpy as np

from jointseg.classes import CLASS_NAMES, NUM_CLASSES, UNLABELLED
from jointseg.exceptions import ScanFormatError

#: The first user-definable LAS 1.4 class: S3DIS class ``i`` is written as ``RESULT_BASE + i``.
RESULT_BASE = 64
#: ASPRS class 1, "unclassified": no fused class, or a stray point.
UNCLASSIFIED = 1
#: The field whose classes go into ``classification`` (a scan holding it is a result).
RESULT_FIELD = "fused_label"
#: The extra dimension keeping the input's own classification (its labels) in a result file.
INPUT_CLASSIFICATION = "input_classification"
#: The jointseg VLR marking a file whose classification holds the result.
RESULT_VLR_RECORD_ID = 2
#: The LAS 1.4 Classification Lookup record: (uint8 class, 15-byte description) per entry.
LOOKUP_USER_ID, LOOKUP_RECORD_ID = "LASF_Spec", 0
_LOOKUP_ENTRY = struct.Struct("<B15s")
#: Formats whose classification is a full byte (LAS 1.4 point formats 6-10).
FULL_BYTE_FORMATS = range(6, 11)


def class_names() -> dict[int, str]:
    """Every class code a result file uses, with its name (the lookup record's entries)."""
    names = {UNCLASSIFIED: "unclassified"}
    names.update({RESULT_BASE + i: name for i, name in enumerate(CLASS_NAMES)})
    return names


def result_classification(fused: np.ndarray, stray: np.ndarray | None, *, path: Path) -> np.ndarray:
    """The LAS classification of fused classes: ``64 + class``, 1 where there is no class
    (-1) or the point is a stray.

    Raises
    ------
    ScanFormatError
        When ``fused`` holds a value that is no S3DIS class nor -1 (its name would be unknown).
    """
    values = np.asarray(fused)
    bad = (values < UNLABELLED) | (values >= NUM_CLASSES)
    if bad.any():
        raise ScanFormatError(
            f"{path}: field {RESULT_FIELD!r} holds {values[bad][0]} ({int(bad.sum())} such "
            f"points); a result's fused classes are S3DIS classes 0..{NUM_CLASSES - 1} or -1 "
            f"(none)"
        )
    out = np.where(values < 0, UNCLASSIFIED, values + RESULT_BASE).astype(np.uint8)
    if stray is not None:
        out[np.asarray(stray) != 0] = UNCLASSIFIED
    return out


def check_full_byte(point_format: int, path: Path) -> None:
    """Refuse to put result classes (64..76) into a point format with 5-bit classes."""
    if point_format not in FULL_BYTE_FORMATS:
        raise ScanFormatError(
            f"{path}: LAS point format {point_format} holds classes 0..31 only; the result "
            f"classes {RESULT_BASE}..{RESULT_BASE + NUM_CLASSES - 1} need point format 6-10"
        )


def lookup_vlr() -> laspy.VLR:
    """The Classification Lookup record naming :func:`class_names` (entries for the codes
    used only; readers take as many 16-byte entries as the record holds)."""
    data = b"".join(
        _LOOKUP_ENTRY.pack(code, name.encode("ascii")) for code, name in class_names().items()
    )
    return laspy.VLR(
        user_id=LOOKUP_USER_ID,
        record_id=LOOKUP_RECORD_ID,
        description="Classification Lookup",
        record_data=data,
    )
