"""The *Frame* folder: what the frame stage decided for the shown job, and the way to correct it.

The frame stage (:mod:`jointseg.frame`) decides which file axis is up, how far the scan was
levelled and the coordinates' unit, each with a confidence; a warning means it was unsure
(report.json's ``frame`` section). A wrong decision is corrected by re-running the job from its
stored upload with another up axis or unit (``POST /v1/jobs/{id}/rerun``: a new job, the old one
unchanged).

The viewer does not start that re-run itself. It holds no API key (a tab signs in for a session
and the key is not kept) and no queue (its process only reads the job table and the files,
:mod:`web.service_source`), and a second way to create jobs would need the API's checks and
ownership rules again. So *Re-run with this frame* opens the job page's frame box on this job
with the choice made here (``/#frame=<id>&up=<axis>&units=<unit>``), where the page's saved key
starts it in one click. On a folder of results (no job service) the folder shows the decision
alone.
"""

from __future__ import annotations

import json
import logging
from typing import Any
from urllib.parse import urlencode

import viser

from web.view_state import script_html

log = logging.getLogger(__name__)

#: The up axes a re-run can name (the frame stage's signed file axes).
UP_AXES = ("+z", "-z", "+y", "-y", "+x", "-x")
#: The units a re-run can name (jointseg.frame.params.UnitsChoice without "auto").
UNITS = ("m", "cm", "mm", "ft", "us-ft", "in")
#: What the folder says when the job's report has no frame section.
NO_FRAME = "This job's report has no frame decision."
#: What it says where there is no job page to re-run on.
NO_SERVICE = "Re-running with another frame needs the job service's job page."


def flipped(axis: str) -> str:
    """The opposite direction of the same axis: ``+y`` -> ``-y``."""
    return ("+" if axis.startswith("-") else "-") + axis[1:]


def decision_markdown(frame: dict[str, Any]) -> str:
    """The frame section as the folder shows it: up axis, tilt, units with their confidence;
    each warning marked unsure."""
    up, units = frame.get("up") or {}, frame.get("units") or {}
    warnings = [str(w) for w in frame.get("warnings") or []]
    up_unsure = any(w.startswith("up axis") for w in warnings)
    units_unsure = any("units" in w or "tall" in w for w in warnings)
    levelled = "levelled" if up.get("levelled") else "not levelled"
    lines = [
        f"- **Up axis** {up.get('axis', '?')}, confidence {_number(up.get('confidence'))}"
        + (" · **unsure**" if up_unsure else ""),
        f"- **Tilt** {_number(up.get('tilt_degrees'), 1)}°, {levelled}",
        f"- **Units** {units.get('unit', '?')}, confidence {_number(units.get('confidence'))}"
        + (" · **unsure**" if units_unsure else ""),
    ]
    lines += [f"- ⚠ unsure: {w}" for w in warnings]
    return "\n".join(lines)


def job_page_script(port: int, job_id: str, up: str, units: str) -> str:
    """JavaScript that opens the job page (the API's port on the viewer's own host) on the frame
    box of ``job_id`` with ``up`` and ``units`` chosen, in a new tab."""
    fragment = urlencode({"frame": job_id, "up": up, "units": units})
    address = f"location.protocol+'//'+location.hostname+':{int(port)}/#'+{json.dumps(fragment)}"
    return f"window.open({address},'_blank','noopener');"


class FramePanel:
    """The *Frame* folder of a tab.

    Parameters
    ----------
    gui : viser.GuiApi
        The tab's control panel.
    job_page_port : int, optional
        The job page's port (the API's) on the viewer's host; None: no job service, the
        decision is shown alone.
    """

    def __init__(self, gui: viser.GuiApi, job_page_port: int | None) -> None:
        self.port = job_page_port
        self.job_id: str | None = None
        self._serial = 0
        with gui.add_folder("Frame", expand_by_default=False, visible=False) as self.folder:
            self.decision = gui.add_markdown(NO_FRAME)
            self.up = gui.add_dropdown("Up axis", UP_AXES, hint="the file axis that points up")
            self.flip = gui.add_button("Flip up", hint="up to the opposite side of the same axis")
            self.units = gui.add_dropdown("Units", UNITS, hint="the coordinates' unit")
            self.rerun = gui.add_button(
                "Re-run with this frame",
                hint="opens the job page's frame box on this job (it holds the API key)",
            )
            self.note = gui.add_markdown(NO_SERVICE, visible=job_page_port is None)
            self.opener = gui.add_html("")
        self.flip.on_click(lambda _: self._flip())
        self.rerun.on_click(lambda _: self.open_job_page())

    @property
    def controls(self) -> tuple[Any, ...]:
        """The controls of a re-run (shown only with a job page)."""
        return (self.up, self.flip, self.units, self.rerun)

    def show_job(self, job_id: str, report: dict[str, Any] | None) -> None:
        """The decision of ``job_id`` (its report's frame section), the controls at it."""
        self.job_id = job_id
        frame = (report or {}).get("frame")
        self.folder.visible = True
        if not isinstance(frame, dict):
            self.decision.content = NO_FRAME
            for control in self.controls:
                control.visible = False
            return
        self.decision.content = decision_markdown(frame)
        axis = str((frame.get("up") or {}).get("axis", "+z"))
        unit = str((frame.get("units") or {}).get("unit", "m"))
        _set(self.up, axis if axis in UP_AXES else "+z")
        _set(self.units, unit if unit in UNITS else "m")
        for control in self.controls:
            control.visible = self.port is not None

    def clear(self) -> None:
        """No job shown: the folder hides."""
        self.job_id = None
        self.folder.visible = False

    def _flip(self) -> None:
        _set(self.up, flipped(str(self.up.value)))

    def open_job_page(self) -> None:
        """Open the job page's frame box on the shown job with the choice made here."""
        if self.port is None or self.job_id is None:
            return
        up, units = str(self.up.value), str(self.units.value)
        self._serial += 1
        script = job_page_script(self.port, self.job_id, up, units)
        self.opener.content = script_html(script, self._serial, "frame")
        log.info(
            "job %s: the job page opened to re-run with up %s, units %s", self.job_id, up, units
        )


def _number(value: Any, digits: int = 2) -> str:
    """A report's number to ``digits`` decimals, ``?`` when missing."""
    return "?" if not isinstance(value, int | float) else f"{float(value):.{digits}f}"


def _set(handle: Any, value: str) -> None:
    handle.value = value  # viser types it read-only
