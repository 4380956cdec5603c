"""Test-time views of a crop: the same points turned about the up axis and mirrored.

The network's labels depend a little on how a crop is turned (it learned from rooms of a few
orientations); averaging its probabilities over several turns and mirrors of each crop evens
that out. A view changes only the crop's coordinates: the neighbours, the crop plan and the
per-cell sums stay those of the one view, so tiled runs keep adding up to untiled ones.
"""

from __future__ import annotations

import math

import torch


def view_matrix(view: int, views: int) -> torch.Tensor | None:
    """The 2x2 map of the crop's horizontal coordinates for view ``view`` of ``views``: a
    turn by ``view / views`` of a circle, mirrored in x for odd views; None for view 0."""
    if view == 0:
        return None
    angle = 2.0 * math.pi * view / views
    c, s = math.cos(angle), math.sin(angle)
    turn = torch.tensor([[c, -s], [s, c]], dtype=torch.float32)
    if view % 2 == 1:
        turn = turn @ torch.diag(torch.tensor([-1.0, 1.0]))
    return turn


def in_view(
    features: torch.Tensor, coords: list[torch.Tensor], view: int, views: int
) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """A batch's features (B, N, 3 + C) and per-layer coordinates (B, N_i, 3), crop-centred in
    x and y, seen in view ``view``."""
    matrix = view_matrix(view, views)
    if matrix is None:
        return features, coords
    matrix = matrix.to(features.device)

    def turn(xyz: torch.Tensor) -> torch.Tensor:
        return torch.cat([xyz[..., :2] @ matrix.T, xyz[..., 2:]], dim=-1)

    return turn(features), [turn(c) for c in coords]
