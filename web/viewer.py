"""The viewer: one viser server whose every browser tab gets its own :class:`ClientView`.

Opening a job directly
----------------------
viser's browser client connects its websocket to the URL given in its ``websocket`` search
parameter (default: the page's own address). A link of the form

    http://HOST:PORT/?websocket=ws://HOST:PORT/job/<id>

(:func:`viewer_link`) therefore opens a websocket whose request path names the job; the
viewer reads that path when the tab connects and shows the job. The link survives reloads,
because the client keeps the parameter in its address bar.
"""

from __future__ import annotations

import logging
import re
import threading
from urllib.parse import quote, unquote

import viser

from web.client_view import ClientView
from web.memory import release_soon
from web.scene import MAX_PANEL_POINTS, SceneCache
from web.sources import JobSource

log = logging.getLogger(__name__)

_JOB_PATH = re.compile(r"^/job/([^/?#]+)/?$")


def viewer_link(base_url: str, job_id: str) -> str:
    """The address that opens the viewer at ``base_url`` (``http://host:port``) on ``job_id``."""
    base = base_url.rstrip("/")
    ws = re.sub(r"^http", "ws", base) + "/job/" + quote(job_id, safe="")
    return f"{base}/?websocket={quote(ws, safe=':/')}"


def job_from_path(path: str | None) -> str | None:
    """The job id in a websocket request path ``/job/<id>``, else None."""
    if not path:
        return None
    match = _JOB_PATH.match(path.partition("?")[0])
    return unquote(match.group(1)) if match else None


class Viewer:
    """A viser server showing finished jobs, one independent view per connected client.

    Parameters
    ----------
    source : JobSource
        Where finished jobs and their files are found.
    host : str
        Interface to listen on; loopback by default (the viewer has no authentication).
    port : int
        viser moves to the next free port when this one is taken: read :attr:`port`.
    max_points : int
        Most points per panel (voxel down-sampling above).
    cache_size : int
        Loaded results kept for quick switching, shared by all clients.
    """

    def __init__(
        self,
        source: JobSource,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        max_points: int = MAX_PANEL_POINTS,
        cache_size: int = 2,
    ) -> None:
        self.source = source
        self.cache = SceneCache(cache_size, max_points=max_points)
        self.views: dict[int, ClientView] = {}
        self._views_lock = threading.Lock()
        self.server = viser.ViserServer(host=host, port=port, label="jointseg", verbose=False)
        self.server.scene.set_up_direction("+z")
        self.server.scene.world_axes.visible = False
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)
        log.info("viewer listening on http://%s:%d", host, self.port)

    @property
    def port(self) -> int:
        """The port the viewer listens on."""
        return self.server.get_port()

    def link(self, job_id: str, host: str = "127.0.0.1") -> str:
        """A link opening this viewer on ``job_id``."""
        return viewer_link(f"http://{host}:{self.port}", job_id)

    def _connect(self, client: viser.ClientHandle) -> None:
        client.gui.configure_theme(control_width="large", show_logo=False)
        client.gui.main_panel.dock_right()  # beside the canvas, not over the panels
        view = ClientView(client, self.source, self.cache)
        with self._views_lock:
            self.views[client.client_id] = view
        job_id = job_from_path(self._request_path(client))
        if job_id is not None:
            view.select(job_id)

    def _disconnect(self, client: viser.ClientHandle) -> None:
        with self._views_lock:
            view = self.views.pop(client.client_id, None)
        if view is not None:
            view.data = None  # drop the tab's reference to its points at once
        release_soon()  # and give the freed memory back once viser has dropped the tab

    def _request_path(self, client: viser.ClientHandle) -> str | None:
        """The path the client's websocket was opened on.

        viser keeps each client's websocket connection in its websocket server; the handshake
        request is the only place the browser's choice of job reaches the server.
        """
        connections = getattr(self.server._websock_server, "_live_connections", {})
        connection = connections.get(client.client_id)
        request = getattr(connection, "request", None)
        return getattr(request, "path", None)

    def wait(self) -> None:
        """Block until the process is stopped (the viewer serves from its own threads)."""
        self.server.sleep_forever()

    def stop(self) -> None:
        """Close every connection and the port."""
        self.server.stop()
