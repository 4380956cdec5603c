"""What the file itself says about its frame: the format's own convention (LAS, E57 z up;
glTF y up), a depth camera's organised cloud or VIEWPOINT (PCD), and the writer named in a
PLY/OBJ header comment or a glTF asset (phone apps write ARKit's gravity-aligned, y-up world).

The result is evidence, not a decision: a prior over the six signed file axes that the frame
stage weighs with the scan's geometry and the network (:mod:`jointseg.frame.weigh`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jointseg.scan import Scan

#: The six signed file axes, in the order every evidence vector uses.
SIGNED_AXES: tuple[str, ...] = ("+x", "-x", "+y", "-y", "+z", "-z")


@dataclass(frozen=True)
class Writer:
    """A program known by name, and what it is known to write."""

    pattern: str
    name: str
    up: str
    gravity_aligned: bool
    camera: bool = False


#: Writers named in header comments or a glTF ``asset.generator``. Phone apps write ARKit's
#: world frame (right handed, y up, gravity-aligned); RTAB-Map writes ROS's (z up); Intel's
#: RealSense viewer writes the camera's frame turned to OpenGL's (y up, looking along -z).
WRITERS: tuple[Writer, ...] = (
    Writer(r"polycam", "Polycam", "+y", True),
    Writer(r"scaniverse", "Scaniverse", "+y", True),
    Writer(r"3d ?scanner ?app|laan ?labs", "3D Scanner App", "+y", True),
    Writer(r"record3d", "Record3D", "+y", True),
    Writer(r"arkit|scenekit|realitykit|model ?i/?o", "ARKit", "+y", True),
    Writer(r"rtab-?map", "RTAB-Map", "+z", True),
    Writer(r"realsense", "Intel RealSense", "+y", False, camera=True),
)

#: The log-prior of a format's or writer's own axis against the other five.
STRONG, MODERATE = 3.0, 1.5


@dataclass(frozen=True)
class FileEvidence:
    """The file's own word on its frame.

    Attributes
    ----------
    prior : ndarray of shape (6,)
        Log-prior of each signed axis (:data:`SIGNED_AXES`) being up; zeros when the file
        says nothing.
    gravity_aligned : bool
        The format or writer puts gravity along a file axis (LAS, E57, phone apps): such a
        scan is never levelled.
    camera : bool
        The file is a single depth-camera frame (an organised PCD, a camera VIEWPOINT).
    says : list of str
        What was read, for the report.
    """

    prior: np.ndarray
    gravity_aligned: bool = False
    camera: bool = False
    says: list[str] = field(default_factory=list)

    def report(self) -> dict[str, Any]:
        """The ``frame.up.evidence.file`` section of report.json."""
        best = int(np.argmax(self.prior))
        return {
            "says": list(self.says),
            "axis": SIGNED_AXES[best] if self.prior[best] > 0 else None,
            "gravity_aligned": self.gravity_aligned,
            "camera_frame": self.camera,
        }


def _prior(axis: str, strength: float) -> np.ndarray:
    p = np.zeros(len(SIGNED_AXES))
    p[SIGNED_AXES.index(axis)] = strength
    return p


def find_writer(scan: Scan) -> Writer | None:
    """The first known writer named in the file's header comments or generator."""
    text = " ".join(str(c) for c in scan.meta.get("comments", []) or []).lower()
    if not text:
        return None
    for writer in WRITERS:
        if re.search(writer.pattern, text):
            return writer
    return None


def _camera_viewpoint(viewpoint: Any) -> bool:
    """True for PCL's OpenNI grabber's VIEWPOINT (a half turn about x: qw 0, qx 1), which it
    writes for every depth-camera frame."""
    try:
        q = np.asarray(viewpoint, dtype=np.float64).reshape(-1)[3:]
    except (TypeError, ValueError):
        return False
    return q.shape == (4,) and bool(np.allclose(np.abs(q), [0.0, 1.0, 0.0, 0.0], atol=1e-3))


def file_evidence(scan: Scan) -> FileEvidence:
    """Read the file's conventions and metadata (see the module)."""
    fmt = (scan.source_format or "").lower()
    meta = scan.meta or {}
    writer = find_writer(scan)
    convention = meta.get("up_convention") or {}
    if fmt in ("las", "laz"):
        return FileEvidence(
            _prior("+z", STRONG), True, False, [f"{fmt.upper()}: z up by definition"]
        )
    if fmt == "e57":
        return FileEvidence(
            _prior("+z", STRONG), True, False, ["E57: z up by definition, scan poses applied"]
        )
    if writer is not None:
        says = [f"written by {writer.name}: {writer.up[1]} up"]
        if writer.gravity_aligned:
            says[0] += ", gravity-aligned"
        return FileEvidence(_prior(writer.up, STRONG), writer.gravity_aligned, writer.camera, says)
    if convention.get("axis") in SIGNED_AXES:
        source = str(convention.get("source", "the format"))
        return FileEvidence(_prior(str(convention["axis"]), STRONG), False, False, [source])
    organised = meta.get("organised")
    if organised or _camera_viewpoint(meta.get("pcd_viewpoint")):
        what = (
            f"an organised {organised[0]} x {organised[1]} cloud"
            if organised
            else "a depth camera's VIEWPOINT"
        )
        return FileEvidence(
            _prior("-y", STRONG), False, True, [f"PCD: {what}: a depth camera's frame, y down"]
        )
    return FileEvidence(_prior("+z", MODERATE), False, False, ["no convention: z up is usual"])
