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
anything, in a password field of the sign-in box it shows instead of its controls. A link
never carries a key (one found in a link is ignored): the key is checked once and dropped, and
the tab holds a short-lived session of this viewer (:mod:`web.sessions`) in a cookie, so a
reload or another link opened in the same browser needs no key until it expires. Each client
sees what its key may see through the API (``scope``: a key's own jobs; every job for admin
keys), so a link opened by someone else shows its job only if their own key may see it.
"""

from __future__ import annotations

import logging
import re
import threading
from collections.abc import Callable
from urllib.parse import unquote

import viser

from web.client_view import ClientView
from web.memory import release_soon
from web.scene import MAX_PANEL_POINTS, SceneCache
from web.sessions import SESSION_S, Sessions, cookie_html, cookie_name, cookie_value, password_html
from web.sources import JobSource
from web.view_state import ViewState, carries_key, parse_path
from web.view_state import viewer_link as state_link

log = logging.getLogger(__name__)

_JOB_PATH = re.compile(r"^/job/([^/?#]+)/?$")
#: Seconds between two refreshes of every tab's job list (a deleted job leaves it, a finished
#: one joins it, without a reload).
LIST_EVERY_S = 2.0


def viewer_link(base_url: str, job_id: str) -> str:
    """The address that opens the viewer at ``base_url`` (``http://host:port``) on ``job_id``
    (never with a key: whoever opens it signs in)."""
    return state_link(base_url, ViewState(job_id=job_id))


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
    session_s : float
        Seconds a sign-in lasts (:mod:`web.sessions`).
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
        session_s: float = SESSION_S,
    ) -> None:
        self.source = source
        self.authorise = authorise
        self.scope = scope
        self.sessions = Sessions(session_s)
        self._serial = 0
        self.cache = SceneCache(cache_size, max_points=max_points)
        self.views: dict[int, ClientView] = {}
        self._views_lock = threading.Lock()
        self.server = viser.ViserServer(host=host, port=port, label="jointseg", verbose=False)
        self.server.scene.set_up_direction("+z")
        self.server.scene.world_axes.visible = False
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)
        self._stopping = threading.Event()
        self._lists = threading.Thread(target=self._refresh_lists, name="job-lists", daemon=True)
        self._lists.start()
        log.info("viewer listening on http://%s:%d", host, self.port)

    @property
    def port(self) -> int:
        """The port the viewer listens on."""
        return self.server.get_port()

    @property
    def cookie(self) -> str:
        """The name of this viewer's session cookie."""
        return cookie_name(self.port)

    def link(self, job_id: str, host: str = "127.0.0.1") -> str:
        """A link opening this viewer on ``job_id``."""
        return viewer_link(f"http://{host}:{self.port}", job_id)

    def _connect(self, client: viser.ClientHandle) -> None:
        # no share button: viser's would publish the scan through its public relay; the
        # address bar is this viewer's way to share a view
        client.gui.configure_theme(control_width="large", show_logo=False, show_share_button=False)
        client.gui.main_panel.dock_right()  # beside the canvas, not over the panels
        path = self._request_path(client)
        state = parse_path(path)
        if self.authorise is None:
            self._open(client, state, self.source)
            return
        token = cookie_value(self._request_header(client, "Cookie"), self.cookie)
        source = self.sessions.find(token)
        if source is None:
            self._sign_in(client, state, key_in_link=carries_key(path))
            return
        assert token is not None
        self._open(client, state, source, token=token)

    def source_for(self, key: str | None) -> JobSource:
        """The jobs a client signed in with ``key`` (already accepted) may see."""
        return self.source if self.scope is None else self.scope(key)

    def _open(
        self,
        client: viser.ClientHandle,
        state: ViewState,
        source: JobSource,
        *,
        token: str | None = None,
    ) -> None:
        """The tab's view on ``source``; with a session ``token``, a *Sign out* button."""
        sign_out = None if token is None else (lambda: self._sign_out(client, token))
        view = ClientView(client, source, self.cache, state, sign_out=sign_out)
        with self._views_lock:
            self.views[client.client_id] = view
        if state.job_id is not None:
            view.select(state.job_id)
        else:
            view.address.sync()

    def _next_serial(self) -> int:
        with self._views_lock:
            self._serial += 1
            return self._serial

    def _sign_in(self, client: viser.ClientHandle, state: ViewState, *, key_in_link: bool) -> None:
        """Show only a key box (a password field): nothing is listed or drawn until a key is
        accepted; then the key is dropped and a session cookie stands for it."""
        gui = client.gui
        with gui.add_folder("Sign in") as folder:
            why = (
                "Links never carry a key: the one in this link was not used."
                if key_in_link
                else "This viewer needs a key."
            )
            note = gui.add_markdown(f"{why} Enter one of the job service's API keys.")
            box = gui.add_text("API key", "")
            button = gui.add_button("Sign in", icon=viser.Icon.LOGIN)
            gui.add_html(password_html(box._impl.uuid, self._next_serial()))

        def attempt(_: object) -> None:
            key = str(box.value).strip()
            box.value = ""  # type: ignore[misc]  # viser types it read-only; the key is not kept
            assert self.authorise is not None
            if not self.authorise(key or None):
                log.info("viewer: client %d presented a refused key", client.client_id)
                note.content = "**This key was refused.** Enter one of the service's API keys."
                return
            source = self.source_for(key)
            token = self.sessions.start(source)
            folder.remove()
            html = cookie_html(self.cookie, token, self.sessions.lifetime_s, self._next_serial())
            gui.add_html(html)
            log.info("viewer: client %d signed in", client.client_id)
            self._open(client, state, source, token=token)

        button.on_click(attempt)

    def _sign_out(self, client: viser.ClientHandle, token: str) -> None:
        """End the session: its cookie is deleted and the tab reloads to the sign-in box."""
        self.sessions.end(token)
        log.info("viewer: client %d signed out", client.client_id)
        client.gui.add_html(cookie_html(self.cookie, None, 0, self._next_serial()))

    def _refresh_lists(self) -> None:
        """Every :data:`LIST_EVERY_S`, each tab's job list read again from its own source."""
        while not self._stopping.wait(LIST_EVERY_S):
            with self._views_lock:
                views = list(self.views.values())
            for view in views:
                try:
                    view.refresh_jobs()
                except Exception:  # a tab closing under the refresh must not end the others'
                    log.exception("refreshing a tab's job list failed")

    def _disconnect(self, client: viser.ClientHandle) -> None:
        with self._views_lock:
            view = self.views.pop(client.client_id, None)
        if view is not None:
            view.close()
        release_soon()  # and give the freed memory back once viser has dropped the tab

    def _request(self, client: viser.ClientHandle) -> object | None:
        """The handshake request of the client's websocket.

        viser keeps each client's websocket connection in its websocket server; the handshake
        request is the only place the browser's choice of job (its path) and its session
        cookie (a header) reach the server.
        """
        connections = getattr(self.server._websock_server, "_live_connections", {})
        connection = connections.get(client.client_id)
        return getattr(connection, "request", None)

    def _request_path(self, client: viser.ClientHandle) -> str | None:
        """The path the client's websocket was opened on."""
        return getattr(self._request(client), "path", None)

    def _request_header(self, client: viser.ClientHandle, name: str) -> str | None:
        """A header of the client's websocket handshake (None when absent)."""
        headers = getattr(self._request(client), "headers", None)
        value = None if headers is None else headers.get(name)
        return value if isinstance(value, str) else None

    def wait(self) -> None:
        """Block until the process is stopped (the viewer serves from its own threads)."""
        self.server.sleep_forever()

    def stop(self) -> None:
        """Close every connection and the port."""
        self._stopping.set()
        self.server.stop()
