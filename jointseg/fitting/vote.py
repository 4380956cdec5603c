"""Fitting the learned vote (``vote_model.json``) on labelled tuning scans: the plan (which
scans, labelled by which networks, weighed how), every scan's offers as the vote makes them,
and the model file with its provenance.

Why a plan file: the inputs of a shipped model must be named, not implied by a script's
defaults, so that `jointseg fit vote --plan PLAN` on the same scans writes the same file. The
trees themselves are fitted in :mod:`jointseg.fitting.vote_trees` (scikit-learn, the ``fit``
extra); nothing here is needed at run time, where the model is plain JSON read by
:class:`jointseg.fusion.tree_runtime.TreeEnsemble`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from jointseg.config_file import load_params_file
from jointseg.exceptions import ConfigError
from jointseg.fitting.outputs import (
    Predictors,
    geometry_output,
    labeller_record,
    network_name,
    network_output,
    network_spec,
)
from jointseg.fitting.provenance import LabellerRecord, ScanRecord, only_known
from jointseg.fitting.scans import (
    TuningScan,
    Variant,
    named_scan_files,
    read_labelled,
    synthetic_rooms,
    variant,
)
from jointseg.fusion.offers import (
    DEFAULT_CELL_SIZE,
    FEATURES,
    Offers,
    StructureHint,
    vote_offers,
)
from jointseg.fusion.thresholds import ClassTally

log = logging.getLogger(__name__)

#: How a labeller's probabilities are deliberately distorted (see :func:`distort`).
Distortion = Literal["biased", "overconfident", "underconfident", "lost"]
#: Class confusions a biased network makes (from -> to; 60 % of the first class's probability
#: moves to the second): furniture swapped, objects taken for the wall behind them.
BIAS = ((7, 8), (8, 7), (11, 2), (5, 2), (10, 12), (6, 2))
#: What a network lost on a sensor it never saw takes the room's shell for (issue 43): from a
#: structural class to one of the classes it is confused with, chosen per LOST_CELL-metre cell
#: of the floor plan, so that whole wall stretches and floor patches are wrong alike.
LOST = {
    2: (12, 10, 6, 4, 5, 12),  # wall: clutter (twice as often), bookcase, door, column, window
    1: (8, 7, 12),  # floor: chair, table, clutter
    0: (12, 3),  # ceiling: clutter, beam
}
#: Share of a structural class's probability the lost network moves, and its cell size. 0.8
#: leaves a sure network's wall about 0.16, inside the spread of what the bundled network gives
#: the ScanNet tuning walls it labels otherwise (quartiles 0.03, 0.09, 0.20); 0.7 left 0.27,
#: above three quarters of them (docs/guide/structure.md).
LOST_SHARE, LOST_CELL = 0.8, 5.0


class Labeller(BaseModel):
    """A network (``backend[:weights]``), optionally with its probabilities distorted."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    network: str = Field(min_length=1)
    distortion: Distortion | None = None


class SyntheticRooms(BaseModel):
    """Generated rooms (seeds ``first_seed``..) and floors (seeds ``first_seed + 100``..)."""

    model_config = ConfigDict(extra="forbid")

    first_seed: int = Field(7000, ge=0)
    rooms: int = Field(6, ge=0)
    floors: int = Field(0, ge=0)
    points: int = Field(100_000, ge=1000)


class VoteDataset(BaseModel):
    """A set of tuning scans, how they are made, who labels them and what they weigh."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(min_length=1)
    #: labelled scan files, or folders of them, relative to the plan's folder
    scans: list[Path] = []
    synthetic: SyntheticRooms | None = None
    variant: Variant = "as is"
    labellers: list[Labeller] = Field(min_length=1)
    #: the dataset's weight: every dataset weighs the same times this
    weight: float = Field(1.0, gt=0)

    @model_validator(mode="after")
    def _some_scans(self) -> VoteDataset:
        if not self.scans and (
            self.synthetic is None or self.synthetic.rooms + self.synthetic.floors == 0
        ):
            raise ValueError(f"dataset {self.name!r} names no scans and no synthetic rooms")
        return self


class TreeParams(BaseModel):
    """The gradient-boosted trees' settings."""

    model_config = ConfigDict(extra="forbid")

    trees: int = Field(50, ge=1)
    depth: int = Field(2, ge=1)
    min_leaf: int = Field(200, ge=1)
    l2: float = Field(1.0, ge=0)
    learning_rate: float = Field(0.1, gt=0)
    #: monotone in the support of the offer and of the point's own label (see vote_trees)
    monotonic: bool = True
    #: offer the geometry's structure reading (False: the vote before issue 43)
    structure: bool = True
    #: features held constant (unusable), to measure what each one brings
    drop_features: list[str] = []

    @field_validator("drop_features")
    @classmethod
    def _known(cls, names: list[str]) -> list[str]:
        return only_known(names, FEATURES, "features")


class VotePlan(BaseModel):
    """Everything a vote fit reads besides the scans' and weights' bytes."""

    model_config = ConfigDict(extra="forbid")

    datasets: list[VoteDataset] = Field(min_length=1)
    fit: TreeParams = TreeParams()
    cell_size: float = Field(DEFAULT_CELL_SIZE, ge=0)
    #: least probability of an offered class at its point (None: FusionParams' default)
    min_support: float | None = Field(None, ge=0, le=1)
    #: the terms of use of the data, copied into the model's card
    data_terms: str = ""

    @field_validator("datasets")
    @classmethod
    def _unique(cls, datasets: list[VoteDataset]) -> list[VoteDataset]:
        names = [d.name for d in datasets]
        if len(set(names)) != len(names):
            raise ValueError(f"dataset names repeat: {names}")
        return datasets


def read_plan(path: Path, **overrides: object) -> VotePlan:
    """The plan at ``path``, validated (a ConfigError naming the file and field otherwise);
    ``overrides`` replace settings of its ``fit`` section (the command line's options)."""
    plan = load_params_file(path, VotePlan)
    given = {k: v for k, v in overrides.items() if v is not None}
    if given:
        fit = load_params_file(None, TreeParams, {**plan.fit.model_dump(), **given})
        plan = plan.model_copy(update={"fit": fit})
    return plan


def distort(probs: np.ndarray, kind: str, xyz: np.ndarray | None = None) -> np.ndarray:
    """Probabilities of a deliberately different network: 'biased' (the confusions of BIAS),
    'overconfident' (temperature 0.5), 'underconfident' (temperature 2) or 'lost' (the shell
    taken for furniture and objects, see LOST; needs the points ``xyz``)."""
    p = probs.astype(np.float64)
    if kind == "lost":
        if xyz is None:
            raise ValueError("the 'lost' distortion needs the points")
        p = lost(p, xyz)
    elif kind == "biased":
        for a, b in BIAS:
            moved = 0.6 * p[:, a]
            p[:, a] -= moved
            p[:, b] += moved
    elif kind in ("overconfident", "underconfident"):
        p = np.power(np.maximum(p, 1e-8), 2.0 if kind == "overconfident" else 0.5)
    else:
        raise ValueError(f"unknown distortion {kind!r}")
    return (p / p.sum(axis=1, keepdims=True)).astype(np.float32)


def lost(p: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """LOST's confusions: in every plan cell, each structural class hands LOST_SHARE of its
    probability to the confused class that cell draws (a fixed hash of the cell, so the same
    scan is distorted the same way every time)."""
    cell = np.floor(xyz[:, :2] / LOST_CELL).astype(np.int64)
    draw = (cell[:, 0] * 73_856_093) ^ (cell[:, 1] * 19_349_663)
    p = p.copy()
    for source, targets in LOST.items():
        target = np.asarray(targets)[np.abs(draw) % len(targets)]
        moved = LOST_SHARE * p[:, source]
        p[:, source] -= moved
        np.add.at(p, (np.arange(len(p)), target), moved)
    return p


def structure_hint(geo: dict[str, np.ndarray]) -> StructureHint | None:
    """The geometry's structure reading as the fusion takes it (None without one)."""
    if "structure" not in geo:
        return None
    return StructureHint(geo["structure"], geo["structure_conf"])


@dataclass
class Room:
    """One scan as one labeller labelled it: its offers, what is true of them, and what scoring
    a rule on it needs."""

    name: str
    dataset: str
    room: str  # scans of one room stay in one fold
    labeller: str
    gt: np.ndarray
    labels: np.ndarray
    offers: Offers
    truth: np.ndarray  # ground truth at each offer's point
    weight: np.ndarray  # per offer: inverse frequency of the true class, rooms weigh alike
    classes: ClassTally  # the network's output per class (the vote's thresholds)


def labeller_name(who: Labeller, spec: str) -> str:
    """How tables and the card name a labeller: its weights file, with its distortion."""
    base = network_name(spec)
    return f"{base}+{who.distortion}" if who.distortion else base


@dataclass(frozen=True)
class Sources:
    """Where a fit's outputs come from: loaded networks, and the cache folder (None: none)."""

    predictors: Predictors
    cache: Path | None = None


def load_room(item: TuningScan, who: Labeller, spec: str, sources: Sources, plan: VotePlan) -> Room:
    """Offers of one scan (segments of the default geometry), with their truth and weights:
    an offer weighs by the inverse frequency of its true class (mIoU counts every class alike),
    and only where it or the network's label is right (elsewhere neither choice helps)."""
    labels, probs = network_output(spec, item, sources.predictors, sources.cache)
    if who.distortion:
        probs = distort(probs, who.distortion, item.scan.xyz)
        labels = probs.argmax(axis=1)
    g = geometry_output(item, cache=sources.cache)
    seg = g["segments"].astype(np.int64)
    gt = item.scan.labels
    if gt is None:
        raise ConfigError(f"tuning scan {item.name}: no labels")
    offers = vote_offers(
        item.scan.xyz,
        seg,
        int(seg.max()) + 1,
        labels,
        probs,
        cell_size=plan.cell_size,
        main_plane=g["plane_id"] >= 0,
        min_support=min_support(plan),
        structure=structure_hint(g) if plan.fit.structure else None,
        has_colour=item.scan.rgb is not None,
    )
    truth = gt[offers.point]
    freq = np.bincount(gt[gt >= 0], minlength=13) / max(int((gt >= 0).sum()), 1)
    w = 1.0 / (freq[np.maximum(truth, 0)] + 0.02)
    useful = (truth == offers.label) | (truth == labels[offers.point])
    w = np.where(useful, w, 0.0)
    room = f"{item.dataset}/{item.room or item.name}"
    name = labeller_name(who, spec)
    return Room(
        item.name,
        item.dataset,
        room,
        name,
        gt,
        labels,
        offers,
        truth,
        w / max(w.sum(), 1e-12),
        ClassTally.of(labels, probs),
    )


def min_support(plan: VotePlan) -> float:
    """The plan's least support of an offer, else the fusion's default."""
    from jointseg.fusion.params import FusionParams

    return FusionParams().min_support if plan.min_support is None else plan.min_support


def tuning_scans(
    dataset: VoteDataset, base: Path, read: dict[Path, TuningScan]
) -> list[TuningScan]:
    """The scans of one dataset, made as it says; ``read`` keeps files read for another
    dataset (the same rooms thinned or without colour)."""
    out = []
    for path, shown in named_scan_files(dataset.scans, base):
        if path not in read:
            read[path] = read_labelled(path, dataset.name, shown)
        out.append(variant(read[path], dataset.variant, dataset.name))
    if dataset.synthetic is not None:
        s = dataset.synthetic
        rooms = synthetic_rooms(s.first_seed, s.rooms, s.floors, s.points, dataset.name)
        out += [variant(r, dataset.variant, dataset.name) for r in rooms]
    return out


@dataclass
class Loaded:
    """Every labelled scan of a plan as each of its labellers labelled it, and the records of
    what was read."""

    rooms: list[Room]
    scans: list[TuningScan]
    labellers: list[LabellerRecord]

    @property
    def scan_records(self) -> list[ScanRecord]:
        return [s.record for s in self.scans if s.record is not None]


def load_rooms(plan: VotePlan, base: Path, sources: Sources) -> Loaded:
    """Every tuning scan of every dataset, labelled by each of its dataset's labellers, in the
    plan's order (datasets, then scans, then labellers: the order the samples are fitted in)."""
    specs = {
        who.network: network_spec(who.network, base) for d in plan.datasets for who in d.labellers
    }
    records = {spec: labeller_record(spec) for spec in dict.fromkeys(specs.values())}
    read: dict[Path, TuningScan] = {}
    rooms, scans = [], []
    for dataset in plan.datasets:
        items = tuning_scans(dataset, base, read)
        scans += items
        for item in items:
            for who in dataset.labellers:
                t = time.perf_counter()
                rooms.append(load_room(item, who, specs[who.network], sources, plan))
                log.info("%s by %s: %.1f s", item.name, rooms[-1].labeller, time.perf_counter() - t)
    return Loaded(rooms, scans, list(records.values()))
