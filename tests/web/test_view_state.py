"""Views as links (web.view_state): what a link holds comes back whole; junk falls back."""

from __future__ import annotations

import base64
import math
from urllib.parse import parse_qs, urlsplit

from web.view_state import (
    ViewState,
    address_html,
    carries_key,
    parse_path,
    state_path,
    viewer_link,
)

KEY = "k&y=+/%"
FULL = ViewState(
    job_id="a b/ç",
    camera=(1.25, -2.5, 3.0, 0.0, 0.5, -0.125),
    hidden=frozenset({0, 2, -1}),
    panels=frozenset({"segments", "errors"}),
    only_changed=True,
    point_size=1.5,
    single="fused",
    budget=50_000,
    boxes=False,
    view="Side",
    fov=math.radians(0.5),
    clip=(-1.5, 2.25, 0.0, 3.5, 0.125, 2.0),
    slice_heights=(1.0, 1.25),
)


def test_a_view_comes_back_from_its_path() -> None:
    assert parse_path(state_path(FULL)) == FULL


def test_object_boxes_are_on_unless_a_link_says_off() -> None:
    assert ViewState(job_id="j").boxes and "x." not in state_path(ViewState(job_id="j"))
    assert "x.0" in state_path(FULL).split("~")
    assert not parse_path("/job/j?v=x.0").boxes
    assert parse_path("/job/j?v=x.1").boxes and parse_path("/job/j?v=o.1").boxes


def test_views_clips_and_slices_come_back_and_malformed_ones_fall_back() -> None:
    state = parse_path("/job/j?v=m.t~f.1.5~q.0,1,0,2,0,3~s.1,1.2")
    assert state.view == "Top" and abs(state.fov - 0.0261799) < 1e-6  # type: ignore[operator]
    assert state.clip == (0, 1, 0, 2, 0, 3) and state.slice_heights == (1, 1.2)
    bad = parse_path("/job/j?v=m.x~f.0~q.0,1,2~s.2,1")
    assert bad.view is None and bad.fov is None and bad.clip is None
    assert bad.slice_heights is None  # a slice whose low end is above its high end


def test_the_path_has_no_character_viser_would_split_the_address_on() -> None:
    # viser writes the websocket address back unescaped: '&', '#', '+' and '%' would break it
    path = state_path(FULL)
    query = path.partition("?")[2]
    assert not set(query) & set("&#+% ")
    assert query.count("=") == 1


def test_a_key_in_a_link_is_never_used_nor_written_back() -> None:
    # links once carried the key (?key=, then a k. token in base64): a link shares a view only
    b64 = base64.urlsafe_b64encode(KEY.encode()).decode().rstrip("=")
    for path in ("/job/abc?key=secret", f"/job/abc?v=k.{b64}~o.1"):
        assert carries_key(path)
        state = parse_path(path)
        assert state.job_id == "abc"
        written = state_path(state)
        assert "secret" not in written and b64 not in written and "k." not in written
    assert not carries_key(state_path(FULL)) and not carries_key(None)
    assert not hasattr(ViewState(), "key")


def test_malformed_tokens_keep_their_defaults() -> None:
    state = parse_path("/job/j?v=c.1,2~h.x,0~z.-3~b.lots~l.Bad!~q.9~p.tzq")
    assert state.job_id == "j"
    assert state.camera is None and state.hidden is None and state.point_size is None
    assert state.budget is None and state.single is None
    assert state.panels == frozenset({"truth"})
    assert parse_path("/elsewhere").job_id is None
    assert parse_path(None) == ViewState()


def test_a_link_opens_the_view_on_the_viewer_and_the_address_element_names_the_path() -> None:
    link = viewer_link("http://h:9", FULL)
    ws = parse_qs(urlsplit(link).query)["websocket"][0]
    assert ws.startswith("ws://h:9/job/")
    assert parse_path(ws.removeprefix("ws://h:9")) == FULL
    html = address_html(state_path(FULL), 7)
    assert 'data-view="7"' in html and "window.URL" in html and "replaceState" in html
    assert '"' not in html.split('onerror="')[1][:-2]  # the handler's quotes are escaped
