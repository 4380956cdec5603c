"""A tab's proposal from its corrections: *Propose from my corrections*, then *Accept proposal*
or *Discard proposal* (the buttons of :class:`web.edit_controls.EditControls`).

The proposal is made in a worker thread (seconds: :mod:`web.proposals`), so the tab keeps
answering. Once made it is shown as one step of the tab's edits (the proposed segments drawn
in their proposed classes, the legend and objects following): *Accept* keeps that step (one
*Undo* takes it back, *Save* saves it as any edit), *Discard* withdraws it as if it never was.
A proposal made over labels that changed meanwhile (an edit, another job) is dropped.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from jointseg.labels.edits import Edit
from web.proposals import ProposalError, Snapshot, describe, make_proposal

if TYPE_CHECKING:
    import viser

    from jointseg.adapt.spread import Proposal
    from web.edit_controls import EditControls
    from web.editing import LabelEdits, Step

log = logging.getLogger(__name__)

PROPOSING = "Proposing from your corrections… (a few seconds)"
STALE = "Your labels changed while the proposal was made; propose again."
PENDING = "Accept or discard the proposal first."


class ProposalHost(Protocol):
    """What the flow needs of the tab's editing (:class:`web.label_editing.LabelEditing`)."""

    edits: LabelEdits | None

    def current_editor(self) -> LabelEdits | None: ...

    def result_of_job(self) -> tuple[Path, dict[str, Any] | None] | None: ...

    def redraw(self, changed: bool) -> None: ...


@dataclass(eq=False)
class Pending:
    """A proposal shown and not yet decided: the last step of ``editor`` and the redo history
    it replaced."""

    editor: LabelEdits
    undone: list[Step]
    proposal: Proposal


class ProposalFlow:
    """The proposal of one tab."""

    def __init__(
        self, ui: EditControls, client: viser.ClientHandle, lock: threading.RLock, host: Any
    ) -> None:
        self.ui, self.client, self.lock = ui, client, lock
        self.host: ProposalHost = host
        self.running: tuple[LabelEdits, int] | None = None  # the editor and its revision
        self.pending: Pending | None = None
        ui.propose.on_click(lambda _: self.start())
        ui.accept.on_click(lambda _: self.accept())
        ui.discard.on_click(lambda _: self.discard())

    def sync(self, corrected: bool) -> None:
        """*Propose* is for a tab with corrections, one proposal at a time."""
        self.ui.propose.disabled = not corrected or self.running is not None or bool(self.pending)

    def reset(self) -> None:
        """Another job (or none): a proposal shown is forgotten with the edits it was in."""
        self.pending = None
        self._buttons(False)
        self._say("")

    # ------------------------------------------------------------ proposing
    def start(self) -> None:
        """Take the tab's corrections and make their proposal in a worker thread."""
        with self.lock:
            if self.running is not None or self.pending is not None:
                return
            editor, where = self.host.current_editor(), self.host.result_of_job()
            if editor is None or where is None:
                self._tell("No proposal", "Show a job and correct some segments first.", "yellow")
                return
            labels, edits = editor.labels.copy(), editor.edit_list()
            snap = Snapshot(where[0], editor.columns, labels, edits, where[1])
            self.running = (editor, editor.revision)
            self.ui.propose.disabled = True
            self._say(PROPOSING)
        busy = self.client.add_notification("Proposing", PROPOSING, loading=True)
        log.info("client %d: proposing from %s", self.client.client_id, snap.path.name)
        threading.Thread(
            target=self._work, args=(snap, busy), name="jointseg-propose", daemon=True
        ).start()

    def _work(self, snap: Snapshot, busy: Any) -> None:
        """The worker thread: a proposal or the words of why there is none."""
        proposal: Proposal | None = None
        try:
            proposal, problem = make_proposal(snap), ""
        except ProposalError as exc:
            problem = str(exc)
        except Exception as exc:  # the thread's last guard: logged whole, told in words
            log.exception("proposal of %s failed", snap.path.name)
            problem = f"No proposal: {type(exc).__name__}: {exc}"
        finally:
            busy.remove()
        self._finish(proposal, problem)

    def _finish(self, proposal: Proposal | None, problem: str) -> None:
        """Show the proposal as a step of the tab's edits, or say why there is none."""
        with self.lock:
            started, self.running = self.running, None
            editor = self.host.edits
            if problem or proposal is None:
                self._say(problem)
                self._tell("No proposal", problem, "red")
            elif started is None or editor is not started[0] or editor.revision != started[1]:
                self._say(STALE)
                self._tell("Proposal dropped", STALE, "yellow")
            elif len(proposal.segments) == 0:
                self._say(describe(proposal))
                self._tell("Nothing to propose", describe(proposal), None)
            else:
                self._show(editor, proposal)
                return
            self.host.redraw(False)

    def _show(self, editor: LabelEdits, proposal: Proposal) -> None:
        undone = list(editor.undone)
        editor.apply_all([Edit.model_validate(e) for e in proposal.edits()])
        self.pending = Pending(editor, undone, proposal)
        text = describe(proposal)
        self._say(f"**Proposed**: {text}. Accept or discard it.")
        self._buttons(True)
        self._tell("Proposal", text, None)
        log.info("client %d: proposed %s", self.client.client_id, text)
        self.host.redraw(True)

    # ------------------------------------------------------------- deciding
    def accept(self) -> None:
        """Keep the proposal: it stays as one ordinary, unsaved edit."""
        with self.lock:
            pending, self.pending = self.pending, None
            if pending is None:
                return
            self._buttons(False)
            self._say(f"Accepted: {describe(pending.proposal)} (one edit: Undo takes it back).")
            self.host.redraw(False)

    def discard(self) -> None:
        """Drop the proposal: the labels (and the redo history) as they were before it."""
        with self.lock:
            pending, self.pending = self.pending, None
            if pending is None:
                return
            self._buttons(False)
            self._say("Proposal discarded.")
            if self.host.edits is pending.editor:
                pending.editor.withdraw(pending.undone)
                self.host.redraw(True)

    # ---------------------------------------------------------------- words
    def _buttons(self, shown: bool) -> None:
        self.ui.accept.visible = shown
        self.ui.discard.visible = shown

    def _say(self, text: str) -> None:
        self.ui.proposal.content = text
        self.ui.proposal.visible = bool(text)

    def _tell(self, title: str, body: str, color: Any) -> None:
        self.client.add_notification(title, body, color=color, auto_close_seconds=8.0)
