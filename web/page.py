"""The job page: plain HTML and JavaScript served by the API at ``/``, no build step.

The page itself and its two assets are public (they hold no data); everything it shows comes
from the /v1 API, called with the API key the user typed (kept in the browser's localStorage
and sent as ``Authorization: Bearer``). ``/web/config.json`` tells the page where the viewer
listens, so it can link each finished job to it.
"""

from __future__ import annotations

import json
import logging
import re
from importlib import resources
from pathlib import Path
from typing import Any

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import HTMLResponse, Response
from pydantic import BaseModel, Field

from jointseg.io import READ_EXTENSIONS
from jointseg.network.registry import installed_backends

log = logging.getLogger(__name__)

#: The page's assets and their media types (nothing else under web/static is served).
ASSETS: dict[str, str] = {
    "jobs.js": "text/javascript; charset=utf-8",
    "style.css": "text/css; charset=utf-8",
}
#: Where the viewer process records the port it actually listens on (in the data directory).
VIEWER_FILE = "viewer.json"


class PageConfig(BaseModel):
    """What the job page needs to know besides the API."""

    viewer_port: int = Field(description="Port of the viewer, on the same host as the page.")
    networks: list[str] = Field(
        description="Network backends a job can choose: those with weights on this service "
        "(the API refuses a job for any other)."
    )


def _static(name: str) -> bytes:
    return resources.files("web").joinpath("static", name).read_bytes()


def page_html() -> bytes:
    """The job page, its file picker offering every extension the readers take (the list in
    ``index.html`` is replaced by :data:`jointseg.io.READ_EXTENSIONS`, so a new format shows
    up without editing the page)."""
    html = _static("index.html").decode("utf-8")
    accept = f'accept="{",".join(READ_EXTENSIONS)}"'
    return re.sub(r'accept="[^"]*"', accept, html, count=1).encode("utf-8")


def viewer_port(settings: Any) -> int:
    """The port the viewer listens on: what its process recorded, else the configured one."""
    recorded = Path(settings.data_dir) / VIEWER_FILE
    try:
        return int(json.loads(recorded.read_text(encoding="utf-8"))["port"])
    except (OSError, ValueError, KeyError, TypeError):
        return int(settings.viewer_port)


def job_page_router() -> APIRouter:
    """The routes of the job page: ``/``, ``/web/config.json`` and ``/web/<asset>``."""
    router = APIRouter(tags=["job page"])

    @router.get("/", response_class=HTMLResponse, include_in_schema=False)
    def index() -> HTMLResponse:
        """The job page."""
        return HTMLResponse(page_html(), headers={"Cache-Control": "no-cache"})

    @router.get("/web/config.json", response_model=PageConfig, include_in_schema=False)
    def config(request: Request) -> PageConfig:
        """Where the viewer is and which networks can be chosen (asked on every load, so a
        network whose weights were pulled since shows up without a restart)."""
        settings = request.app.state.services.settings
        return PageConfig(viewer_port=viewer_port(settings), networks=list(installed_backends()))

    @router.get("/web/{name}", include_in_schema=False)
    def asset(name: str) -> Response:
        """One of the page's static files."""
        if name not in ASSETS:
            raise HTTPException(status_code=404, detail=f"no such page asset: {name!r}")
        return Response(
            _static(name), media_type=ASSETS[name], headers={"Cache-Control": "no-cache"}
        )

    return router
