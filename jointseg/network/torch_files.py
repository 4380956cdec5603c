"""PyTorch files of any backend: read without running code stored in them, with errors that
name the file in one line, and a state that does not fit its network said in one line.

Why apart from the backends: every backend reads its weights this way (RandLA-Net's checkpoints in
:mod:`jointseg.network.randlanet.checkpoint`, DGCNN's published files), so it sits below them.
"""

from __future__ import annotations

import gzip
import io
import os
from pathlib import Path
from typing import Any

import torch

from jointseg.exceptions import ConfigError, library_reason


def read_torch_file(path: str | os.PathLike[str], *, hint: str = "") -> Any:
    """Tensors (and plain containers) from a PyTorch file; never runs code stored in it.

    Raises
    ------
    ConfigError
        When the file is missing or not a readable PyTorch file; ``hint`` is appended to the
        missing-file message (e.g. where to get the weights).
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"weights file not found: {path}{hint}")
    try:
        if gzipped(path):
            with gzip.open(path, "rb") as fh:
                return torch.load(io.BytesIO(fh.read()), map_location="cpu", weights_only=True)
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a bad file
        raise ConfigError(
            f"{path}: not a readable PyTorch checkpoint ({_torch_reason(exc, path)})"
        ) from exc


def gzipped(path: Path) -> bool:
    """Whether ``path`` starts like a gzip stream."""
    with path.open("rb") as fh:
        return fh.read(2) == b"\x1f\x8b"


def _torch_reason(exc: BaseException, path: Path) -> str:
    """Why torch could not read ``path``, in one short clause.

    torch's own messages run over many lines (the ``weights_only`` advice, C++ ``enforce fail``
    locations) and the unpickler's names the first byte it refused, which says what the file
    holds; none of that is passed on.
    """
    try:
        if path.stat().st_size == 0:
            return "the file is empty"
    except OSError:
        pass
    if "Weights only load failed" in str(exc):
        return (
            "not a PyTorch file, or it holds Python objects besides tensors (only tensors are read)"
        )
    return library_reason(exc, "not a PyTorch file, or a truncated one")


#: Tensor names listed at most in a mismatch message.
LISTED_KEYS = 3


def _names(keys: list[str]) -> str:
    """``a, b, c and 4 more``."""
    shown = ", ".join(keys[:LISTED_KEYS])
    return shown + (f" and {len(keys) - LISTED_KEYS} more" if len(keys) > LISTED_KEYS else "")


def state_mismatch(model: torch.nn.Module, state: dict[str, Any]) -> str | None:
    """How ``state`` fails to fit ``model``, in one line (None when it fits).

    Why not torch's message: it lists every missing key, tab-indented, over many lines.
    """
    expected = model.state_dict()
    missing = [k for k in expected if k not in state]
    unexpected = [k for k in state if k not in expected]
    shapes = [
        f"{k} {tuple(state[k].shape)} for {tuple(v.shape)}"
        for k, v in expected.items()
        if k in state and isinstance(state[k], torch.Tensor) and state[k].shape != v.shape
    ]
    others = [k for k in expected if k in state and not isinstance(state[k], torch.Tensor)]
    problems = []
    if missing:
        problems.append(f"{len(missing)} tensors missing ({_names(missing)})")
    if unexpected:
        problems.append(f"{len(unexpected)} unexpected ({_names(unexpected)})")
    if shapes:
        problems.append(f"{len(shapes)} of another shape ({_names(shapes)})")
    if others:
        problems.append(f"{len(others)} not tensors ({_names(others)})")
    return "; ".join(problems) or None
