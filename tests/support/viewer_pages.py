"""What the viewer's browser tests share: a free loopback port, a new tab in the tests' window,
and the server-side view of the tab that shows a job. A module of its own (not conftest) so
tests import it by name."""

from __future__ import annotations

import socket
import time
from typing import Any

from tests.support.shots import HIDE_OVERLAYS, VIEWPORT


def free_port() -> int:
    """A loopback port nobody listens on now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def open_tab(
    browser: Any, url: str, *, viewport: dict[str, int] = VIEWPORT, overlays: bool = False
) -> Any:
    """A new tab on ``url`` (downloads accepted) in the tests' window, with the toasts and the
    legend hidden from its screenshots unless ``overlays``; closed again if it cannot load."""
    page = browser.new_page(viewport=viewport, accept_downloads=True)
    try:
        page.goto(url)
        if not overlays:
            page.add_style_tag(content=HIDE_OVERLAYS)
    except BaseException:
        page.close()
        raise
    return page


def wait_for(condition: Any, what: str = "condition", timeout: float = 15.0) -> None:
    """Poll ``condition`` every 0.1 s until it holds; fail naming ``what`` after ``timeout``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def view_of(viewer: Any, job_id: str, exclude: tuple[Any, ...] = ()) -> Any:
    """The server-side view of the newest tab showing ``job_id`` (other than those in
    ``exclude``), waiting up to 15 s for it.

    The newest, because a tab an earlier test closed stays among the viewer's views until viser
    has seen its websocket close: the oldest match can be that closed tab (viser numbers its
    clients in the order they connect)."""
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        found = [v for v in list(viewer.views.values()) if v.job_id == job_id and v not in exclude]
        if found:
            return max(found, key=lambda v: v.client.client_id)
        time.sleep(0.1)
    raise AssertionError(f"no client shows {job_id}")


def key_in(text: str, key: str) -> bool:
    """Whether ``text`` (an address, a link) holds ``key`` in clear, percent-encoded (once or
    twice: a websocket address inside a page address) or in base64 (standard or URL-safe)."""
    import base64
    from urllib.parse import quote, unquote

    raw = key.encode()
    forms = {key, quote(key), quote(key, safe=""), quote(quote(key, safe=""), safe="")}
    for encode in (base64.b64encode, base64.urlsafe_b64encode):
        coded = encode(raw).decode()
        forms |= {coded, coded.rstrip("="), quote(coded, safe="")}
    decoded = unquote(unquote(text))
    return any(form in text or form in decoded for form in forms)


def sign_in(page: Any, key: str) -> None:
    """Type ``key`` into the viewer's sign-in box (a password field) and sign in."""
    page.get_by_text("Enter one of the job service's API keys").wait_for(timeout=60_000)
    row = page.get_by_text("API key", exact=True).locator(
        "xpath=ancestor::div[contains(@class, 'mantine-Flex-root')][1]"
    )
    box = row.locator("input").first
    deadline = time.monotonic() + 15
    while box.get_attribute("type") != "password":
        assert time.monotonic() < deadline, "the key field is no password field"
        time.sleep(0.05)
    box.fill(key)
    page.get_by_role("button", name="Sign in").click()
