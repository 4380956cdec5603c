"""The *Edit labels* folder: how to select, a button per class, undo, redo, save, and a
proposal from the corrections (:mod:`web.proposals`) to accept or discard.

viser 1.1 has no keyboard events, so the number keys come through the page's JavaScript: a
hidden element of the folder (:func:`web.view_state.script_html`, as the address and the legend
are written) installs one ``keydown`` listener that clicks the class button of the key pressed,
or *Undo* / *Redo*; the server sees an ordinary click. Keys typed into a field are left alone
(a dropdown's read-only input is no field).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import viser

from jointseg.classes import CLASS_NAMES, NUM_CLASSES, PALETTE
from web.selection import HINTS, MODES, OFF
from web.view_state import script_html

#: The key of each class, in the legend's order: 1-9 and 0 for the first ten, Shift+1 to
#: Shift+3 for bookcase, board and clutter.
SHORTCUTS = tuple([*"1234567890", "⇧1", "⇧2", "⇧3"][:NUM_CLASSES])
UNDO, REDO, APPLY, SAVE, RELOAD = "Undo", "Redo", "Apply", "Save", "Reload saved labels"
PROPOSE, ACCEPT, DISCARD = "Propose from my corrections", "Accept proposal", "Discard proposal"


def class_button_label(cls: int) -> str:
    """``1 · ceiling``: the shortcut, then the class."""
    return f"{SHORTCUTS[cls]} · {CLASS_NAMES[cls]}"


def key_script() -> str:
    """The page's keyboard shortcuts (installed once per page)."""
    keys = {s.replace("⇧", "s"): class_button_label(c) for c, s in enumerate(SHORTCUTS)}
    return (
        "if(!window.__jointsegEditKeys){window.__jointsegEditKeys=1;"
        f"var K={json.dumps(keys)};"
        "document.addEventListener('keydown',function(e){"
        "var t=e.target;if(t&&((t.tagName==='INPUT'&&!t.readOnly)||t.tagName==='TEXTAREA'"
        "||t.isContentEditable))return;"
        "var c=e.ctrlKey||e.metaKey,m=/^(Digit|Numpad)(\\d)$/.exec(e.code||''),l=null;"
        f"if(c&&(e.key==='z'||e.key==='Z'))l=e.shiftKey?'{REDO}':'{UNDO}';"
        f"else if(c&&e.key==='y')l='{REDO}';"
        "else if(m&&!c&&!e.altKey)l=K[(e.shiftKey?'s':'')+m[2]];"
        "if(!l)return;var b=[].slice.call(document.querySelectorAll('button')).find("
        "function(x){return x.textContent.trim()===l;});"
        "if(b&&!b.disabled){e.preventDefault();b.click();}});}"
    )


class EditControls:
    """The controls of the *Edit labels* folder of one tab."""

    def __init__(self, gui: viser.GuiApi) -> None:
        with gui.add_folder("Edit labels"):
            self.mode = gui.add_dropdown("Select", MODES, initial_value=OFF)
            self.selection = gui.add_markdown(HINTS[OFF])
            with gui.add_folder("Give class"):
                self.class_buttons = {
                    cls: gui.add_button(
                        class_button_label(cls),
                        color=(int(PALETTE[cls][0]), int(PALETTE[cls][1]), int(PALETTE[cls][2])),
                        hint="give the selection this class",
                    )
                    for cls in range(NUM_CLASSES)
                }
            self.apply = gui.add_button(
                APPLY, icon=viser.Icon.CHECK, hint="give the selection the last class again"
            )
            self.undo = gui.add_button(UNDO, icon=viser.Icon.ARROW_BACK_UP, hint="Ctrl+Z")
            self.redo = gui.add_button(REDO, icon=viser.Icon.ARROW_FORWARD_UP, hint="Ctrl+Y")
            self.save = gui.add_button(
                SAVE, icon=viser.Icon.DEVICE_FLOPPY, hint="save the edits as a new labels version"
            )
            self.version = gui.add_markdown("No job to edit.")
            self.propose = gui.add_button(
                PROPOSE,
                icon=viser.Icon.WAND,
                disabled=True,
                hint="relabel the segments like the ones you corrected (shown first, to accept)",
            )
            self.proposal = gui.add_markdown("", visible=False)
            self.accept = gui.add_button(ACCEPT, icon=viser.Icon.CHECKS, visible=False)
            self.discard = gui.add_button(DISCARD, icon=viser.Icon.X, visible=False)
            self.reload = gui.add_button(RELOAD, icon=viser.Icon.RELOAD, visible=False)
            self.keys = gui.add_html(script_html(key_script(), 1, "keys"))

    def on_class(self, given: Callable[[int], None]) -> None:
        """Have a class button (or its key) call ``given`` with its class."""
        for cls, button in self.class_buttons.items():
            button.on_click(_calling(given, cls))


def _calling(action: Callable[[int], None], value: int) -> Callable[[Any], None]:
    """A click callback that calls ``action(value)``."""
    return lambda _: action(value)
