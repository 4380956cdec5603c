"""Hostile scan files (issue 44, point 1), made without ever holding what they claim: a LAZ
whose header lies about its point count, an NPZ that inflates a thousandfold, and PLY and PCD
headers declaring far more points than their bodies hold. Shared by the tests and
bench/hostile_uploads.py."""

from __future__ import annotations

import struct
import zipfile
from pathlib import Path

import numpy as np

from jointseg.io import write_scan
from jointseg.scan import Scan

#: Points each hostile file claims (below the service's 50 M max_points).
CLAIMED = 40_000_000


def liar_laz(folder: Path, *, points: int = 900) -> Path:
    """A ~6 KB LAZ of ``points`` real points whose header claims :data:`CLAIMED` (LAS 1.4
    keeps the count twice: the legacy 32-bit field at byte 107, the 64-bit one at 247)."""
    path = folder / "liar.laz"
    if not path.exists():
        rng = np.random.default_rng(0)
        write_scan(Scan(xyz=rng.random((points, 3)) * 5), path)
        data = bytearray(path.read_bytes())
        struct.pack_into("<I", data, 107, CLAIMED)
        struct.pack_into("<Q", data, 247, CLAIMED)
        path.write_bytes(bytes(data))
    return path


def bomb_npz(folder: Path, *, points: int = CLAIMED) -> Path:
    """A valid deflated NPZ of ``points`` points at the origin (0.47 MB for 40 M points, 480
    MB once inflated), written a few MB at a time."""
    path = folder / "bomb.npz"
    if not path.exists():
        header = {"descr": "<f4", "fortran_order": False, "shape": (points, 3)}
        with (
            zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as zf,
            zf.open("xyz.npy", "w", force_zip64=True) as fh,
        ):
            np.lib.format.write_array_header_1_0(fh, header)
            block = bytes(12 * 1_000_000)
            for start in range(0, points, 1_000_000):
                fh.write(block[: 12 * min(1_000_000, points - start)])
    return path


def liar_ply(folder: Path) -> Path:
    """An ASCII PLY declaring :data:`CLAIMED` vertices, with three."""
    path = folder / "liar.ply"
    path.write_text(
        f"ply\nformat ascii 1.0\nelement vertex {CLAIMED}\nproperty float x\n"
        "property float y\nproperty float z\nend_header\n0 0 0\n1 1 1\n2 2 2\n"
    )
    return path


def liar_pcd(folder: Path) -> Path:
    """An ASCII PCD declaring :data:`CLAIMED` points, with three."""
    path = folder / "liar.pcd"
    path.write_text(
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {CLAIMED}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {CLAIMED}\nDATA ascii\n"
        "0 0 0\n1 1 1\n2 2 2\n"
    )
    return path


#: Each kind of hostile file, by name.
HOSTILE = {"laz": liar_laz, "npz": bomb_npz, "ply": liar_ply, "pcd": liar_pcd}
