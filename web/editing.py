"""A tab's unsaved corrections to the labels of the job it shows: apply, undo, redo, save.

The viewer draws an even sample of a result's rows, but an edit is about the whole result: a
segment is every point of it, a region every point inside. So the first edit of a job reads the
columns an edit needs (xyz, ``segment``, ``fused_label``, ``instance``) of every row, block by
block (:mod:`jointseg.io.formats.ply.blocks`), and applies each edit to them with the library's own
:func:`jointseg.labels.edits.apply_edits`: the legend's counts stay exact, and what is saved is
what was seen. Memory: 30 bytes a point while a tab edits (a 10 M point result: 300 MB).

Each tab edits its own copy of the shown sample's labels (the loaded scene is shared by the
tabs through :class:`web.scene.SceneCache`): another tab sees a correction once it is saved.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.exceptions import JobStateError
from jointseg.io import read_scan
from jointseg.io.formats.ply.blocks import open_vertex_blocks
from jointseg.labels.edits import Edit, EditList, apply_edits
from web.objects_view import objects_of
from web.scene import SceneData
from web.sources import LabelsInfo

log = logging.getLogger(__name__)

#: Most points a tab reads to edit (30 bytes each, while it edits).
MAX_EDIT_POINTS = 60_000_000
#: Bytes read at a time.
BLOCK_BYTES = 16 << 20


@dataclass(frozen=True, eq=False)
class Columns:
    """Every row of a result, as edits need it: file coordinates, segment, label, object."""

    xyz: np.ndarray
    segment: np.ndarray
    fused: np.ndarray
    instance: np.ndarray | None


def read_columns(path: Path) -> Columns:
    """The columns of every row of a result file (binary PLY by blocks, other formats whole)."""
    source = open_vertex_blocks(path) if path.suffix.lower() == ".ply" else None
    if source is None:
        scan = read_scan(path)
        instance = scan.fields.get("instance")
        return Columns(
            np.asarray(scan.xyz, np.float64),
            np.asarray(scan.fields["segment"], np.int32),
            np.asarray(scan.fields["fused_label"], np.int16),
            None if instance is None else np.asarray(instance, np.int32),
        )
    if source.count > MAX_EDIT_POINTS:
        raise JobStateError(
            f"{source.count:,} points: the viewer edits results of up to {MAX_EDIT_POINTS:,}; "
            "use `jointseg relabel --edits`"
        )
    n, has_instance = source.count, "instance" in source.names
    xyz = np.empty((n, 3), np.float64)
    segment, fused = np.empty(n, np.int32), np.empty(n, np.int16)
    instance = np.empty(n, np.int32) if has_instance else None
    for block in source.blocks(BLOCK_BYTES):
        part = slice(block.start, block.start + len(block.records))
        for axis, name in enumerate("xyz"):
            xyz[part, axis] = block.column(name)
        segment[part] = block.column("segment")
        fused[part] = block.column("fused_label")
        if instance is not None:
            instance[part] = block.column("instance")
    return Columns(xyz, segment, fused, instance)


@dataclass(frozen=True, eq=False)
class Step:
    """One applied step (an edit, or an accepted proposal's edits): the rows of the file whose
    class it changed, their classes before and after."""

    edits: tuple[Edit, ...]
    rows: np.ndarray
    before: np.ndarray
    after: np.ndarray


def editable(data: SceneData) -> SceneData:
    """A tab's own copy of a shown job's labels, counts and objects (the arrays drawn from)."""
    report = None if data.report is None else dict(data.report)
    if report is not None and isinstance(report.get("objects"), list):
        report["objects"] = [dict(o) for o in report["objects"]]
    rows = data.rows if data.rows is not None else np.arange(data.xyz.shape[0], dtype=np.int64)
    return replace(
        data,
        fused=data.fused.copy(),
        changed=data.changed.copy(),
        counts={**data.counts, "fused": data.counts["fused"].copy()},
        report=report,
        rows=rows,
    )


def _count_index(labels: np.ndarray) -> np.ndarray:
    """Classes as indices of a counts array (the last entry counts unlabelled points)."""
    labels = np.asarray(labels, np.int64)
    return np.where((labels >= 0) & (labels < NUM_CLASSES), labels, NUM_CLASSES)


class LabelEdits:
    """Unsaved edits of one job in one tab, over the version it shows.

    Parameters
    ----------
    data : SceneData
        The tab's own copy (:func:`editable`); its sample labels, counts and objects follow.
    columns : Columns
        Every row of the shown version's result.
    info : LabelsInfo
        The version shown and its ETag (sent with the save).
    """

    def __init__(self, data: SceneData, columns: Columns, info: LabelsInfo) -> None:
        self.data = data
        self.columns = columns
        self.info = info
        self.labels = columns.fused.astype(np.int16)
        self.done: list[Step] = []
        self.undone: list[Step] = []
        #: Counts changes of :attr:`labels` (a proposal made over older labels is stale).
        self.revision = 0

    @property
    def unsaved(self) -> int:
        """Edits applied since the version shown (and not undone)."""
        return len(self.done)

    def apply(self, edit: Edit) -> set[int]:
        """Apply ``edit`` to every row; the classes whose points changed (new redo history).

        Raises
        ------
        ConfigError
            For an id out of range (nothing applied).
        """
        return self.apply_all([edit])

    def apply_all(self, edits: Sequence[Edit]) -> set[int]:
        """Apply ``edits`` in order as one step (one undo takes them all back, as a proposal
        accepted is one decision); the classes whose points changed (new redo history)."""
        cols = self.columns
        outcome = apply_edits(
            EditList(edits=list(edits)),
            machine_labels=self.labels,
            user_label=None,
            segment=cols.segment,
            xyz=cols.xyz,
        )
        rows = np.flatnonzero((outcome.user_label >= 0) & (outcome.user_label != self.labels))
        after = outcome.user_label[rows].astype(np.int16)
        step = Step(tuple(edits), rows, self.labels[rows].copy(), after)
        self.done.append(step)
        self.undone.clear()
        return self._set(rows, after)

    def undo(self) -> set[int] | None:
        """Take back the last step; the classes changed (None: nothing to undo)."""
        if not self.done:
            return None
        step = self.done.pop()
        self.undone.append(step)
        return self._set(step.rows, step.before)

    def redo(self) -> set[int] | None:
        """Apply the last step undone again; the classes changed (None: nothing to redo)."""
        if not self.undone:
            return None
        step = self.undone.pop()
        self.done.append(step)
        return self._set(step.rows, step.after)

    def withdraw(self, undone: list[Step]) -> set[int] | None:
        """Take back the last step as if it never was: no redo of it, the redo history it
        replaced (``undone``) back. A proposal discarded (None: nothing to take back)."""
        if not self.done:
            return None
        step = self.done.pop()
        self.undone = list(undone)
        return self._set(step.rows, step.before)

    def edit_list(self) -> EditList | None:
        """Every unsaved edit, in order, as one request (None: none)."""
        return EditList(edits=[e for s in self.done for e in s.edits]) if self.done else None

    def _set(self, rows: np.ndarray, values: np.ndarray) -> set[int]:
        """Give ``rows`` of the file ``values``: the full labels, the counts, the sample's
        labels and change flags, the objects' classes. Returns the classes involved."""
        data = self.data
        self.revision += 1
        before = self.labels[rows]
        counts = data.counts["fused"]
        np.subtract.at(counts, _count_index(before), 1)
        np.add.at(counts, _count_index(values), 1)
        self.labels[rows] = values
        assert data.rows is not None  # editable() sets it
        where = np.searchsorted(data.rows, rows)
        hit = where < data.rows.size
        hit[hit] = data.rows[where[hit]] == rows[hit]
        shown, new = where[hit], values[hit]
        data.fused[shown] = new
        data.changed[shown] = data.network[shown] != data.fused[shown]
        self._reclass_objects(shown)
        classes = {int(c) for c in np.unique(before)} | {int(c) for c in np.unique(values)}
        return {c if 0 <= c < NUM_CLASSES else -1 for c in classes}

    def _reclass_objects(self, shown: np.ndarray) -> None:
        """An object some of whose shown points changed takes the class most of its shown
        points now have (its box stays where the run found it)."""
        data = self.data
        if data.instance is None or shown.size == 0:
            return
        ids = {int(i) for i in np.unique(data.instance[shown]) if i >= 0}
        for obj in objects_of(data):
            if obj.get("id") not in ids:
                continue
            labels = data.fused[data.instance == obj["id"]]
            labels = labels[(labels >= 0) & (labels < NUM_CLASSES)]
            if labels.size:
                obj["cls"] = CLASS_NAMES[int(np.bincount(labels).argmax())]

    def saved(self, info: LabelsInfo) -> None:
        """The edits were saved as ``info``'s version: nothing is unsaved any more."""
        self.info = info
        self.done.clear()
        self.undone.clear()


def status_line(info: LabelsInfo, unsaved: int) -> str:
    """``labels version 1 (1,234 points corrected) · 2 unsaved edits``."""
    corrected = f" ({info.corrected:,} points corrected)" if info.version else " (the run's own)"
    edits = (
        "no unsaved edits" if not unsaved else f"**{unsaved} unsaved edit{'s' * (unsaved > 1)}**"
    )
    return f"Labels version {info.version}{corrected} · {edits}"
