"""Named fusion variants that the benchmarks (``bench/fusion.py``, ``bench/fusion_real.py``) and
``bench/same_outputs.py`` compare."""

from __future__ import annotations

from jointseg.fusion.params import FusionParams

VARIANTS: dict[str, FusionParams] = {
    "paper": FusionParams(mode="paper", ratio_threshold=0.5),
    "soft": FusionParams(mode="soft"),
    "guarded": FusionParams(mode="guarded"),
    "soft_guarded": FusionParams(mode="soft_guarded"),
    "evidence w=0.25": FusionParams(mode="evidence", evidence_weight=0.25),
    "evidence": FusionParams(mode="evidence"),
    "evidence w=0.5": FusionParams(mode="evidence", evidence_weight=0.5),
    "evidence w=0.75": FusionParams(mode="evidence", evidence_weight=0.75),
    "evidence w=1": FusionParams(mode="evidence", evidence_weight=1.0),
    "evidence 0.5 m": FusionParams(mode="evidence", vote_cell_size=0.5),
    "evidence segments": FusionParams(mode="evidence", vote_cell_size=0.0),
    "learned": FusionParams(mode="learned"),
    "learned t=0.6": FusionParams(mode="learned", flip_threshold=0.6),
    "learned t=0.7": FusionParams(mode="learned", flip_threshold=0.7),
}
#: The variant tables single out: the library's default.
DEFAULT_VARIANT = "learned"
