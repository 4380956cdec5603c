"""One job's panels in one tab's scene: the nodes sent, which are drawn, and what a ray hits.

A job's points are sent once per panel, split into one node per (class, changed by fusion)
group: hiding a class, showing only the changed points or resizing points are property updates,
not new uploads. Every job is drawn below a scene path of its own (``/jointseg/<n>``): a node
removed and added again under the same name in one update can keep its old position in the
browser, which laid a three-panel job over a four-panel job's slots.
"""

from __future__ import annotations

import numpy as np
import viser

from web.clipping import Clip
from web.layout import title_position
from web.legend import class_title
from web.object_list import SELECTED_COLOUR
from web.objects_view import box_segments
from web.picking import pick
from web.render import Cloud, Label, Lines
from web.scene import CONFIDENCE, NETWORK, TRUTH, Panel, SceneData, group_points
from web.tools import Picked

ROOT = "/jointseg"
#: Default point size as a multiple of the shown points' spacing.
POINT_SIZE = 2.0
#: Which label set hides a panel's points with their class.
LABEL_KEY = {NETWORK.key: "network", CONFIDENCE.key: "network", TRUTH.key: "truth"}

Groups = dict[tuple[int, bool], np.ndarray]


class PanelScene:
    """The scene nodes of the job a tab shows.

    Parameters
    ----------
    scene : viser.SceneApi
        The tab's scene (``client.scene``).
    hidden : set of int
        Hidden classes, shared with the view (the class buttons change it).
    """

    def __init__(self, scene: viser.SceneApi, hidden: set[int]) -> None:
        self.scene = scene
        self.hidden = hidden
        self.only_changed = False
        self.boxes_on = True
        self.size_factor = POINT_SIZE  # point size as a multiple of the spacing
        self.clip: Clip | None = None  # what the clip box and the slice keep
        self.data: SceneData | None = None
        self.shown: np.ndarray | None = None  # rows of the scene data sent (point budget)
        self.frames: dict[str, viser.FrameHandle] = {}
        self.titles: dict[str, viser.LabelHandle] = {}
        self.nodes: dict[tuple[str, int, bool], viser.PointCloudHandle] = {}
        self.boxes: dict[int, viser.LineSegmentsHandle] | None = None  # by class; None: not sent
        self.selected: np.ndarray | None = None  # the selected object's box edges, (12, 2, 3)
        self.highlights: dict[str, viser.LineSegmentsHandle] = {}  # its box, by panel key
        self.groups: dict[str, Groups] = {}
        self.root_path = ROOT
        self._root: viser.FrameHandle | None = None
        self._generation = 0

    def start(self, data: SceneData, budget: int, clip: Clip | None = None) -> str:
        """Make ``data`` the shown job, at most ``budget`` points per panel, only the rows and
        boxes the clip box and the slice keep (:mod:`web.clipping`); the scene path of its new
        root (nothing is drawn until :meth:`lay_out`). A selected object stays selected when
        the same job is sent again."""
        selected = self.selected if data is self.data else None
        self.clear()
        self.selected = selected
        self.data = data
        self.clip = clip
        self._select(data, budget, None if clip is None else clip.rows)
        self._generation += 1
        self.root_path = f"{ROOT}/{self._generation}"
        self._root = self.scene.add_frame(self.root_path, show_axes=False)
        return self.root_path

    def clear(self) -> None:
        """Remove the shown job's nodes (every panel node is below its root)."""
        if self._root is not None:
            self._root.remove()
        self._root, self.data, self.shown, self.boxes = None, None, None, None
        self.frames, self.titles, self.nodes, self.groups = {}, {}, {}, {}
        self.selected, self.highlights = None, {}

    def _select(self, data: SceneData, budget: int, kept: np.ndarray | None) -> None:
        """The rows sent to this browser (at most the point budget per panel, those kept by the
        clip box and the slice) and their groups."""
        n = data.xyz.shape[0]
        # an even random subset of what the viewer loaded (itself thinned evenly for big
        # files): exactly the budget, the same rows every time for one budget
        rng = np.random.default_rng(budget)
        self.shown = None if n <= budget else np.sort(rng.choice(n, budget, replace=False))
        if kept is not None:
            rows = np.arange(n) if self.shown is None else self.shown
            self.shown = rows[kept[rows]]

        self._regroup(data)

    def _regroup(self, data: SceneData) -> None:
        """The (class, changed) groups of the rows sent, by label set."""

        def sel(a: np.ndarray) -> np.ndarray:
            return a if self.shown is None else a[self.shown]

        changed = sel(data.changed)
        self.groups = {
            "network": group_points(sel(data.network), changed),
            "fused": group_points(sel(data.fused), changed),
        }
        if data.truth is not None:
            self.groups["truth"] = group_points(sel(data.truth), changed)

    def rows(self, positions: np.ndarray) -> np.ndarray:
        """Rows of the scene data of positions among the points sent."""
        return positions if self.shown is None else self.shown[positions]

    def lay_out(self, panels: tuple[Panel, ...], offsets: np.ndarray, axis: int = 0) -> None:
        """Put ``panels`` at ``offsets`` of a row along ``axis`` (sending any not sent yet),
        hide the others."""
        data = self.data
        if data is None:
            return
        for panel, offset in zip(panels, offsets, strict=True):
            if panel.key not in self.frames:
                self._send_panel(panel, data)
            self.frames[panel.key].position = offset
            self.titles[panel.key].position = title_position(data.extent, axis)
            if panel.key == "fused" and self.boxes is None:
                self._send_boxes(data)
        keys = {p.key for p in panels}
        for key, frame in self.frames.items():
            frame.visible = key in keys
        self.apply_visibility()
        self._highlight(panels)

    def select(self, edges: np.ndarray | None, panels: tuple[Panel, ...]) -> None:
        """Draw a selected object's box (its ``edges``, scene coordinates) around its copy in
        every panel, or none (None)."""
        for node in self.highlights.values():
            node.remove()
        self.selected, self.highlights = edges, {}
        self._highlight(panels)

    def _highlight(self, panels: tuple[Panel, ...]) -> None:
        """The selected box in every panel shown that lacks it (one shown later gets it too)."""
        if self.selected is None:
            return
        for panel in panels:
            if panel.key in self.frames and panel.key not in self.highlights:
                self.highlights[panel.key] = self.scene.add_line_segments(
                    f"{self.root_path}/{panel.key}/selected",
                    self.selected,
                    SELECTED_COLOUR,
                    thickness=4.0,
                    thickness_units="screen",
                )

    def _send_panel(self, panel: Panel, data: SceneData) -> None:
        path = f"{self.root_path}/{panel.key}"
        self.frames[panel.key] = self.scene.add_frame(path, show_axes=False)
        self.titles[panel.key] = self.scene.add_label(
            f"{path}/title",
            panel.title,
            position=title_position(data.extent),
            anchor="bottom-center",
            font_screen_scale=1.4,
        )
        self._send_groups(panel, data, set(self.groups[LABEL_KEY.get(panel.key, "fused")]))

    def _send_groups(self, panel: Panel, data: SceneData, keys: set[tuple[int, bool]]) -> None:
        """(Re)send a panel's nodes of the (class, changed) groups ``keys``; a group now empty
        loses its node."""
        rows = slice(None) if self.shown is None else self.shown
        xyz, colours = data.xyz[rows], data.colours_of(panel)[rows]
        groups = self.groups[LABEL_KEY.get(panel.key, "fused")]
        for cls, changed in keys:
            old = self.nodes.pop((panel.key, cls, changed), None)
            if old is not None:
                old.remove()
            index = groups.get((cls, changed))
            if index is None:
                continue
            name = f"{class_title(cls)}_{'changed' if changed else 'kept'}"
            self.nodes[(panel.key, cls, changed)] = self.scene.add_point_cloud(
                f"{self.root_path}/{panel.key}/{name}",
                xyz[index],
                colours[index],
                point_size=self.point_size(),
                point_shape="square",
                point_shading="flat",
                precision="float32",
                visible=self.node_visible(cls, changed),
            )

    def relabel(self, panels: tuple[Panel, ...]) -> None:
        """The fused labels of some shown points changed (a correction): regroup, and send
        again only the groups whose points changed, in the panels sent; redraw the boxes
        (objects may have changed class) and the selection."""
        data = self.data
        if data is None:
            return
        before = self.groups
        self._regroup(data)
        by_panel = {p.key: p for p in data.panels}
        for key in list(self.frames):
            label = LABEL_KEY.get(key, "fused")
            old, new = before.get(label, {}), self.groups.get(label, {})
            stale = {
                g for g in set(old) | set(new)
                if g not in old or g not in new or not np.array_equal(old[g], new[g])
            }  # fmt: skip
            if key == "errors":  # its colours follow the fused labels in every group
                stale = set(old) | set(new)
            if stale and key in by_panel:
                self._send_groups(by_panel[key], data, stale)
        for box in (self.boxes or {}).values():
            box.remove()
        self.boxes = None
        if "fused" in self.frames:
            self._send_boxes(data)
        self.apply_visibility()

    def _send_boxes(self, data: SceneData) -> None:
        """The objects' boxes, drawn once in the fused panel (the report's objects), a node
        per class so that they follow the class buttons."""
        self.boxes = {
            cls: self.scene.add_line_segments(
                f"{self.root_path}/fused/objects_{class_title(cls)}",
                segments,
                colours,
                thickness=2.0,
                thickness_units="screen",
                visible=self.box_visible(cls),
            )
            for cls, (segments, colours) in box_segments(
                data, None if self.clip is None else self.clip.box
            ).items()
        }

    def offsets(self) -> dict[str, np.ndarray]:
        """Where each panel shown sits, by key."""
        return {k: np.asarray(f.position, np.float64) for k, f in self.frames.items() if f.visible}

    def drawing(self) -> tuple[list[Cloud], list[Lines], list[Label]]:
        """What the tab draws now, in world coordinates: the points of every node shown, the
        objects' and the selection's boxes, the panels' titles (a screenshot draws them)."""
        clouds, lines, labels = [], [], []
        for key, offset in self.offsets().items():
            for (panel, _, _), node in self.nodes.items():
                if panel == key and node.visible:
                    clouds.append(Cloud(node.points + offset, node.colors, node.point_size))
            boxes = [b for b in (self.boxes or {}).values() if b.visible] if key == "fused" else []
            for box in boxes:
                lines.append(Lines(box.points + offset, box.colors, 2.0))
            if key in self.highlights:
                selected = self.highlights[key]
                lines.append(Lines(selected.points + offset, selected.colors, 4.0))
            if key in self.titles:
                title = self.titles[key]
                labels.append(Label(title.text, np.asarray(title.position) + offset))
        return clouds, lines, labels

    def node_visible(self, cls: int, changed: bool) -> bool:
        """A group is drawn when its class is shown, and it changed or all points are shown."""
        return cls not in self.hidden and (changed or not self.only_changed)

    def box_visible(self, cls: int) -> bool:
        """Boxes are drawn when *Object boxes* is ticked and their class is shown."""
        return self.boxes_on and cls not in self.hidden

    def apply_visibility(self) -> None:
        """Show and hide the nodes by the class buttons, *only changed* and *Object boxes*."""
        for (_, cls, changed), node in self.nodes.items():
            node.visible = self.node_visible(cls, changed)
        for cls, box in (self.boxes or {}).items():
            box.visible = self.box_visible(cls)

    def restyle(self, only_changed: bool, boxes_on: bool, size_factor: float) -> None:
        """Draw with these options (node properties: viser sends only those that changed)."""
        self.only_changed, self.boxes_on, self.size_factor = only_changed, boxes_on, size_factor
        self.apply_visibility()
        self.resize()

    def point_size(self) -> float:
        """The drawn points' size in metres."""
        spacing = 1e-4 if self.data is None else max(self.data.spacing, 1e-4)
        return float(self.size_factor) * spacing

    def resize(self) -> None:
        """Give every node the current point size."""
        size = self.point_size()
        for node in self.nodes.values():
            node.point_size = size

    def drawn_rows(self, panel: Panel | str) -> np.ndarray:
        """Rows of the scene data drawn in a panel now (by its key or itself), ascending."""
        key = panel if isinstance(panel, str) else panel.key
        groups = self.groups.get(LABEL_KEY.get(key, "fused"), {})
        drawn = [idx for (cls, ch), idx in groups.items() if self.node_visible(cls, ch)]
        if not drawn:
            return np.zeros(0, dtype=np.int64)
        return np.sort(self.rows(np.concatenate(drawn)))

    def drawn(self, panel: Panel) -> int:
        """How many points a panel draws now."""
        groups = self.groups.get(LABEL_KEY.get(panel.key, "fused"), {})
        return sum(idx.size for (cls, ch), idx in groups.items() if self.node_visible(cls, ch))

    def status(self, name: str, panels: tuple[Panel, ...]) -> str:
        """The status line: how many points the browser draws now (in the one panel shown, or
        the fused one), of how many the scan has, and why fewer are sent."""
        data = self.data
        if data is None:
            return "No job shown."
        fused = next((p for p in panels if p.key == "fused"), panels[0] if panels else None)
        panel = panels[0] if len(panels) == 1 else fused
        drawn = 0 if panel is None else self.drawn(panel)
        loaded = data.xyz.shape[0]
        sent = loaded if self.shown is None else self.shown.size
        notes = []
        if data.voxel is not None:
            notes.append(f"voxel {data.voxel * 100:.1f} cm")
        if sent < loaded and self.clip is None:
            notes.append(f"budget {sent:,} of {loaded:,} loaded")
        if self.clip is not None:
            notes.append(f"clipped to {sent:,} of {loaded:,} loaded")
        note = f" ({', '.join(notes)})" if notes else ""
        where = "" if panel is None else f" in {panel.title}"
        return f"**{name}**: {drawn:,} of {data.total_points:,} points shown{where}{note}."

    def pick(
        self,
        origin: np.ndarray,
        direction: np.ndarray,
        panels: tuple[Panel, ...],
        tolerance: float,
    ) -> Picked | None:
        """The drawn point a ray (world coordinates) hits first, over ``panels``."""
        data = self.data
        if data is None:
            return None
        best: tuple[float, Picked] | None = None
        for panel in panels:
            frame = self.frames.get(panel.key)
            rows = self.drawn_rows(panel)
            if frame is None or rows.size == 0:
                continue
            local_origin = origin - np.asarray(frame.position, dtype=np.float64)
            found = pick(data.xyz[rows], local_origin, direction, tolerance)
            if found is None:
                continue
            row = int(rows[found])
            depth = float((data.xyz[row] - local_origin) @ direction)
            if best is None or depth < best[0]:
                best = (depth, Picked(panel.key, row, data.xyz[row].astype(np.float64)))
        return None if best is None else best[1]
