"""The viewer's own sign-in sessions: a key is typed once, then a random token stands for it.

A link shares a view, never a credential (issue 44): the API key is asked for in a password
field and dropped once checked; the browser keeps only a session token, in a cookie of this
viewer's port (:func:`cookie_name`), which its websocket handshake sends back on a reload or a
new tab. The token maps, in this process only, to what the key may see (its tenant's
:class:`web.sources.JobSource`) until it expires; the table holds tokens' hashes, never keys.
A token is useless after the viewer restarts, and it never appears in an address, a log or a
download.
"""

from __future__ import annotations

import hashlib
import json
import re
import secrets
import threading
import time
from dataclasses import dataclass
from http.cookies import CookieError, SimpleCookie

from web.sources import JobSource

#: Seconds a sign-in lasts (a reload or a new tab after that asks for the key again).
SESSION_S = 3600.0
#: Most live sessions kept; the oldest go first (a flood of sign-ins cannot grow the process).
MAX_SESSIONS = 10_000


def cookie_name(port: int) -> str:
    """The session cookie of the viewer on ``port``: browsers share cookies between the ports
    of one host, so each viewer (and the API beside it) keeps to a name of its own."""
    return f"jointseg_viewer_{port}"


def cookie_value(header: str | None, name: str) -> str | None:
    """The value of cookie ``name`` in a ``Cookie`` request header, None when absent."""
    if not header:
        return None
    jar: SimpleCookie = SimpleCookie()
    try:
        jar.load(header)
    except CookieError:
        return None
    morsel = jar.get(name)
    return morsel.value if morsel is not None and morsel.value else None


def cookie_html(name: str, token: str | None, max_age_s: float, serial: int) -> str:
    """An invisible element that stores ``token`` in cookie ``name`` for ``max_age_s`` (None:
    deletes it, then reloads the page so it asks for a key again).

    Sent like :func:`web.view_state.address_html`: an image whose ``onerror`` runs the script.
    """
    if token is None:
        script = (
            f"document.cookie={json.dumps(name + '=; Max-Age=0; Path=/; SameSite=Strict')};"
            "window.location.reload();"
        )
    else:
        cookie = f"{name}={token}; Max-Age={int(max_age_s)}; Path=/; SameSite=Strict"
        script = f"document.cookie={json.dumps(cookie)};this.remove();"
    return _hidden(script, serial)


def password_html(field_id: str, serial: int) -> str:
    """An invisible element that makes viser's text input labelled for ``field_id`` a password
    input (viser 1.1 has none), so a typed key is never shown.

    A style masks the input's characters from the moment it is drawn; a script sets its
    ``type`` to ``password`` and sets it again whenever React redraws the input, until the
    sign-in box is gone (or is not drawn within 30 s).
    """
    if not re.fullmatch(r"[0-9A-Za-z_-]+", field_id):  # viser's uuids: nothing to escape
        raise ValueError(f"not a GUI element id: {field_id!r}")
    row = f'div.mantine-Flex-root:has(label[for="{field_id}"]) input'
    style = f"<style>{row}{{-webkit-text-security:disc;text-security:disc}}</style>"
    script = (
        "var seen=false,t=Date.now(),h=setInterval(function(){"
        f"var l=document.querySelector('label[for={json.dumps(field_id)}]');"
        "if(!l){if(seen||Date.now()-t>30000){clearInterval(h);}return;}seen=true;"
        "var r=l.closest('.mantine-Flex-root');var i=r&&r.querySelector('input');"
        "if(i&&i.type!=='password'){i.type='password';i.autocomplete='off';}},20);"
        "this.remove();"
    )
    return style + _hidden(script, serial)


def _hidden(script: str, serial: int) -> str:
    escaped = script.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")
    return (
        f'<img alt="" data-run="{serial}" src="data:,{serial}" style="display:none" '
        f'onerror="{escaped}">'
    )


@dataclass
class _Session:
    source: JobSource
    expires: float


class Sessions:
    """Live sign-ins of one viewer: token hash -> what the key may see, until it expires.

    Parameters
    ----------
    lifetime_s : float
        Seconds a session lasts from its sign-in.
    most : int
        Most sessions kept at once.
    """

    def __init__(self, lifetime_s: float = SESSION_S, most: int = MAX_SESSIONS) -> None:
        self.lifetime_s = lifetime_s
        self.most = most
        self._live: dict[str, _Session] = {}
        self._lock = threading.Lock()

    @staticmethod
    def _digest(token: str) -> str:
        return hashlib.sha256(token.encode()).hexdigest()

    def start(self, source: JobSource) -> str:
        """A new session seeing ``source``; its token (given to the browser only)."""
        token = secrets.token_urlsafe(32)
        now = time.monotonic()
        with self._lock:
            self._live = {d: s for d, s in self._live.items() if s.expires > now}
            while len(self._live) >= self.most:
                self._live.pop(next(iter(self._live)))
            self._live[self._digest(token)] = _Session(source, now + self.lifetime_s)
        return token

    def find(self, token: str | None) -> JobSource | None:
        """What the session ``token`` may see; None for an unknown or expired token."""
        if not token:
            return None
        digest = self._digest(token)
        with self._lock:
            session = self._live.get(digest)
            if session is None:
                return None
            if session.expires <= time.monotonic():
                del self._live[digest]
                return None
            return session.source

    def end(self, token: str | None) -> None:
        """Forget session ``token`` (signing out)."""
        if token:
            with self._lock:
                self._live.pop(self._digest(token), None)

    def __len__(self) -> int:
        with self._lock:
            return len(self._live)
