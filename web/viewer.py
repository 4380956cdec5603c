"""The viewer: one viser server whose every browser tab gets its own :class:`ClientView`.

Opening a job directly
----------------------
viser's browser client connects its websocket to the URL given in its ``websocket`` search
parameter (default: the page's own address). A link of the form

    http://HOST:PORT/?websocket=ws://HOST:PORT/job/<id>

(:func:`viewer_link`) therefore opens a websocket whose request path names the job; the
viewer reads that path when the tab connects and shows the job. The link survives reloads,
because the client keeps the parameter in its address bar, and the view writes the rest of
its state there too (:mod:`web.view_state`).

Keys
----
When the job service has API keys, the viewer asks for one of them before it lists or shows
anything: in the link (``?key=`` on the websocket address, as the job page writes it) or typed
into the sign-in box it shows instead of its controls. Each client then sees what its key may
see through the API (``scope``: a key's own jobs; every job for admin keys).
"""

from __future__ import annotations

import logging
import re
import threading
from collections.abc import Callable
from dataclasses import replace
from urllib.parse import unquote

import viser

from web.client_view import ClientView
from web.memory import release_soon
from web.scene import MAX_PANEL_POINTS, SceneCache
from web.sources import JobSource
from web.view_state import ViewState, parse_path
from web.view_state import viewer_link as state_link

log = logging.getLogger(__name__)

_JOB_PATH = re.compile(r"^/job/([^/?#]+)/?$")


def viewer_link(base_url: str, job_id: str, key: str | None = None) -> str:
    """The address that opens the viewer at ``base_url`` (``http://host:port``) on ``job_id``
    (signed in with ``key`` when given)."""
    return state_link(base_url, ViewState(job_id=job_id, key=key))


def job_from_path(path: str | None) -> str | None:
    """The job id in a websocket request path ``/job/<id>`` (any query dropped), else None."""
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
        Interface to listen on; loopback by default.
    port : int
        viser moves to the next free port when this one is taken: read :attr:`port`.
    max_points : int
        Most points per panel (voxel down-sampling above).
    cache_size : int
        Loaded results kept for quick switching, shared by all clients.
    authorise : callable, optional
        Whether a presented API key (None: none) may see the jobs; None when the service has
        no keys (everyone may).
    scope : callable, optional
        The source a client whose key (None: none) was accepted sees: the job service's
        tenants (:meth:`web.service_source.ServiceSource.for_tenant`); None: ``source`` for
        every client.
    """

    def __init__(
        self,
        source: JobSource,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        max_points: int = MAX_PANEL_POINTS,
        cache_size: int = 2,
        authorise: Callable[[str | None], bool] | None = None,
        scope: Callable[[str | None], JobSource] | None = None,
    ) -> None:
        self.source = source
        self.authorise = authorise
        self.scope = scope
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

    def link(self, job_id: str, host: str = "127.0.0.1", key: str | None = None) -> str:
        """A link opening this viewer on ``job_id``."""
        return viewer_link(f"http://{host}:{self.port}", job_id, key)

    def _connect(self, client: viser.ClientHandle) -> None:
        # no share button: viser's would publish the scan through its public relay; the
        # address bar is this viewer's way to share a view
        client.gui.configure_theme(control_width="large", show_logo=False, show_share_button=False)
        client.gui.main_panel.dock_right()  # beside the canvas, not over the panels
        state = parse_path(self._request_path(client))
        if self.authorise is not None and not self.authorise(state.key):
            self._sign_in(client, state)
            return
        self._open(client, state, key_in_address=state.key is not None)

    def source_for(self, key: str | None) -> JobSource:
        """The jobs a client signed in with ``key`` (already accepted) may see."""
        return self.source if self.scope is None else self.scope(key)

    def _open(self, client: viser.ClientHandle, state: ViewState, *, key_in_address: bool) -> None:
        source = self.source_for(state.key)
        view = ClientView(client, source, self.cache, state, key_in_address=key_in_address)
        with self._views_lock:
            self.views[client.client_id] = view
        if state.job_id is not None:
            view.select(state.job_id)
        else:
            view.sync_address()

    def _sign_in(self, client: viser.ClientHandle, state: ViewState) -> None:
        """Show only a key box: nothing is listed or drawn until a key is accepted."""
        gui = client.gui
        with gui.add_folder("Sign in") as folder:
            why = "The key in this link was refused." if state.key else "This viewer needs a key."
            note = gui.add_markdown(f"{why} Enter one of the job service's API keys.")
            box = gui.add_text("API key", "")
            button = gui.add_button("Sign in", icon=viser.Icon.LOGIN)

        def attempt(_: object) -> None:
            key = str(box.value).strip()
            assert self.authorise is not None
            if not self.authorise(key or None):
                log.info("viewer: client %d presented a refused key", client.client_id)
                note.content = "**This key was refused.** Enter one of the service's API keys."
                return
            folder.remove()
            self._open(client, replace(state, key=key), key_in_address=False)

        button.on_click(attempt)

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
