"""Checkpoints that carry a model card: what the weights are, what they were trained on, and
the input conventions a caller must honour."""

from __future__ import annotations

import gzip
import io
import os
from pathlib import Path
from typing import Any

import torch
from pydantic import ValidationError

from jointseg.exceptions import ConfigError, library_reason
from jointseg.io.atomic import atomic_open
from jointseg.network.randlanet.model import RandLANet, RandLANetConfig

FORMAT = "jointseg-randlanet/1"
INPUT_CONVENTIONS = (
    "features = [x - crop mean x, y - crop mean y, z - scan min z, r/255, g/255, b/255] on a "
    "0.04 m grid average; z up, metres; S3DIS class order"
)


def save_checkpoint(
    path: Path,
    model: RandLANet,
    card: dict[str, Any],
    *,
    extra: dict[str, Any] | None = None,
    half: bool = False,
    compress: bool = False,
) -> None:
    """Write model weights, config and card atomically (``half`` stores float16 weights,
    ``compress`` gzips the file: about 9 % smaller, read back transparently)."""
    state = {
        k: (v.half() if half and v.is_floating_point() else v).cpu()
        for k, v in model.state_dict().items()
    }
    body = {
        "format": FORMAT,
        "config": model.config.model_dump(),
        "state_dict": state,
        "card": {**card, "input_conventions": INPUT_CONVENTIONS},
        **(extra or {}),
    }
    buffer = io.BytesIO()
    torch.save(body, buffer)
    data = buffer.getvalue()
    if compress:
        data = gzip.compress(data, compresslevel=9, mtime=0)
    with atomic_open(Path(path)) as fh:
        fh.write(data)


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
        with path.open("rb") as fh:
            gzipped = fh.read(2) == b"\x1f\x8b"
        if gzipped:
            with gzip.open(path, "rb") as fh:
                return torch.load(io.BytesIO(fh.read()), map_location="cpu", weights_only=True)
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a bad file
        raise ConfigError(
            f"{path}: not a readable PyTorch checkpoint ({_torch_reason(exc, path)})"
        ) from exc


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


def _config_problem(exc: ValidationError) -> str:
    """The first problem of an invalid stored configuration, as ``field: message``."""
    errors = exc.errors()
    first = errors[0]
    where = ".".join(str(part) for part in first.get("loc", ())) or "config"
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    return f"{where}: {first.get('msg', 'invalid')}{more}"


def load_checkpoint(path: str | os.PathLike[str]) -> tuple[RandLANet, dict[str, Any], dict]:
    """Load a checkpoint written by :func:`save_checkpoint`.

    Returns
    -------
    (model in eval mode, card, the whole checkpoint dict)

    Raises
    ------
    ConfigError
        When the file is missing, not a torch file, or not a jointseg RandLA-Net checkpoint.
    """
    path = Path(path)
    body = read_torch_file(path)
    if not isinstance(body, dict) or body.get("format") != FORMAT:
        raise ConfigError(
            f"{path}: not a jointseg RandLA-Net checkpoint (format {FORMAT!r}); convert "
            "Open3D-ML checkpoints with `jointseg models import open3d-ml FILE`"
        )
    config, state = body.get("config"), body.get("state_dict")
    if not isinstance(config, dict) or not isinstance(state, dict):
        raise ConfigError(f"{path}: the checkpoint lacks its 'config' or 'state_dict' mapping")
    try:
        model = RandLANet(RandLANetConfig(**config))
    except ValidationError as exc:
        raise ConfigError(
            f"{path}: the checkpoint's stored configuration is invalid: {_config_problem(exc)}"
        ) from exc
    except TypeError as exc:  # keys that are not strings
        raise ConfigError(f"{path}: the checkpoint's stored configuration is invalid") from exc
    problem = state_mismatch(model, state)
    if problem is not None:
        raise ConfigError(f"{path}: weights do not fit the stored configuration: {problem}")
    state = {k: v.float() if v.is_floating_point() else v for k, v in state.items()}
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        raise ConfigError(
            f"{path}: weights do not fit the stored configuration "
            f"({library_reason(exc, 'they do not load')})"
        ) from exc
    model.eval()
    return model, body.get("card", {}), body
