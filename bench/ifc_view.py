"""Render an IFC model written by jointseg through IfcOpenShell's own geometry kernel
(``ifcopenshell.geom``), so the docs show what an IFC viewer opens.

Without arguments it segments a 3-room synthetic floor (``jointseg synth --floor 3``) with the
bundled network, writes its IFC model with ``jointseg.objects.ifc.write_ifc`` and renders it;
``--ifc FILE`` renders an existing model instead. Walls, slabs and spaces are tessellated by
``ifcopenshell.geom`` (world coordinates) and drawn with matplotlib, each class in its colour;
the ceiling slabs are left out so the rooms can be seen from above.

    .venv/bin/python bench/ifc_view.py [--ifc model.ifc] [--out docs/images/ifc_floor.png]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from helpers.report import header

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

COLOURS = {
    "IfcWall": (0.70, 0.45, 0.32, 0.55),
    "IfcSlab": (0.75, 0.78, 0.82, 0.35),
    "IfcDoor": (0.42, 0.53, 0.29, 0.9),
    "IfcWindow": (0.30, 0.68, 0.33, 0.9),
    "IfcFurniture": (0.16, 0.19, 0.40, 0.9),
    "IfcBuildingElementProxy": (0.6, 0.6, 0.6, 0.5),
}


def make_model(folder: Path) -> Path:
    """A 3-room synthetic floor, segmented, as an IFC model."""
    from jointseg.objects.ifc import write_ifc
    from jointseg.pipeline import PipelineConfig, run
    from jointseg.synth import make_floor

    scan = make_floor(22, rooms=3, points=600_000)
    result = run(scan, PipelineConfig(seed=0))
    assert result.layout is not None
    path = folder / "floor.ifc"
    counts = write_ifc(result.layout.report, path, name="synthetic floor")
    print("wrote", path, counts)
    return path


def render(path: Path, out: Path) -> dict[str, int]:
    """Tessellate every product and draw it; the number of shapes per class."""
    import ifcopenshell
    import ifcopenshell.geom
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    model = ifcopenshell.open(str(path))
    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    fig = plt.figure(figsize=(12, 8), dpi=110)
    ax = fig.add_subplot(projection="3d")
    shown: dict[str, int] = {}
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    iterator = ifcopenshell.geom.iterator(settings, model)
    if iterator.initialize():
        while True:
            shape = iterator.get()
            product = model.by_id(shape.id)
            assert product is not None  # the iterator's shapes are the model's own products
            kind = product.is_a()
            name = product.Name or ""
            if kind in COLOURS and not (kind == "IfcSlab" and "ceiling" in name):
                verts = np.asarray(shape.geometry.verts).reshape(-1, 3)
                faces = np.asarray(shape.geometry.faces).reshape(-1, 3)
                ax.add_collection3d(
                    Poly3DCollection(verts[faces], facecolor=COLOURS[kind], edgecolor="none")
                )
                lo, hi = np.minimum(lo, verts.min(0)), np.maximum(hi, verts.max(0))
                shown[kind] = shown.get(kind, 0) + 1
            if not iterator.next():
                break
    span = float((hi - lo).max())
    centre = (lo + hi) / 2
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=True):
        setter(c - span / 2, c + span / 2)
    ax.view_init(elev=55, azim=-60)
    ax.set_axis_off()
    counts = ", ".join(f"{v} {k}" for k, v in sorted(shown.items()))
    ax.set_title(f"{path.name} through ifcopenshell.geom: {counts}", fontsize=9)
    fig.tight_layout()
    fig.savefig(out)
    return shown


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--ifc", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "ifc_floor.png")
    args = ap.parse_args()
    header()
    path = args.ifc or make_model(Path(tempfile.mkdtemp(prefix="ifc_view_")))
    print(render(path, args.out), "->", args.out)


if __name__ == "__main__":
    main()
