"""What a downloaded file must be: bytes the reader of its format parses (laspy for LAS and LAZ,
json for the report and objects.json, the STEP header of an IFC file, the PLY header).

A module of its own (not conftest) so the job page's and the viewer's tests import it by name.
"""

from __future__ import annotations

import io
import json
from typing import Any

import laspy
import numpy as np

#: The job page's buttons and the viewer's, in the order both show them, with the file name each
#: saves under (after the upload's stem).
PAGE_BUTTONS = {"ply": "PLY", "las": "LAS", "laz": "LAZ", "report": "report", "objects": "objects",
                "ifc": "IFC"}  # fmt: skip
VIEWER_BUTTONS = {"ply": "PLY", "las": "LAS", "laz": "LAZ", "report": "Report",
                  "objects": "objects.json", "ifc": "IFC"}  # fmt: skip
SUFFIXES = {"ply": "_segmented.ply", "las": "_segmented.las", "laz": "_segmented.laz",
            "report": "_report.json", "objects": "_objects.json", "ifc": ".ifc"}  # fmt: skip


def parsed(kind: str, body: bytes, points: int) -> Any:
    """``body`` read as a ``kind`` download of a result with ``points`` points; raises
    (AssertionError, or the reader's error) when it is not one."""
    if kind == "ply":
        assert body.startswith(b"ply\n"), body[:40]
        header = body[: body.index(b"end_header")].decode("ascii")
        assert f"element vertex {points}" in header and "fused_label" in header, header
        return header
    if kind in ("las", "laz"):
        las = laspy.read(io.BytesIO(body))
        assert las.header.point_count == points
        assert (kind == "laz") == las.header.are_points_compressed
        fused = np.asarray(las["fused_label"])
        assert fused.min() >= 0 and fused.max() <= 12
        return las
    if kind in ("report", "objects"):
        value = json.loads(body)
        if kind == "report":
            assert value["points"] == points
        else:
            assert {"objects", "rooms", "walls"} <= set(value), sorted(value)
        return value
    assert kind == "ifc"
    assert body.startswith(b"ISO-10303-21;"), body[:40]
    assert b"FILE_SCHEMA(('IFC4'))" in body[:2000] and body.rstrip().endswith(b"END-ISO-10303-21;")
    return body
