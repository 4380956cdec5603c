"""Parameters of the label fusion (§2.3), validated once at the edge.

``mode="paper"`` is eq. 6-7 of the paper and nothing else. The other modes add what the paper
lacks: votes weighted by the network's class probabilities (``soft``) and a guard that leaves
impure segments alone, because a majority vote over a segment that mixes classes overwrites the
network's correct minority labels (the paper's own Table 1 loses board and clutter IoU so).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, PositiveInt

FusionMode = Literal["paper", "guarded", "soft", "soft_guarded", "evidence", "learned"]

#: Modes that vote with summed class probabilities instead of hard labels.
SOFT_MODES: frozenset[str] = frozenset({"soft", "soft_guarded"})
#: Modes that apply the impure-segment guard.
GUARDED_MODES: frozenset[str] = frozenset({"guarded", "soft_guarded"})

#: The default: the variant of bench/fusion_real.py that gains most on the tuning rooms of real
#: S3DIS Area_6 with DGCNN and on synthetic calibration rooms with the bundled network while
#: losing on none; docs/benchmarks/fusion.md has the tables (tuning and judging rooms apart).
#: Majority modes ('paper', 'soft') overwrite a strong network's correct labels inside impure
#: real segments.
DEFAULT_MODE: FusionMode = "learned"


class FusionParams(BaseModel):
    """How network labels and geometric segments are combined.

    Shares are fractions of a segment's votes (points, or probability mass in the soft modes).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    mode: FusionMode = Field(
        DEFAULT_MODE,
        description="'paper': eq. 6-7 with hard labels; 'soft': votes are summed class "
        "probabilities (one-hot when the network gave none); 'guarded' / 'soft_guarded': the "
        "same with the impure-segment guard; 'evidence': a point follows its unit only where "
        "the unit's evidence outweighs the network's confidence at the point; 'learned' "
        "(default): a point takes the label its segment or cell offers where the shipped vote "
        "model (jointseg/fusion/vote_model.json) finds the change more likely right than wrong.",
    )
    ratio_threshold: float = Field(
        0.5,
        ge=0,
        le=1,
        description="K of eq. 7: a label holding less than this share of its segment's votes "
        "is replaced by the segment's majority label L_max; 1 replaces every minority label.",
    )
    neighbours: PositiveInt = Field(
        1,
        description="K of the nearest-neighbour query that carries network labels to the "
        "segmented points when the network labelled a different point set (majority of K).",
    )
    guard_min_margin: float = Field(
        0.2,
        ge=0,
        le=1,
        description="Guarded modes: a segment (or cell) whose two largest vote shares differ "
        "by less has no clear winner; such a segment is split into cells, such a cell keeps the "
        "network labels.",
    )
    guard_huge_fraction: float = Field(
        0.05,
        gt=0,
        le=1,
        description="Guarded modes: a segment holding more than this share of the scan's "
        "points is huge ...",
    )
    guard_huge_min_share: float = Field(
        0.8,
        ge=0,
        le=1,
        description="... and, when its majority share is below this, mixed: it is split into "
        "cubic cells of guard_cell_size and each cell votes on its own.",
    )
    guard_cell_size: float = Field(
        0.5,
        ge=0,
        description="Cell side (m) for splitting impure segments; 0 keeps their network "
        "labels instead.",
    )
    evidence_weight: float = Field(
        0.4,
        ge=0,
        description="'evidence': w in log p_i(c) + w log q_U(c); how much the voting unit's "
        "mean probabilities count against the point's own (0 keeps the network's labels).",
    )
    vote_cell_size: float = Field(
        0.3,
        ge=0,
        description="'evidence': voting units are segments cut into cubic cells of this side "
        "(m), so a vote stays local inside a large plane; 0 votes over whole segments.",
    )
    flip_threshold: float = Field(
        0.55,
        ge=0,
        le=1,
        description="'learned': a point takes the label its segment or cell offers where the "
        "vote model's probability that the change is right exceeds this (higher: fewer, safer "
        "changes), between two classes alike in size and IoU; see metric_iou.",
    )
    metric_iou: Literal["auto"] | Annotated[float, Field(gt=0, le=1)] = Field(
        "auto",
        description="'learned': how the threshold follows the expected change of the mIoU. "
        "A point leaves a class the network gave few points of, or finds poorly, only on "
        "stronger evidence (one wrong move costs that class more than one right move gains "
        "the class it joins) and joins one on weaker. 'auto' (default): every class's "
        "size and IoU as the network's own probabilities expect them; a number in (0, 1]: "
        "that IoU for every class and the network's counts as sizes; 1 keeps flip_threshold "
        "for every pair of classes (docs/guide/fusion.md).",
    )
    seen_fixture_share: float = Field(
        0.7,
        gt=0,
        le=1,
        description="'learned': a point the network labels a wall fixture of a believable size "
        "(window, door, board, column, beam) keeps its label against a wall that only the "
        "structure reading offers, where the network gives that fixture more than this share "
        "of the point's cell (it sees the fixture there; the reading cannot tell a fixture in "
        "a wall's plane from the wall); 1 disables.",
    )
    min_support: float = Field(
        0.03,
        ge=0,
        le=1,
        description="Every mode but 'paper', when the network gave probabilities: a point is "
        "relabelled only to a class the network gave that point at least this probability "
        "(a class it ruled out for the point stays ruled out); 0 disables.",
    )
