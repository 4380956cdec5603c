"""The browser's address following a tab's view, so a reload or a copied link opens it again.

:mod:`web.view_state` writes a view as a path and makes the hidden element that sets the
address; this is the tab's side of it: when to write. A control the user changes is written at
once; a moving camera reports many times a second, so it is written at most every
:data:`ADDRESS_EVERY_S`, the last pose always included.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import viser

from web.view_state import ViewState, address_html, state_path

#: Least seconds between two address updates while the camera moves.
ADDRESS_EVERY_S = 0.4


class AddressBar:
    """Writes a tab's view into its browser's address.

    Parameters
    ----------
    element : viser.GuiHtmlHandle
        An (invisible) HTML element of the tab's control panel that carries the update.
    state : callable
        The view as a link would restore it, now.
    lock : threading.RLock
        The view's lock, held while the state is read.
    """

    def __init__(
        self,
        element: viser.GuiHtmlHandle,
        state: Callable[[], ViewState],
        lock: threading.RLock,
    ) -> None:
        self.element = element
        self._state = state
        self._lock = lock
        self._serial = 0
        self._due: threading.Timer | None = None
        self._last = 0.0

    def sync(self) -> None:
        """Write the view into the address now."""
        with self._lock:
            if self._due is not None:
                self._due.cancel()
                self._due = None
            self._last = time.monotonic()
            self._serial += 1
            self.element.content = address_html(state_path(self._state()), self._serial)

    def soon(self) -> None:
        """Write it within :data:`ADDRESS_EVERY_S` (the camera moves: many calls, few writes)."""
        with self._lock:
            if self._due is not None:
                return
            wait = max(0.0, ADDRESS_EVERY_S - (time.monotonic() - self._last))
            self._due = threading.Timer(wait, self.sync)
            self._due.daemon = True
            self._due.start()
