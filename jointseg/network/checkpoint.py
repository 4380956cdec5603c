"""Where RandLA-Net's checkpoints were read and written before issue 69, kept for the callers
that still import them from here (:mod:`jointseg.adapt.learn`, code outside the project).

The checkpoint format is RandLA-Net's and lives in its folder,
:mod:`jointseg.network.randlanet.checkpoint`; reading a PyTorch file of any backend is
:mod:`jointseg.network.torch_files`. New code imports from those.
"""

from __future__ import annotations

from jointseg.network.randlanet.checkpoint import (
    FORMAT,
    INPUT_CONVENTIONS,
    load_checkpoint,
    save_checkpoint,
)
from jointseg.network.torch_files import read_torch_file, state_mismatch

__all__ = [
    "FORMAT",
    "INPUT_CONVENTIONS",
    "load_checkpoint",
    "read_torch_file",
    "save_checkpoint",
    "state_mismatch",
]
