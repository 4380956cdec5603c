"""Correcting a job's labels in one tab: the *Edit labels* folder wired to the shown job.

A selection (:mod:`web.selection`) and a class make an edit; it is applied at once to the
tab's own copy of the labels (:mod:`web.editing`): the panels following the fused labels are
sent again only for the class groups whose points changed (:meth:`web.panels.PanelScene.relabel`),
the legend's counts are exact for the whole result, and an object whose shown points changed
takes their commonest class (its box keeps its place, in that class's colour). *Save* sends every
unsaved edit as one edit list with the ETag of the version shown; a save that another came
before is refused (HTTP 412's :class:`PreconditionFailed`) and the tab offers to reload.
*Propose from my corrections* (:mod:`web.proposal_flow`) shows what the corrections teach the
rest of the scan as one step to accept or discard; until then the other edits wait.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from jointseg import exceptions
from jointseg.classes import CLASS_NAMES
from jointseg.exceptions import JointsegError
from web.edit_controls import EditControls
from web.editing import LabelEdits, editable, read_columns, status_line
from web.legend import legend_html
from web.objects_view import objects_html
from web.proposal_flow import PENDING, ProposalFlow
from web.selection import (
    BOX,
    HINTS,
    LASSO,
    OBJECT,
    OFF,
    SEGMENT,
    SLICE,
    Selection,
    of_lasso,
    of_object,
    of_region,
    of_segment,
)
from web.sources import LabelsInfo

if TYPE_CHECKING:
    import threading

    import viser

    from web.address import PageElement
    from web.controls import Controls
    from web.panels import PanelScene
    from web.scene import Panel, SceneData
    from web.sources import JobSource
    from web.tools import Picked


class EditedView(Protocol):
    """What the editing needs of a tab (:class:`web.client_view.ClientView`, which imports
    this module: a protocol keeps the imports one way)."""

    client: viser.ClientHandle
    source: JobSource
    job_id: str | None
    panels: PanelScene
    ui: Controls
    overlay: PageElement
    _lock: threading.RLock

    @property
    def data(self) -> SceneData | None: ...

    def pick(self, origin: np.ndarray, direction: np.ndarray) -> Picked | None: ...

    def visible_panels(self) -> tuple[Panel, ...]: ...

    def show_job(self, job_id: str) -> bool: ...

    def _status_line(self) -> None: ...


log = logging.getLogger(__name__)

#: Another save came first (HTTP 412); a class of :mod:`server.corrections`' errors.
PRECONDITION_FAILED: type[Exception] | tuple[()] = getattr(exceptions, "PreconditionFailed", ())
LASSO_COLOUR = (255, 120, 0)
#: How far in front of the camera the lasso's outline is drawn (it is a line on the screen).
LASSO_DEPTH = 0.5


class LabelEditing:
    """The corrections of one tab."""

    def __init__(self, view: EditedView) -> None:
        self.view = view
        self.ui = EditControls(view.client.gui)
        self.edits: LabelEdits | None = None
        self.info: LabelsInfo | None = None
        self.selection: Selection | None = None
        self.cls: int | None = None
        self.corners: list[np.ndarray] = []  # the lasso's rays
        self.eye: np.ndarray | None = None
        self.ui.mode.on_update(lambda _: self.reselect())
        self.ui.on_class(self.give)
        self.ui.apply.on_click(lambda _: self.apply())
        self.ui.undo.on_click(lambda _: self.step(redo=False))
        self.ui.redo.on_click(lambda _: self.step(redo=True))
        self.ui.save.on_click(lambda _: self.save())
        self.ui.reload.on_click(lambda _: self.reload())
        self.proposals = ProposalFlow(self.ui, view.client, view._lock, self)

    @property
    def active(self) -> bool:
        """Whether clicks on the scene select (not the click tools)."""
        return self.view.data is not None and str(self.ui.mode.value) != OFF

    # -------------------------------------------------------------- the job
    def show_job(self, job_id: str) -> None:
        """A job shown (anew): its version, no edits, no selection."""
        self.edits, self.selection = None, None
        self.proposals.reset()
        try:
            self.info = self.view.source.labels(job_id)
        except (JointsegError, OSError) as exc:
            log.warning("labels version of %s unknown: %s", job_id, exc)
            self.info = LabelsInfo(refusal=str(exc))
        self.ui.reload.visible = False
        self.reselect()

    def clear(self) -> None:
        """No job to edit."""
        self.edits, self.info, self.selection = None, None, None
        self.proposals.reset()
        self._forget_lasso()
        self.ui.version.content = "No job to edit."
        self.ui.selection.content = HINTS[str(self.ui.mode.value)]

    def _editor(self) -> LabelEdits:
        """The tab's edits of the shown job, reading every row on first use."""
        view = self.view
        if self.edits is None:
            assert view.data is not None and view.job_id is not None
            columns = read_columns(view.source.result_path(view.job_id))
            copy = editable(view.data)
            view.panels.data = copy  # this tab draws its own labels from now on
            self.edits = LabelEdits(copy, columns, self.info or LabelsInfo())
        return self.edits

    def current_editor(self) -> LabelEdits | None:
        """The tab's edits for a proposal (None: no job, or its rows cannot be read: told)."""
        if self.view.data is None or self.view.job_id is None:
            return None
        try:
            return self._editor()
        except (JointsegError, OSError) as exc:
            self.view.client.add_notification("No proposal", str(exc), color="red")
            return None

    def result_of_job(self) -> tuple[Path, dict[str, Any] | None] | None:
        """The shown job's result file and report (for a proposal)."""
        view = self.view
        if view.job_id is None or view.data is None:
            return None
        try:
            return view.source.result_path(view.job_id), view.data.report
        except (JointsegError, OSError) as exc:
            view.client.add_notification("No proposal", str(exc), color="red")
            return None

    # ------------------------------------------------------------ selecting
    def reselect(self) -> None:
        """The mode changed (or the job): a region is selected at once, a click mode waits."""
        with self.view._lock:
            mode = str(self.ui.mode.value)
            self.selection = None
            self._forget_lasso()
            if mode in (BOX, SLICE) and self.view.data is not None:
                box, heights = self.view.ui.clip.ranges()
                what = "the clip box" if mode == BOX else "the slice"
                box, heights = (box, None) if mode == BOX else (None, heights)
                data = self.view.data
                self.selection = self._guarded(
                    lambda: of_region(data, self._editor().columns, box, heights, what)
                )
                if self.selection is None and box is None and heights is None:
                    self.ui.selection.content = f"Switch on {what} in *Clip and slice* first."
                    return
            self._tell()

    def clicked(self, origin: np.ndarray, direction: np.ndarray) -> bool:
        """A click on the scene: select with it when a selection mode is on (True)."""
        if not self.active:
            return False
        view, mode = self.view, str(self.ui.mode.value)
        with view._lock:
            data = view.data
            assert data is not None
            if mode == LASSO:
                self._corner(origin, direction)
                return True
            if mode not in (SEGMENT, OBJECT):
                return True
            hit = view.pick(origin, direction)
            if hit is None:
                self.ui.selection.content = "No point under the click."
                return True
            if mode == SEGMENT:
                self.selection = of_segment(data, hit.index)
            else:
                self.selection = self._guarded(
                    lambda: of_object(data, self._editor().columns, hit.index)
                )
                if self.selection is None:
                    self.ui.selection.content = "That point is in no object."
                    return True
            self._tell()
        return True

    def _corner(self, origin: np.ndarray, direction: np.ndarray) -> None:
        """One more corner of the lasso; the selection follows from the third."""
        view = self.view
        if self.eye is None:
            self.eye = origin
        self.corners.append(direction / np.linalg.norm(direction))
        rays = np.asarray(self.corners)
        line = self.eye + LASSO_DEPTH * rays
        loop = np.stack([line, np.roll(line, -1, axis=0)], axis=1).astype(np.float32)
        view.client.scene.add_line_segments(
            "/jointseg_lasso", loop, LASSO_COLOUR, thickness=3.0, thickness_units="screen"
        )
        data = view.data
        if len(self.corners) >= 3 and data is not None:
            eye = self.eye
            self.selection = self._guarded(
                lambda: of_lasso(data, self._editor().columns, eye, rays, view.panels.offsets())
            )
        self._tell(f"Lasso: {len(self.corners)} corners.")

    def _forget_lasso(self) -> None:
        if self.corners:
            self.view.client.scene.remove_by_name("/jointseg_lasso")
        self.corners, self.eye = [], None

    def _guarded(self, select: object) -> Selection | None:
        """A selection that may need every row read; a result that cannot be is told."""
        try:
            return select()  # type: ignore[operator,no-any-return]
        except (JointsegError, OSError) as exc:
            self.view.client.add_notification("Cannot select", str(exc), color="red")
            return None

    def _tell(self, note: str = "") -> None:
        """The selection line and the version line."""
        chosen = "" if self.cls is None else f" Class: **{CLASS_NAMES[self.cls]}**."
        if self.selection is not None:
            text = f"Selected: {self.selection.what}.{chosen}"
        else:
            text = note or HINTS[str(self.ui.mode.value)]
        self.ui.selection.content = text
        self._version_line()

    def _version_line(self) -> None:
        info = (self.edits.info if self.edits else self.info) or LabelsInfo()
        line = status_line(info, self.edits.unsaved if self.edits else 0)
        if info.refusal:
            line += f"  \n{info.refusal}"
        self.ui.version.content = line if self.view.data is not None else "No job to edit."
        corrected = bool(self.edits and self.edits.unsaved) or info.version > 0
        self.proposals.sync(corrected and self.view.data is not None)

    # -------------------------------------------------------------- editing
    def give(self, cls: int) -> None:
        """A class button or its key: the class of the next edits, applied to the selection."""
        self.cls = cls
        if self.proposals.pending is not None:
            self._tell(PENDING)
            return
        if self.selection is None:
            self._tell("Class chosen; now select what it is for.")
            return
        self.apply()

    def apply(self) -> None:
        """Give the selection the chosen class (every point of the result it covers)."""
        view = self.view
        if self.proposals.pending is not None:
            self._tell(PENDING)
            return
        if self.selection is None or self.cls is None or view.data is None:
            self._tell("Select something and choose a class first.")
            return
        with view._lock:
            try:
                classes = self._editor().apply(self.selection.edit(self.cls))
            except (JointsegError, OSError) as exc:
                view.client.add_notification("Cannot apply", str(exc), color="red")
                return
            log.info("client %d: %s -> %s", view.client.client_id, self.selection.what, self.cls)
            self._forget_lasso()
            self.redraw(bool(classes))

    def step(self, *, redo: bool) -> None:
        """Undo the last edit, or redo the last undone (a proposal shown: Undo discards it)."""
        with self.view._lock:
            if self.proposals.pending is not None:
                if redo:
                    self._tell(PENDING)
                else:
                    self.proposals.discard()
                return
            if self.edits is None:
                return
            classes = self.edits.redo() if redo else self.edits.undo()
            if classes is None:
                self._tell(f"Nothing to {'redo' if redo else 'undo'}.")
                return
            self.redraw(True)

    def redraw(self, changed: bool) -> None:
        """After an edit: the panels' changed groups, the legend's counts, the objects, the
        status and version lines, in one update."""
        view = self.view
        data = view.data
        if data is None:
            return
        with view.client.atomic():
            if changed:
                view.panels.relabel(view.visible_panels())
            view.ui.legend.content = legend_html(data.counts)
            listing = objects_html(data)
            if listing is not None:
                view.ui.objects_table.content = listing
            view._status_line()
            self._tell()
        view.client.flush()
        view.overlay.sync()  # the legend over the canvas counts too

    def save(self) -> None:
        """Send every unsaved edit as one list over the version shown (its ETag)."""
        view = self.view
        with view._lock:
            if self.proposals.pending is not None:
                self._tell(PENDING)
                return
            edits, job_id = self.edits, view.job_id
            body = None if edits is None else edits.edit_list()
            if edits is None or body is None or job_id is None:
                self._tell("Nothing to save.")
                return
            try:
                info = view.source.save_edits(job_id, body, if_match=edits.info.etag)
            except PRECONDITION_FAILED:
                self.ui.reload.visible = True
                self.ui.version.content = (
                    "**Someone else saved these labels first.** Your edits are kept here, "
                    "unsaved; *Reload saved labels* shows theirs (and drops yours)."
                )
                view.client.add_notification(
                    "Not saved", "Someone else saved these labels first.", color="yellow"
                )
                return
            except (JointsegError, OSError) as exc:
                view.client.add_notification("Not saved", str(exc), color="red")
                self._tell()
                return
            edits.saved(info)
            self.info = info
            self._tell()
        view.client.add_notification(
            "Saved", f"Labels version {info.version} saved.", auto_close_seconds=5.0
        )

    def reload(self) -> None:
        """Show the job's saved labels (the latest version), dropping unsaved edits."""
        job_id = self.view.job_id
        if job_id is not None:
            self.view.show_job(job_id)
