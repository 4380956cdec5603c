"""What labels points for a caller that must not import the network: the signature both sides
see.

Why here, under both: the frame stage asks a network for its verdict on candidate frames
(:mod:`jointseg.frame.judge`) but never imports the network, and the network makes such a
labeller from a loaded predictor (:mod:`jointseg.network.judge`); frame and network are on the
same floor and import neither the other (docs/ARCHITECTURE.md), so the type they share sits
below both.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: ``label(xyz, rgb) -> (xyz_judged, probs)``: class probabilities (M, 13) of M of the points
#: given (in a z-up metric frame), with their coordinates.
LabelFn = Callable[[np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray]]
