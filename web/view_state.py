"""A view as a link: the job, the camera, hidden classes and toggles, in the URL; never a key.

viser's browser client opens its websocket on the address in the page's ``websocket`` search
parameter, so that address is the one part of the page URL the viewer receives. A view is
written into it as the path and one query parameter,

    ws://HOST:PORT/job/<id>?v=<token>~<token>~...

each token a letter, a dot and a value (``c.`` camera, ``h.`` hidden classes, ``x.0`` object
boxes off, ``m.t`` the plan, ``q.`` a clip box, ``s.`` a slice, ...). A single
parameter with ``~`` between tokens survives viser's own rewriting of the address bar, which
puts the websocket address back unescaped (an ``&`` inside it would split it).

A link shares a view, never a credential (issue 44): no key is written into an address, and a
key found in one (``key=`` or a ``k.`` token, as links once carried) is not used: the viewer
asks whoever opens the link to sign in (:mod:`web.sessions`). :func:`carries_key` tells.

The viewer keeps the browser's address following the view with :func:`address_html`: viser
has no call to set a client's address, so a hidden image whose ``onerror`` runs
``history.replaceState`` is sent as an HTML element (the element's markup is set with
``innerHTML``, where an image's error handler runs and a script would not). Inside an inline
handler ``URL`` is ``document.URL``, a string: the handler names ``window.URL``.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, replace
from urllib.parse import parse_qs, quote, unquote

from jointseg.classes import NUM_CLASSES

_JOB_PATH = re.compile(r"^/job/([^/?#]+)/?$")
#: Optional panels by their letter in the ``p.`` token.
PANEL_LETTERS = {"t": "truth", "s": "segments", "c": "confidence", "e": "errors"}
#: The plan and the elevations by their letter in the ``m.`` token.
VIEW_LETTERS = {"t": "Top", "f": "Front", "s": "Side"}


@dataclass(frozen=True)
class ViewState:
    """What a link restores; None (or empty) means the viewer's default."""

    job_id: str | None = None
    camera: tuple[float, ...] | None = None  # position xyz, look-at xyz (scene coordinates)
    hidden: frozenset[int] | None = None
    panels: frozenset[str] | None = None  # optional panels shown: truth, segments, ...
    only_changed: bool = False
    point_size: float | None = None
    single: str | None = None  # one large panel (its key) instead of the row
    budget: int | None = None
    boxes: bool = True  # the objects' boxes drawn
    view: str | None = None  # the plan or an elevation (a key of VIEW_LETTERS' values)
    fov: float | None = None  # the camera's field of view, radians (a plan's or elevation's)
    clip: tuple[float, ...] | None = None  # x0, x1, y0, y1, z0, z1 kept (web.clipping)
    slice_heights: tuple[float, ...] | None = None  # low, high heights above the floor kept


def _floats(text: str, count: int) -> tuple[float, ...] | None:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        return None
    ok = len(values) == count and all(abs(v) < 1e7 for v in values)
    return values if ok else None


def parse_path(path: str | None) -> ViewState:
    """The view a websocket request path names; anything malformed is left at its default."""
    if not path:
        return ViewState()
    route, _, query = path.partition("?")
    match = _JOB_PATH.match(route)
    job_id = unquote(match.group(1)) if match else None
    params = parse_qs(query, keep_blank_values=True)
    state = ViewState(job_id=job_id)
    for token in (params.get("v") or [""])[0].split("~"):
        letter, _, value = token.partition(".")
        state = _apply(state, letter, value)
    return state


def carries_key(path: str | None) -> bool:
    """Whether a websocket path tries to carry a key (``key=``, or a ``k.`` token): the viewer
    ignores it and says so at sign-in."""
    query = (path or "").partition("?")[2]
    params = parse_qs(query, keep_blank_values=True)
    tokens = (params.get("v") or [""])[0].split("~")
    return "key" in params or any(token.startswith("k.") for token in tokens)


def _apply(state: ViewState, letter: str, value: str) -> ViewState:
    if letter == "c":
        return replace(state, camera=_floats(value, 6))
    if letter == "h":
        try:
            classes = {int(v) for v in value.split(",") if v}
        except ValueError:
            return state
        return replace(state, hidden=frozenset(c for c in classes if -1 <= c < NUM_CLASSES))
    if letter == "p":
        return replace(
            state, panels=frozenset(PANEL_LETTERS[c] for c in value if c in PANEL_LETTERS)
        )
    if letter == "o":
        return replace(state, only_changed=value == "1")
    if letter == "z":
        size = _floats(value, 1)
        return replace(state, point_size=None if size is None or size[0] <= 0 else size[0])
    if letter == "l":
        return replace(state, single=value or None) if re.fullmatch(r"[a-z]*", value) else state
    if letter == "b" and value.isdigit():
        return replace(state, budget=int(value))
    if letter == "x":
        return replace(state, boxes=value != "0")
    if letter == "m":
        return replace(state, view=VIEW_LETTERS.get(value))
    if letter == "f":
        fov = _floats(value, 1)
        ok = fov is not None and 0.0 < fov[0] < 179.0
        return replace(state, fov=math.radians(fov[0]) if fov is not None and ok else None)
    if letter == "q":
        return replace(state, clip=_ranges(value, 3))
    if letter == "s":
        return replace(state, slice_heights=_ranges(value, 1))
    return state


def _ranges(text: str, count: int) -> tuple[float, ...] | None:
    """``count`` (low, high) pairs, each low below its high; None when malformed."""
    values = _floats(text, 2 * count)
    if values is None or any(values[i] >= values[i + 1] for i in range(0, len(values), 2)):
        return None
    return values


def state_path(state: ViewState) -> str:
    """The websocket path (and query) that restores ``state``."""
    if state.job_id is None:
        return "/"
    tokens = []
    if state.camera is not None:
        tokens.append("c." + ",".join(f"{v:.4f}" for v in state.camera))
    if state.hidden is not None:
        tokens.append("h." + ",".join(str(c) for c in sorted(state.hidden)))
    if state.panels is not None:
        letters = {name: letter for letter, name in PANEL_LETTERS.items()}
        tokens.append("p." + "".join(sorted(letters[p] for p in state.panels if p in letters)))
    if state.only_changed:
        tokens.append("o.1")
    if state.point_size is not None:
        tokens.append(f"z.{state.point_size:g}")
    if state.single:
        tokens.append("l." + state.single)
    if state.budget is not None:
        tokens.append(f"b.{state.budget}")
    if not state.boxes:
        tokens.append("x.0")
    letters = {name: letter for letter, name in VIEW_LETTERS.items()}
    if state.view in letters:
        tokens.append("m." + letters[state.view])
    if state.fov is not None:
        tokens.append(f"f.{math.degrees(state.fov):.5f}")
    if state.clip is not None:
        tokens.append("q." + ",".join(f"{v:.3f}" for v in state.clip))
    if state.slice_heights is not None:
        tokens.append("s." + ",".join(f"{v:.3f}" for v in state.slice_heights))
    path = "/job/" + quote(state.job_id, safe="")
    return path + ("?v=" + "~".join(tokens) if tokens else "")


def viewer_link(base_url: str, state: ViewState) -> str:
    """The page address at ``base_url`` (``http://host:port``) that opens ``state``."""
    base = base_url.rstrip("/")
    ws = re.sub(r"^http", "ws", base) + state_path(state)
    return f"{base}/?websocket={quote(ws, safe='')}"


def address_html(path: str, serial: int) -> str:
    """An invisible element that sets the browser's address to open ``path`` (a websocket path
    from :func:`state_path`) on this page's own host; ``serial`` makes every update new markup,
    so the browser runs it again."""
    script = (
        "var u=new window.URL(window.location.href);"
        "u.searchParams.set('websocket',(location.protocol==='https:'?'wss://':'ws://')"
        f"+location.host+{json.dumps(path)});"
        "history.replaceState(history.state,'',u.toString());"
    )
    return script_html(script, serial, "view")


def script_html(script: str, serial: int, kind: str) -> str:
    """An invisible element of the control panel that runs ``script`` in the page once, then
    removes itself (viser sets an HTML element's markup with ``innerHTML``, where an image's
    error handler runs and a script element would not); ``serial`` makes each one new markup,
    ``kind`` names it (``data-<kind>``)."""
    return (
        f'<img alt="" data-{kind}="{serial}" src="data:,{serial}" style="display:none" '
        f'onerror="{_attr(script + "this.remove();")}">'
    )


def _attr(text: str) -> str:
    return text.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")
