"""Parameters of the label fusion (§2.3), validated once at the edge.

``mode="paper"`` is eq. 6-7 of the paper and nothing else. The other modes add what the paper
lacks: votes weighted by the network's class probabilities (``soft``) and a guard that leaves
impure segments alone, because a majority vote over a segment that mixes classes overwrites the
network's correct minority labels (the paper's own Table 1 loses board and clutter IoU so).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, PositiveInt

FusionMode = Literal["paper", "guarded", "soft", "soft_guarded"]

#: Modes that vote with summed class probabilities instead of hard labels.
SOFT_MODES: frozenset[str] = frozenset({"soft", "soft_guarded"})
#: Modes that apply the impure-segment guard.
GUARDED_MODES: frozenset[str] = frozenset({"guarded", "soft_guarded"})

#: The default: the best mode of bench/fusion.py with the bundled weights on 10 held-out rooms
#: and 2 floors (largest mean gain over the network among the variants that lose on no scan;
#: the README has the table). The paper's rule at ratio 0.5 gains about as much on average but
#: loses slightly on one room; soft votes with the min_support check lose on none.
DEFAULT_MODE: FusionMode = "soft"


class FusionParams(BaseModel):
    """How network labels and geometric segments are combined.

    Shares are fractions of a segment's votes (points, or probability mass in the soft modes).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    mode: FusionMode = Field(
        DEFAULT_MODE,
        description="'paper': eq. 6-7 with hard labels; 'soft': votes are summed class "
        "probabilities (one-hot when the network gave none); 'guarded' / 'soft_guarded': the "
        "same with the impure-segment guard.",
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
    min_support: float = Field(
        0.03,
        ge=0,
        le=1,
        description="Every mode but 'paper', when the network gave probabilities: a point is "
        "relabelled only to a class the network gave that point at least this probability "
        "(a class it ruled out for the point stays ruled out); 0 disables.",
    )
