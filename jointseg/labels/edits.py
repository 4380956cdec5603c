"""Corrections to a result's labels, by the method's own unit: segments, points or a box.

An edit list is what a user sends (the viewer, ``PATCH /v1/jobs/{id}/labels``, ``jointseg relabel
--edits``); it is validated once here, against the scan it edits, so a bad edit is refused whole
before anything is written. Edits apply in order: a later edit wins where two cover a point.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from jointseg.boxes import in_box
from jointseg.classes import CLASS_INDEX, CLASS_NAMES, NUM_CLASSES
from jointseg.exceptions import ConfigError

#: The class a user gave, per point: -1 where the user gave none.
NO_USER_LABEL = -1
#: Most edits in one request, and most ids (segments or points) all edits name together; a
#: request past either is refused whole (the API's own body limit comes first).
MAX_EDITS = 10_000
MAX_IDS = 50_000_000

ClassRef = Annotated[
    int | str,
    Field(description="A class by name (`wall`) or index (0-12, the S3DIS order)."),
]


class Box(BaseModel):
    """An axis-aligned box in the result file's own coordinates (its units, its axes)."""

    model_config = ConfigDict(extra="forbid")

    min: tuple[float, float, float]
    max: tuple[float, float, float]

    @model_validator(mode="after")
    def _ordered(self) -> Box:
        if any(lo > hi for lo, hi in zip(self.min, self.max, strict=True)):
            raise ValueError(f"box min {list(self.min)} exceeds max {list(self.max)} on an axis")
        return self


class Edit(BaseModel):
    """One correction: every point of the named segments, the named points, or the points
    inside a box get ``label``. Exactly one of ``segments``, ``points`` and ``box``."""

    model_config = ConfigDict(extra="forbid")

    segments: list[int] | None = Field(
        default=None, description="Segment ids (the result's `segment` field)."
    )
    points: list[int] | None = Field(default=None, description="Point indices, 0-based.")
    box: Box | None = Field(default=None, description="A box in the file's coordinates.")
    label: ClassRef

    @model_validator(mode="after")
    def _one_selection(self) -> Edit:
        given = [k for k in ("segments", "points", "box") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(
                f"an edit names exactly one of segments, points or box (got {given or 'none'})"
            )
        return self

    @property
    def class_index(self) -> int:
        """The class as its index (checked by :func:`parse_edits`)."""
        if isinstance(self.label, str):
            return CLASS_INDEX[self.label]
        return int(self.label)


class EditList(BaseModel):
    """The body of a correction: ``{"edits": [...]}``."""

    model_config = ConfigDict(extra="forbid")

    edits: list[Edit] = Field(min_length=1, max_length=MAX_EDITS)


def parse_edits(body: Any, *, max_ids: int = MAX_IDS) -> EditList:
    """An edit list checked for shape, classes and size.

    Parameters
    ----------
    body : object
        The decoded JSON.
    max_ids : int
        Most segment and point ids all edits may name together (a service passes its own
        point limit when lower than :data:`MAX_IDS`).

    Raises
    ------
    ConfigError
        Naming the field (``edits[2].label``) and what is wrong with it.
    """
    try:
        parsed = EditList.model_validate(body)
    except ValidationError as exc:
        problem = exc.errors()[0]
        where = _field_path(problem["loc"])
        raise ConfigError(f"{where}: {problem['msg']}") from None
    total = 0
    for i, edit in enumerate(parsed.edits):
        label = edit.label
        if isinstance(label, str) and label not in CLASS_INDEX:
            raise ConfigError(
                f"edits[{i}].label: unknown class {label!r}; one of {', '.join(CLASS_NAMES)}"
            )
        if isinstance(label, int) and not 0 <= label < NUM_CLASSES:
            raise ConfigError(f"edits[{i}].label: class {label} out of range 0..{NUM_CLASSES - 1}")
        total += len(edit.segments or ()) + len(edit.points or ())
        if total > max_ids:
            raise ConfigError(f"edits[{i}]: more than {max_ids:,} ids in one request")
    return parsed


def _field_path(loc: tuple[Any, ...]) -> str:
    """``("edits", 2, "label", "int")`` as ``edits[2].label``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in ("int", "str", "function-after[_one_selection(), Edit]"):
            continue
        else:
            out += ("." if out else "") + str(part)
    return out or "body"


@dataclass(frozen=True)
class EditOutcome:
    """What a list of edits did.

    Attributes
    ----------
    user_label : ndarray of shape (N,), int16
        The user's class per point after the edits (-1 where the user gave none).
    changed : int
        Points whose label (the version's, user's over the machine's) the edits changed.
    touched : int
        Points the edits covered, changed or not.
    """

    user_label: np.ndarray
    changed: int
    touched: int


def apply_edits(
    edits: EditList,
    *,
    machine_labels: np.ndarray,
    user_label: np.ndarray | None,
    segment: np.ndarray,
    xyz: np.ndarray,
) -> EditOutcome:
    """Apply ``edits`` over a version's user labels; inputs are not changed.

    Parameters
    ----------
    edits : EditList
        From :func:`parse_edits`.
    machine_labels : ndarray of shape (N,), int
        Version 0's labels (the pipeline's ``fused_label``).
    user_label : ndarray of shape (N,), int, optional
        The user's classes so far (-1 for none); None for none yet.
    segment : ndarray of shape (N,), int
        The result's segment per point.
    xyz : ndarray of shape (N, 3)
        The result's coordinates, as its file holds them.

    Raises
    ------
    ConfigError
        For a segment or point id out of range (naming the edit and the id); nothing is applied.
    """
    n = len(machine_labels)
    before = np.full(n, NO_USER_LABEL, np.int16) if user_label is None else user_label
    after = np.array(before, dtype=np.int16, copy=True)
    n_segments = int(segment.max()) + 1 if n and segment.size else 0
    masks = [_selection(i, e, segment, n_segments, xyz, n) for i, e in enumerate(edits.edits)]
    touched = np.zeros(n, bool)
    for edit, mask in zip(edits.edits, masks, strict=True):
        after[mask] = edit.class_index
        touched |= mask
    old = version_labels(machine_labels, before)
    new = version_labels(machine_labels, after)
    return EditOutcome(after, int(np.count_nonzero(old != new)), int(touched.sum()))


def _selection(
    i: int, edit: Edit, segment: np.ndarray, n_segments: int, xyz: np.ndarray, n: int
) -> np.ndarray:
    """The points edit ``i`` covers, as a mask; ids checked first."""
    if edit.segments is not None:
        ids = np.asarray(edit.segments, dtype=np.int64)
        bad = ids[(ids < 0) | (ids >= n_segments)]
        if bad.size:
            raise ConfigError(
                f"edits[{i}].segments: segment {int(bad[0])} out of range 0..{n_segments - 1}"
            )
        wanted = np.zeros(n_segments + 1, bool)
        wanted[ids] = True
        return wanted[np.where(segment < 0, n_segments, segment)]
    if edit.points is not None:
        ids = np.asarray(edit.points, dtype=np.int64)
        bad = ids[(ids < 0) | (ids >= n)]
        if bad.size:
            raise ConfigError(f"edits[{i}].points: point {int(bad[0])} out of range 0..{n - 1}")
        mask = np.zeros(n, bool)
        mask[ids] = True
        return mask
    assert edit.box is not None  # the model allows no other case
    lo, hi = np.asarray(edit.box.min), np.asarray(edit.box.max)
    return in_box(xyz, lo, hi)


def version_labels(machine_labels: np.ndarray, user_label: np.ndarray | None) -> np.ndarray:
    """A version's label per point: the user's class where given, else the machine's."""
    labels = np.asarray(machine_labels, dtype=np.int32)
    if user_label is None:
        return labels.copy()
    return np.where(user_label >= 0, user_label.astype(np.int32), labels)
