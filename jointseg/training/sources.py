"""Training data from several sources at once, each drawn with its own share.

Users' scans come from many sensors and buildings, and one dataset teaches a network one
building. ``jointseg train --data A:0.5 --data B:0.3 --data synth:0.2`` draws half the crops from
A, and so on. A source is ``synth``, a Stanford3dDataset_v1.2 folder (``Area_N/<room>/
Annotations``) or a folder of labelled scans in any readable format; ``NAME=`` in front names it
in reports (default: the folder's name).

Per source: its own validation scans (``--val-scan`` patterns, else ``val_count`` scans in a
name-hash order; S3DIS: the test area; synth: held-out seeds), its own class frequencies (crop
centres are balanced against them, so a rare class of one dataset is not drowned by a common
one of another), and its terms of use for the model card.
"""

from __future__ import annotations

import fnmatch
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from jointseg.classes import NUM_CLASSES
from jointseg.exceptions import ConfigError
from jointseg.network.randlanet.crops import GridCloud, grid_subsample
from jointseg.training.data import labelled_scan_files, split_validation

log = logging.getLogger(__name__)

#: Training keeps each scan at this grid (m): fine enough for the 1-6 cm density augmentation,
#: coarse enough that a dense room does not fill the memory.
BASE_GRID = 0.01

#: What a network trained on S3DIS-derived rooms carries with it (S3DIS's terms of use).
S3DIS_TERMS = (
    "trained on data derived from the Stanford Large-Scale 3D Indoor Spaces Dataset (S3DIS; "
    "Armeni et al., CVPR 2016), whose terms allow non-commercial research and educational use "
    "and ask users to cite the dataset paper; weights derived from it carry the same terms"
)
SCANNET_TERMS = (
    "trained on data derived from ScanNet (Dai et al., CVPR 2017), released under the ScanNet "
    "Terms of Use: non-commercial research and educational use only, cite the dataset paper; "
    "weights derived from it carry the same terms"
)
SYNTH_TERMS = "synthetic rooms only (jointseg.synth); no third-party data"
OTHER_TERMS = "user-supplied labelled scans: their own terms of use apply"
#: Pseudo-labels (jointseg.training.pseudo) come from the pipeline's network, trained
#: on S3DIS and ScanNet, so they carry the strictest terms of the data behind them.
PSEUDO_TERMS = (
    "pseudo-labels made by jointseg's pipeline, whose bundled network was trained on data "
    "derived from S3DIS (Armeni et al., CVPR 2016) and ScanNet (Dai et al., CVPR 2017), on "
    "unlabelled scans from the Point Cloud Library's data (BSD 3-clause) and Open3D-ML (MIT): "
    "the strictest terms of those apply, non-commercial research and educational use only, "
    "cite both dataset papers; weights derived from them carry the same terms"
)

_SPEC = re.compile(r"^(?:(?P<name>[A-Za-z0-9_.-]+)=)?(?P<path>.+?)(?::(?P<share>[0-9.]+))?$")


@dataclass(frozen=True)
class SourceSpec:
    """One ``--data`` entry: where, what to call it, and its share of the crops (None: equal)."""

    name: str
    path: str
    share: float | None

    @property
    def is_synth(self) -> bool:
        return self.path == "synth"


def parse_source(text: str) -> SourceSpec:
    """``[NAME=]PATH[:SHARE]`` or ``synth[:SHARE]``; a clear error for anything else."""
    match = _SPEC.match(text.strip())
    if not match:
        raise ConfigError(f"training data {text!r}: expected [NAME=]PATH[:SHARE] or synth[:SHARE]")
    path = match["path"]
    share = None
    if match["share"] is not None:
        try:
            share = float(match["share"])
        except ValueError:
            raise ConfigError(
                f"training data {text!r}: share {match['share']!r} is no number"
            ) from None
        if not 0 < share <= 1:
            raise ConfigError(f"training data {text!r}: share must be in (0, 1], got {share}")
    name = match["name"] or ("synth" if path == "synth" else Path(path).name or path)
    return SourceSpec(name, path, share)


def resolve_shares(specs: list[SourceSpec]) -> list[float]:
    """Each source's share of the crops: given shares as given, the rest split evenly among
    sources without one; the total must be 1 (within rounding)."""
    given = sum(s.share for s in specs if s.share is not None)
    free = [s for s in specs if s.share is None]
    if given > 1 + 1e-6 or (not free and abs(given - 1) > 1e-3):
        raise ConfigError(
            f"training data shares add up to {given:g}: they must add up to 1 "
            "(or leave some sources without a share to take the rest)"
        )
    rest = (1 - given) / len(free) if free else 0.0
    if free and rest <= 0:
        raise ConfigError("training data shares leave nothing for the sources without a share")
    return [s.share if s.share is not None else rest for s in specs]


def terms_for(spec: SourceSpec) -> str:
    """The terms of use a source's data carries (known public datasets by name or path)."""
    text = f"{spec.name} {spec.path}".lower()
    if spec.is_synth:
        return SYNTH_TERMS
    if "pseudo" in text:  # before the datasets: pseudo-labels carry both datasets' terms
        return PSEUDO_TERMS
    if "scannet" in text:
        return SCANNET_TERMS
    if "s3dis" in text or "stanford3d" in text or "area_" in text:
        return S3DIS_TERMS
    return OTHER_TERMS


@dataclass
class Source:
    """A loaded source: training clouds at :data:`BASE_GRID`, validation clouds at the network's
    grid, class frequencies of its training labels and a card line."""

    spec: SourceSpec
    share: float
    train: list[GridCloud]
    val: list[GridCloud]
    description: str
    terms: str
    train_names: list[str] = field(default_factory=list)
    val_names: list[str] = field(default_factory=list)

    @property
    def class_frequency(self) -> np.ndarray:
        """Share of each class among the labelled training points (labels -1 left out)."""
        labels = [c.labels[c.labels >= 0] for c in self.train if c.labels is not None]
        counts = np.bincount(np.concatenate(labels), minlength=NUM_CLASSES)[:NUM_CLASSES]
        return counts / max(int(counts.sum()), 1)


def matches(name: str, patterns: list[str]) -> bool:
    """Whether a scan's file stem matches any validation pattern (``fnmatch``, e.g.
    ``scene0002_*`` keeps every re-scan of a room together)."""
    return any(fnmatch.fnmatchcase(name, p) for p in patterns)


def _folder(
    spec: SourceSpec,
    grid: float,
    val_patterns: list[str],
    val_count: int,
    exclude_patterns: list[str],
) -> tuple[list[GridCloud], list[GridCloud], list[str], list[str]]:
    from jointseg.io import read_scan

    files = [
        p for p in labelled_scan_files(Path(spec.path)) if not matches(p.stem, exclude_patterns)
    ]
    if not files:
        raise ConfigError(f"training data {spec.path}: every scan is excluded")
    names = [p.stem for p in files]
    if val_patterns:
        val_names = [n for n in names if matches(n, val_patterns)]
    else:
        val_names = split_validation(names, [], val_count)
    if len(val_names) == len(names):
        raise ConfigError(f"training data {spec.path}: every scan is a validation scan")
    train, val, train_names = [], [], []
    for path in files:
        scan = read_scan(path)
        if scan.labels is None or not (scan.labels >= 0).any():
            raise ConfigError(f"{path}: no 'label' field with class ids, cannot train on it")
        if path.stem in val_names:
            val.append(grid_subsample(scan.xyz, scan.rgb, scan.labels, grid))
        else:
            train.append(grid_subsample(scan.xyz, scan.rgb, scan.labels, BASE_GRID))
            train_names.append(path.stem)
    return train, val, train_names, val_names


def _s3dis(root: Path, test_area: int, grid: float) -> tuple[list[GridCloud], list[GridCloud]]:
    from jointseg.io import read_scan

    train: list[GridCloud] = []
    val: list[GridCloud] = []
    for ann in sorted(root.glob("Area_*/*/Annotations")):
        scan = read_scan(ann.parent)
        held = ann.parent.parent.name == f"Area_{test_area}"
        cloud = grid_subsample(scan.xyz, scan.rgb, scan.labels, grid if held else BASE_GRID)
        (val if held else train).append(cloud)
    return train, val


def _synth(
    rooms: int, floors: int, val_rooms: int, points: int, grid: float
) -> tuple[list[GridCloud], list[GridCloud], str]:
    from jointseg.synth import make_floor, make_room

    train: list[GridCloud] = []
    val: list[GridCloud] = []
    for i in range(rooms):
        scan = make_room(1000 + i, points=points, shape="L" if i % 3 == 2 else "box")
        train.append(grid_subsample(scan.xyz, scan.rgb, scan.labels, BASE_GRID))
    for i in range(floors):
        scan = make_floor(3000 + i, points=points * 3)
        train.append(grid_subsample(scan.xyz, scan.rgb, scan.labels, BASE_GRID))
    for i in range(val_rooms):
        scan = make_room(2000 + i, points=points, shape="L" if i % 2 else "box")
        val.append(grid_subsample(scan.xyz, scan.rgb, scan.labels, grid))
    text = (
        f"jointseg.synth: {rooms} rooms (seeds 1000+, box and L, random yaw, {points} points) "
        f"and {floors} floors (seeds 3000+); validation rooms seeds 2000+"
    )
    return train, val, text


@dataclass(frozen=True)
class SourceOptions:
    """The training options that say how sources are loaded."""

    grid: float
    val_patterns: list[str]
    exclude_patterns: list[str]
    val_count: int
    test_area: int
    synth_rooms: int
    synth_floors: int
    synth_val_rooms: int
    synth_points: int


def load_source(spec: SourceSpec, share: float, opts: SourceOptions) -> Source:
    """Read one source's scans (see the module docstring for the kinds)."""
    if spec.is_synth:
        train, val, text = _synth(
            opts.synth_rooms, opts.synth_floors, opts.synth_val_rooms, opts.synth_points, opts.grid
        )
        return Source(spec, share, train, val, text, SYNTH_TERMS)
    root = Path(spec.path)
    if root.is_dir() and any(root.glob("Area_*/*/Annotations")):
        train, val = _s3dis(root, opts.test_area, opts.grid)
        text = f"S3DIS at {root}, Area_{opts.test_area} held out ({len(train)} rooms)"
        return Source(spec, share, train, val, text, terms_for(spec))
    if root.is_dir() and not any(root.iterdir()):
        raise ConfigError(
            f"training data {root}: empty folder (expected labelled scans or the "
            "Stanford3dDataset_v1.2 Area_N/<room>/Annotations layout)"
        )
    train, val, train_names, val_names = _folder(
        spec, opts.grid, opts.val_patterns, opts.val_count, opts.exclude_patterns
    )
    text = (
        f"{len(train_names)} labelled scans from {root} ({', '.join(train_names)}); "
        f"validation (never trained on): {', '.join(val_names) or 'none'}"
    )
    return Source(spec, share, train, val, text, terms_for(spec), train_names, val_names)


def load_sources(texts: list[str], opts: SourceOptions) -> list[Source]:
    """Every ``--data`` source, loaded; validation patterns that match no scan are an error."""
    specs = [parse_source(t) for t in texts]
    if not specs:
        raise ConfigError("no training data: give --data at least once")
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        raise ConfigError(f"training data names repeat ({', '.join(names)}): name them NAME=PATH")
    shares = resolve_shares(specs)
    sources = [load_source(s, share, opts) for s, share in zip(specs, shares, strict=True)]
    seen = [n for src in sources for n in src.val_names]
    unused = [p for p in opts.val_patterns if not any(fnmatch.fnmatchcase(n, p) for n in seen)]
    if unused:
        raise ConfigError(f"validation scans not in any training folder: {', '.join(unused)}")
    for src in sources:
        log.info("source %s (share %.2f): %s", src.spec.name, src.share, src.description)
    return sources
