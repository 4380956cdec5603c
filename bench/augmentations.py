"""What each training augmentation does to the crops, measured: every augmentation alone at
full strength against none, on the same crop centres of a room (a synthetic one; a real
Area_6 room with ``--real`` when ../shared/data is there).

    .venv/bin/python bench/augmentations.py [--crops 40] [--points 4096] [--real]

Prints one row per augmentation: the statistic that shows its claim, without and with it.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np
from helpers.report import header
from scipy.spatial import cKDTree

from jointseg.io import read_scan
from jointseg.network.randlanet.crops import GridCloud, grid_subsample
from jointseg.synth import make_room
from jointseg.training.augment import AugmentParams
from jointseg.training.batches import region_crop, training_crop
from jointseg.training.sources import BASE_GRID

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
#: Every augmentation off: the baseline each row is compared with.
NONE = AugmentParams(
    elastic=0, density=0, partial=0, slice=0, tilt_degrees=0, colour_drop=0, grey=0,
    noise=(0.0, 0.0), exposure=0, stray=0, no_ceiling=0, holes=0, colour_cast=0,
)  # fmt: skip
Crop = tuple[np.ndarray, np.ndarray, np.ndarray]


def spacing_cm(c: Crop) -> float:
    """Median distance to the nearest other point (cm): the crop's density."""
    d, _ = cKDTree(c[0]).query(c[0], k=2)
    return 100 * float(np.median(d[:, 1]))


def floor_tilt_deg(c: Crop) -> float:
    """The floor's tilt (deg): the smallest eigenvector of its points' covariance against z."""
    floor = c[0][c[2] == 1]
    if len(floor) < 50:
        return float("nan")
    _, vecs = np.linalg.eigh(np.cov((floor - floor.mean(0)).T))
    return float(np.degrees(np.arccos(min(1.0, abs(vecs[2, 0])))))


def floor_noise_mm(c: Crop) -> float:
    """Spread of the floor points off their best plane (mm)."""
    floor = c[0][c[2] == 1]
    if len(floor) < 50:
        return float("nan")
    centred = floor - floor.mean(0)
    _, vecs = np.linalg.eigh(np.cov(centred.T))
    return 1000 * float(np.std(centred @ vecs[:, 0]))


def has_ceiling(c: Crop) -> float:
    """1 for a crop holding ceiling points (the median over crops is then the majority)."""
    return float((c[2] == 0).any())


def radius_m(c: Crop) -> float:
    """Median horizontal distance from the crop's middle (m): how much ground it covers."""
    return float(np.median(np.linalg.norm(c[0][:, :2] - np.median(c[0][:, :2], 0), axis=1)))


def height_m(c: Crop) -> float:
    return float(np.ptp(c[0][:, 2]))


def stray_share(c: Crop) -> float:
    return float((c[2] == -1).mean())


def colour_spread(c: Crop) -> float:
    """Spread of the three channels' means: a cast pulls them apart."""
    return float(np.ptp(c[1].mean(axis=0)))


def brightness(c: Crop) -> float:
    return float(c[1].mean())


def no_colour_share(c: Crop) -> float:
    return float(not c[1].any())


def grey_share(c: Crop) -> float:
    return float(np.allclose(c[1][:, 0], c[1][:, 1]) and np.allclose(c[1][:, 1], c[1][:, 2]))


ROWS: list[tuple[str, dict[str, object], str, Callable[[Crop], float]]] = [
    ("density 6 cm", {"density": 1.0, "density_range": (0.06, 0.06)}, "spacing (cm)", spacing_cm),
    ("density 6 cm", {"density": 1.0, "density_range": (0.06, 0.06)}, "radius (m)", radius_m),
    ("slice", {"slice": 1.0}, "height (m)", height_m),
    ("no ceiling", {"no_ceiling": 1.0}, "crops with ceiling (mean)", has_ceiling),
    ("tilt 3 deg", {"tilt_degrees": 3.0}, "floor tilt (deg)", floor_tilt_deg),
    ("noise 1-5 mm", {"noise": (0.001, 0.005)}, "floor off plane (mm)", floor_noise_mm),
    ("elastic", {"elastic": 1.0}, "floor off plane (mm)", floor_noise_mm),
    ("strays", {"stray": 1.0}, "stray share", stray_share),
    ("colour cast", {"colour_cast": 1.0}, "channel spread", colour_spread),
    ("exposure (gamma)", {"exposure": 1.0}, "brightness", brightness),
    ("colour drop", {"colour_drop": 1.0}, "crops without colour", no_colour_share),
    ("grey", {"grey": 1.0}, "grey crops", grey_share),
]


def crops(cloud: GridCloud, aug: AugmentParams, n: int, points: int) -> list[Crop]:
    """``n`` training crops, the same centres for any ``aug`` (seeded per crop)."""
    out = []
    for i in range(n):
        c = training_crop(cloud, points, 0.04, np.random.default_rng(i), aug)
        out.append((c.xyz, c.rgb, c.labels))
    return out


def missing_share(cloud: GridCloud, update: dict[str, object], n: int, points: int) -> np.ndarray:
    """Per crop centre: the share of the plain crop's surface (its points nearer the centre than
    the augmented crop reaches) with no augmented point within 5 cm: what a cut or a hole takes
    away. Compared before the rotation and scaling every crop gets, so the two line up."""
    out = []
    for i in range(n):
        centre = cloud.xyz[np.random.default_rng(i).integers(len(cloud.xyz))]
        plain = region_crop(cloud, centre, points, 0.04, np.random.default_rng(i), NONE)
        aug = NONE.model_copy(update=update)
        cut = region_crop(cloud, centre, points, 0.04, np.random.default_rng(i), aug)
        reach = 0.8 * np.linalg.norm(cut.xyz - centre, axis=1).max()
        inner = plain.xyz[np.linalg.norm(plain.xyz - centre, axis=1) < reach]
        gap = cKDTree(cut.xyz).query(inner)[0] > 0.05
        out.append(float(gap.mean()) if len(inner) else np.nan)
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--crops", type=int, default=40)
    ap.add_argument("--points", type=int, default=4096)
    ap.add_argument("--real", action="store_true", help="an Area_6 room instead of a synthetic one")
    args = ap.parse_args()
    header()
    if args.real:
        room = read_scan(SHARED / "s3dis_area6" / "area6_office_3.ply")
        name = "area6_office_3"
    else:
        room, name = make_room(7, points=300_000), "synthetic room, seed 7"
    cloud = grid_subsample(room.xyz, room.rgb, room.labels, BASE_GRID)
    base = crops(cloud, NONE, args.crops, args.points)
    print(f"{name}: {args.crops} crops of {args.points} points, each augmentation alone\n")
    print("| augmentation | statistic | without (median) | with (median) | with (max) |")
    print("|---|---|---|---|---|")
    for label, update, stat, fn in ROWS:
        with_it = crops(cloud, NONE.model_copy(update=update), args.crops, args.points)
        a = np.array([fn(c) for c in base])
        b = np.array([fn(c) for c in with_it])
        mid = np.nanmean if "(mean)" in stat else np.nanmedian
        print(f"| {label} | {stat} | {mid(a):.3g} | {mid(b):.3g} | {np.nanmax(b):.3g} |")
    for label, part in (("partial room", {"partial": 1.0}), ("holes", {"holes": 1.0})):
        b = missing_share(cloud, dict(part), args.crops, args.points)
        a = missing_share(cloud, {}, args.crops, args.points)
        print(f"| {label} | surface missing | {np.nanmedian(a):.3g} | {np.nanmedian(b):.3g} "
              f"| {np.nanmax(b):.3g} |")  # fmt: skip


if __name__ == "__main__":
    main()
