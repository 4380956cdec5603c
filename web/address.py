"""Writing what a tab shows back to its browser, soon and seldom: the address, the overlay.

A control the user changes is written at once; a moving camera reports many times a second, so
what follows it (the address, the scale bar) is written at most every :data:`EVERY_S`, the last
state always included. :mod:`web.view_state` writes a view as a path and makes the hidden
element that sets the address, :mod:`web.overlay` the one that draws the legend over the canvas;
a :class:`PageElement` says when.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import viser

from web.view_state import ViewState, address_html, state_path

#: Least seconds between two writes while the camera moves.
EVERY_S = 0.4


class Throttled:
    """Runs ``write`` now (:meth:`now`) or within :data:`EVERY_S` (:meth:`soon`), under ``lock``."""

    def __init__(self, write: Callable[[], None], lock: threading.RLock) -> None:
        self._write = write
        self._lock = lock
        self._due: threading.Timer | None = None
        self._last = 0.0

    def now(self) -> None:
        """Write at once (a pending write is folded in)."""
        with self._lock:
            if self._due is not None:
                self._due.cancel()
                self._due = None
            self._last = time.monotonic()
            self._write()

    def soon(self) -> None:
        """Write within :data:`EVERY_S` (many calls, few writes)."""
        with self._lock:
            if self._due is not None:
                return
            wait = max(0.0, EVERY_S - (time.monotonic() - self._last))
            self._due = threading.Timer(wait, self.now)
            self._due.daemon = True
            self._due.start()


class PageElement:
    """An invisible element of the tab's control panel, rewritten with what the tab shows.

    Parameters
    ----------
    element : viser.GuiHtmlHandle
        The element that carries each update to the page.
    markup : callable
        The element's markup for a serial number (each update is new markup, so the page runs
        it again): :func:`web.view_state.address_html`, :func:`web.overlay.overlay_html`.
    lock : threading.RLock
        The view's lock, held while the markup is made.
    """

    def __init__(
        self,
        element: viser.GuiHtmlHandle,
        markup: Callable[[int], str],
        lock: threading.RLock,
    ) -> None:
        self.element = element
        self._markup = markup
        self._serial = 0
        self._writer = Throttled(self._write, lock)

    def sync(self) -> None:
        """Write it now."""
        self._writer.now()

    def soon(self) -> None:
        """Write it within :data:`EVERY_S` (the camera moves)."""
        self._writer.soon()

    def _write(self) -> None:
        self._serial += 1
        self.element.content = self._markup(self._serial)


class AddressBar(PageElement):
    """The browser's address following the view (:mod:`web.view_state`): a reload or a copied
    link opens it again.

    Parameters
    ----------
    element : viser.GuiHtmlHandle
        The (invisible) element of the control panel that carries the update.
    state : callable
        The view as a link would restore it, now.
    lock : threading.RLock
    """

    def __init__(
        self,
        element: viser.GuiHtmlHandle,
        state: Callable[[], ViewState],
        lock: threading.RLock,
    ) -> None:
        super().__init__(element, lambda serial: address_html(state_path(state()), serial), lock)
