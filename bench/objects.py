"""Objects and rooms (issue 33): how well objects are grouped, rooms measured, and what it costs.

Objects: per class, instance precision / recall / F1 at IoU >= 0.5, grouping (a) the true labels
(what the grouping itself can do) and (b) the fused labels of ``jointseg.pipeline.run`` with the
bundled network (what a user gets; "inventory": only the objects of their class's shape,
``jointseg.objects.shapes``, set on the tuning scans). Scans: ScanNet's in
../shared/data/scannet (their own ``instance`` ids; scene0002, 0005 and 0007 judge, the others
tune) and synthetic rooms (``jointseg.synth`` knows every object; seeds 11-14 and 20-21 judge,
1-8 tuned the contact distance). Per scan: chairs and tables found against the truth.

Rooms: on synthetic rooms and 3-room floors (true plans from ``jointseg.synth.room_layout`` /
``floor_layout``): floor area and ceiling height against the truth, walls, doors and windows
found, door and window widths.

Cost: the objects stage's seconds against the whole run on the 1 M-point room (``jointseg synth
--seed 1501 --points 1000000``), the same ``run`` call, as a share.

    .venv/bin/python bench/objects.py [--part objects|rooms|cost|all] [--points 200000]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Literal

import numpy as np
from helpers.report import header

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SHARED = ROOT.parent / "shared" / "data"
JUDGING = ("scene0002", "scene0005", "scene0007")
CLASSES = (5, 6, 7, 8, 9, 10)  # window, door, table, chair, sofa, bookcase
#: Synthetic rooms judged (never tuned on): 11-14, and 20-21, the first later seeds with sofas.
JUDGING_SEEDS = (11, 12, 13, 14, 20, 21)


def _scores(rows: list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]) -> dict:
    """Summed (tp, fp, fn) per class over (name, truth ids, truth labels, found ids, labels)."""
    from jointseg.objects.scoring import match_counts

    totals = {c: np.zeros(3, int) for c in CLASSES}
    for _, t_ids, t_lab, f_ids, f_lab in rows:
        for c, v in match_counts(t_ids, t_lab, f_ids, f_lab, classes=CLASSES).items():
            totals[c] += v
    return totals


def _print_scores(title: str, totals: dict) -> None:
    from jointseg.classes import CLASS_NAMES
    from jointseg.objects.scoring import f1

    print(f"\n{title}\n\n| class | true | found | precision | recall | F1 |")
    print("|---|---|---|---|---|---|")
    for c, (tp, fp, fn) in totals.items():
        p, r, f = f1(int(tp), int(fp), int(fn))
        print(f"| {CLASS_NAMES[c]} | {tp + fn} | {tp + fp} | {p:.2f} | {r:.2f} | {f:.2f} |")


def objects_part(points: int) -> None:
    from jointseg.io import read_scan
    from jointseg.objects.instances import find_instances
    from jointseg.pipeline import PipelineConfig, load_predictor, run
    from jointseg.spacing import estimate_spacing
    from jointseg.synth import make_room

    config = PipelineConfig(seed=0)
    predictor = load_predictor(config.network)
    sets: dict[str, list[tuple]] = {}
    counts = []
    scans = []
    if (SHARED / "scannet").is_dir():
        for path in sorted((SHARED / "scannet").glob("*.ply")):
            scan = read_scan(path)
            truth = np.where(scan.fields["instance"] > 0, scan.fields["instance"], -1)
            split = "ScanNet judging" if path.stem.startswith(JUDGING) else "ScanNet tuning"
            scans.append((split, path.stem, scan, truth))
    else:
        print("(../shared/data/scannet missing: ScanNet rows left out)")
    for seed in JUDGING_SEEDS:
        scan = make_room(seed, points=points, shape="L" if seed % 2 == 0 else "box")
        truth = np.where(scan.fields["instance"] >= 0, scan.fields["instance"], -1)
        scans.append(("synthetic judging", f"synth{seed}", scan, truth))
    for split, name, scan, truth in scans:
        assert scan.labels is not None, f"{name} has no labels"
        spacing = estimate_spacing(scan.xyz)
        from_truth = find_instances(scan.xyz, scan.labels, spacing)
        result = run(scan, config, predictor=predictor)
        fused = result.fused_labels
        sets.setdefault(f"{split}, true labels", []).append(
            (name, truth, scan.labels, from_truth, scan.labels)
        )
        sets.setdefault(f"{split}, fused labels", []).append(
            (name, truth, scan.labels, result.instances, fused)
        )
        # the inventory: objects of their class's shape (fragments are not counted)
        objects = result.layout.report.objects if result.layout else []
        fragments = [o.id for o in objects if not o.plausible]
        inventory = np.where(np.isin(result.instances, fragments), -1, result.instances)
        sets.setdefault(f"{split}, fused labels, inventory", []).append(
            (name, truth, scan.labels, inventory, fused)
        )
        per = {}
        for cls, label in ((8, "chair"), (7, "table")):
            t = len({int(i) for i in np.unique(truth[(scan.labels == cls) & (truth >= 0)])})
            f = sum(o.cls == label and o.plausible for o in objects)
            per[label] = (t, f)
        counts.append((split, name, per))
    for title, rows in sets.items():
        _print_scores(f"Objects, {title}", _scores(rows))
    print("\n| split | scan | chairs true / found (fused) | tables true / found (fused) |")
    print("|---|---|---|---|")
    for split, name, per in counts:
        print(f"| {split} | {name} | {per['chair'][0]} / {per['chair'][1]} | "
              f"{per['table'][0]} / {per['table'][1]} |")  # fmt: skip


def _wall_count(faces: list) -> int:
    """Walls of a true plan: faces on one line that touch are one wall."""
    spans = sorted((f.axis, round(f.coord, 3), f.u0, f.u1) for f in faces)
    count, last = 0, None
    for axis, coord, u0, u1 in spans:
        if last is None or (axis, coord) != last[:2] or u0 > last[2] + 1e-6:
            count += 1
        last = (axis, coord, u1 if last is None or (axis, coord) != last[:2] else max(u1, last[2]))
    return count


def rooms_part(points: int) -> None:
    from jointseg.objects.layout import find_layout
    from jointseg.spacing import estimate_spacing
    from jointseg.synth import floor_layout, make_floor, make_room, room_layout

    print("\n| scan | true area m² | found m² | error | true height | found | walls true / found |"
          " doors true / found | windows true / found | door widths true | found |"
          " window widths true | found |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for seed in (11, 12, 13, 14):
        shape: Literal["box", "L"] = "L" if seed % 2 == 0 else "box"
        scan, plan = make_room(seed, points=points, shape=shape), room_layout(seed, shape=shape)
        assert scan.labels is not None  # synthetic rooms are labelled
        layout = find_layout(scan.xyz, scan.labels, None, estimate_spacing(scan.xyz)).report
        room = layout.rooms[0] if layout.rooms else None
        found = room.floor_area if room else float("nan")
        truth = plan.spaces[0].area
        openings = [o for w in layout.walls for o in w.openings]
        doors_t = sorted(round(o.width, 2) for o in plan.openings if o.kind == "door")
        doors_f = sorted(round(o.width, 2) for o in openings if o.kind == "door")
        wins_t = sorted(round(o.width, 2) for o in plan.openings if o.kind == "window")
        wins_f = sorted(round(o.width, 2) for o in openings if o.kind == "window")
        walls_t = _wall_count(plan.spaces[0].faces)
        height = room.ceiling_height if room else float("nan")
        error = 100 * (found / truth - 1)
        print(f"| synth{seed} ({shape}) | {truth:.2f} | {found:.2f} | {error:+.1f} % | "
              f"{plan.height:.3f} | {height:.3f} | {walls_t} / {len(layout.walls)} | "
              f"{len(doors_t)} / {len(doors_f)} | {len(wins_t)} / {len(wins_f)} | {doors_t} | "
              f"{doors_f} | {wins_t} | {wins_f} |")  # fmt: skip
    for seed in (21, 22):
        scan, plan = make_floor(seed, rooms=3, points=2 * points), floor_layout(seed, rooms=3)
        assert scan.labels is not None  # synthetic floors are labelled
        layout = find_layout(scan.xyz, scan.labels, None, estimate_spacing(scan.xyz)).report
        spaces = sorted(round(s.area, 1) for s in plan.spaces)
        rooms = sorted(round(r.floor_area, 1) for r in layout.rooms)
        print(f"| floor{seed} (3 rooms + corridor) | {spaces} | {rooms} | {len(rooms)} of "
              f"{len(spaces)} spaces | | | | | | | | | |")  # fmt: skip


def cost_part() -> None:
    from jointseg.pipeline import PipelineConfig, load_predictor, run
    from jointseg.synth import make_room

    scan = make_room(1501, points=1_000_000)
    config = PipelineConfig(seed=0)
    predictor = load_predictor(config.network)
    rows = []
    for enabled in (False, True, False, True):
        cfg = config.model_copy(
            update={"objects": config.objects.model_copy(update={"enabled": enabled})}
        )
        t = time.perf_counter()
        result = run(scan, cfg, predictor=predictor)
        rows.append((enabled, time.perf_counter() - t, result.timings.get("objects", 0.0)))
    print("\n| objects stage | run (s) | objects (s) |\n|---|---|---|")
    for enabled, total, objects in rows:
        print(f"| {'on' if enabled else 'off'} | {total:.2f} | {objects:.2f} |")
    off = np.median([r[1] for r in rows if not r[0]])
    on = np.median([r[1] for r in rows if r[0]])
    print(f"\nwith objects / without: {on / off:.3f} (run() on the 1 M-point room, same process)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--part", choices=("objects", "rooms", "cost", "all"), default="all")
    ap.add_argument("--points", type=int, default=200_000)
    args = ap.parse_args()
    header()
    if args.part in ("objects", "all"):
        objects_part(args.points)
    if args.part in ("rooms", "all"):
        rooms_part(args.points)
    if args.part in ("cost", "all"):
        cost_part()


if __name__ == "__main__":
    main()
