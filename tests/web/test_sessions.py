"""The viewer's sign-in sessions (web.sessions): a token stands for a key until it expires;
neither the table nor the cookie holds the key."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from web.sessions import Sessions, cookie_html, cookie_name, cookie_value, password_html
from web.sources import DirectorySource


def test_a_session_stands_for_what_its_key_may_see_until_it_expires(tmp_path: Path) -> None:
    source = DirectorySource(tmp_path)
    sessions = Sessions(lifetime_s=0.3, most=2)
    token = sessions.start(source)
    assert len(token) >= 40 and sessions.find(token) is source
    assert token not in repr(sessions._live)  # hashes only
    assert sessions.find(token + "x") is None and sessions.find(None) is None
    time.sleep(0.35)
    assert sessions.find(token) is None and len(sessions) == 0
    # bounded: the oldest live session goes first
    first, second, third = (sessions.start(source) for _ in range(3))
    assert sessions.find(first) is None and sessions.find(third) is source
    sessions.end(third)
    assert sessions.find(third) is None and sessions.find(second) is source


def test_the_cookie_is_the_viewers_own_and_the_markup_never_breaks_out() -> None:
    name = cookie_name(8080)
    header = f"other=1; {name}=abc_DEF-123; jointseg_viewer_8081=zzz"
    assert cookie_value(header, name) == "abc_DEF-123"
    assert cookie_value("garbage;;;=", name) is None and cookie_value(None, name) is None
    html = cookie_html(name, "tok", 3600, 4)
    assert "Max-Age=3600" in html and "SameSite=Strict" in html and 'data-run="4"' in html
    gone = cookie_html(name, None, 0, 5)
    assert "reload" in gone and "Max-Age=0" in gone
    assert "label[for=" in password_html("0f3a-9c", 1)
    with pytest.raises(ValueError):
        password_html('x"><b>', 1)
