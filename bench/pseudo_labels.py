"""Self-training's confidence rule (issue 65): how many points each rule keeps and how often the
kept labels are right.

The pipeline (default configuration, bundled network) labels the tuning ScanNet scans and
``--views`` depth-camera views of every tuning room (S3DIS Area_6 and ScanNet, as
bench/camera_views.py cuts them: camera frame, the frame stage decides up) with their labels
hidden; the truth then scores what each rule keeps. Judging rooms (bench/helpers/scans.py's
split: ScanNet scene0002, scene0005, scene0007 and ten S3DIS rooms) and the pack's validation
and judging scans are never used.

Per rule: the share of points kept, the accuracy of the kept labels against the truth (points
whose truth is known), and per class the kept labels' accuracy (precision) and the share of
that class's true points kept. The first row is every fused label, the second the structure
reading alone (where sure and the fused label agrees); rules are (structure, share, prob),
the vote's labels only on scans with a floor read unless said (see PseudoRule).

    flock /tmp/cpu.lock nice -n 5 .venv/bin/python bench/pseudo_labels.py [--views 3]
"""

from __future__ import annotations

import argparse
import logging
import zlib
from dataclasses import dataclass

import numpy as np
from helpers.inputs import AREA6, CACHE, SCANNET
from helpers.report import header
from helpers.scans import load_items

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.network import load
from jointseg.synth.views import camera_view
from jointseg.training.prepared import JUDGING, VALIDATION
from jointseg.training.pseudo import Evidence, PseudoRule, keep_labels, pseudo_label
from jointseg.training.sources import matches

#: Rules compared (the default, PseudoRule(), is the one the pack uses).
RULES: dict[str, PseudoRule] = {
    "loose (0.5, 0.8, 0.8)": PseudoRule(structure=0.5, share=0.8, prob=0.8),
    "(0.7, 0.9, 0.8)": PseudoRule(structure=0.7, share=0.9, prob=0.8),
    "(0.8, 0.95, 0.9)": PseudoRule(structure=0.8, share=0.95, prob=0.9),
    "(0.9, 0.8, 0.8)": PseudoRule(structure=0.9, share=0.8, prob=0.8),
    "default (0.9, 0.9, 0.9)": PseudoRule(),
    "strict (0.9, 0.95, 0.95)": PseudoRule(structure=0.9, share=0.95, prob=0.95),
    "default, vote on floorless scans too": PseudoRule(vote_needs_floor=False),
}
#: Classes in the per-class columns (the rest are in the overall figures).
SHOWN = ("ceiling", "floor", "wall", "window", "door", "table", "chair", "sofa", "bookcase",
         "clutter")  # fmt: skip


@dataclass
class Labelled:
    """One scan's evidence and truth (work scan's points)."""

    name: str
    kind: str  # "scan" or "view"
    evidence: Evidence
    truth: np.ndarray


def collect(views: int) -> list[Labelled]:
    """The pipeline's evidence on every tuning scan and view (cached under bench/_cache)."""
    predictor = load("randlanet")
    out = []
    for item in load_items([str(AREA6), str(SCANNET)], 10, (0, 0, 0)):
        if item.split != "tune" or matches(
            item.name, [f"{p}*" for p in JUDGING] + list(VALIDATION)
        ):
            continue
        scans = [("scan", item.scan)] if item.dataset == "ScanNet" else []
        rng = np.random.default_rng([7, zlib.crc32(item.name.encode())])
        for i in range(views):
            view = camera_view(item.scan, rng)
            if view is not None:
                scans.append((f"view {i}", view.scan))
        for kind, scan in scans:
            out.append(_labelled(f"{item.name} {kind}", kind, scan, predictor))
    return out


def _labelled(name: str, kind: str, scan: object, predictor: object) -> Labelled:
    from jointseg.scan import Scan

    assert isinstance(scan, Scan) and scan.labels is not None
    path = CACHE / "pseudo" / f"{zlib.crc32(name.encode()):08x}-{len(scan)}.npz"
    if path.is_file():
        z = np.load(path)
        ev = Evidence(
            fused=z["fused"],
            prob=z["prob"],
            structure=z["structure"],
            structure_confidence=z["confidence"],
            share=z["share"],
            floor=bool(z["floor"]),
        )
        return Labelled(name, kind, ev, z["truth"])
    pseudo, result = pseudo_label(scan, PseudoRule(), predictor)  # type: ignore[arg-type]
    ev, truth = pseudo.evidence, scan.labels[~result.stray]
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {"fused": ev.fused, "prob": ev.prob, "structure": ev.structure,
              "confidence": ev.structure_confidence, "share": ev.share, "truth": truth,
              "floor": np.array(ev.floor)}  # fmt: skip
    np.savez_compressed(path, **arrays)  # type: ignore[arg-type]
    return Labelled(name, kind, ev, truth)


def structure_only(ev: Evidence, least: float) -> np.ndarray:
    """The structure reading alone, where the fused label agrees and it is sure."""
    sure = (ev.structure >= 0) & (ev.fused == ev.structure) & (ev.structure_confidence >= least)
    return np.where(sure, ev.fused, -1)


def row(name: str, scans: list[Labelled], rule: PseudoRule | float | None) -> str:
    """One table row: kept share, accuracy, per class accuracy / kept share of the truth
    (``rule`` None: every fused label; a number: the structure reading alone at that least
    confidence)."""
    kept, truth = [], []
    for s in scans:
        if rule is None:
            kept.append(s.evidence.fused)
        elif isinstance(rule, float):
            kept.append(structure_only(s.evidence, rule))
        else:
            kept.append(keep_labels(s.evidence, rule))
        truth.append(s.truth)
    k, t = np.concatenate(kept).astype(np.int64), np.concatenate(truth).astype(np.int64)
    known = (k >= 0) & (t >= 0)
    cells = [f"{(k >= 0).mean():.1%}", f"{(k == t)[known].mean():.1%}"]
    for cls in SHOWN:
        c = CLASS_NAMES.index(cls)
        said = known & (k == c)
        precision = f"{(t[said] == c).mean():.0%}" if said.any() else "-"
        recall = f"{(k[t == c] == c).mean():.0%}" if (t == c).any() else "-"
        cells.append(f"{precision} / {recall}")
    return f"| {name} | " + " | ".join(cells) + " |"


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--views", type=int, default=3, help="views per tuning room")
    args = parser.parse_args()
    header("self-training's confidence rule (tuning ScanNet scans and camera views)")
    logging.basicConfig(level=logging.ERROR)
    if not SCANNET.is_dir():
        raise SystemExit(f"no real rooms under {SCANNET.parent}: this bench needs ../shared/data")
    scans = collect(args.views)
    assert NUM_CLASSES == len(CLASS_NAMES)
    for title, sel in (
        ("whole ScanNet tuning scans", [s for s in scans if s.kind == "scan"]),
        ("camera views of the tuning rooms", [s for s in scans if s.kind != "scan"]),
    ):
        points = sum(len(s.truth) for s in sel)
        floors = sum(s.evidence.floor for s in sel)
        print(f"\n{title}: {len(sel)} scans ({floors} with a floor read), {points:,} points; "
              "per class: accuracy of kept labels / share of its true points kept\n")  # fmt: skip
        print("| rule | kept | accuracy | " + " | ".join(SHOWN) + " |")
        print("|---" * (3 + len(SHOWN)) + "|")
        print(row("all fused labels", sel, None))
        print(row("structure reading >= 0.9 only", sel, 0.9))
        for name, rule in RULES.items():
            print(row(name, sel, rule))


if __name__ == "__main__":
    main()
