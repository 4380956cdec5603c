"""Network backends by name, and the weights that ship with the package."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from jointseg.exceptions import ConfigError
from jointseg.network.checkpoint import load_checkpoint
from jointseg.network.predict import RandLANetPredictor

WEIGHTS_DIR = Path(__file__).parent / "weights"
DEFAULT_WEIGHTS = {"randlanet": WEIGHTS_DIR / "randlanet_synth.pt"}
WHERE_TO_GET = {
    "randlanet": (
        "train them with `jointseg train --data synth --out model.pt`, or convert Open3D-ML's "
        "randlanet_s3dis_202201071330utc.pth with `jointseg models import open3d-ml FILE`"
    ),
}


@dataclass(frozen=True)
class BackendInfo:
    """What `jointseg models list` shows for one backend."""

    name: str
    weights: Path
    available: bool
    trained_on: str


def available_backends() -> list[BackendInfo]:
    """Every backend with its default weights and whether they are installed."""
    out = []
    for name, path in DEFAULT_WEIGHTS.items():
        trained_on = "-"
        if path.is_file():
            try:
                trained_on = str(load_checkpoint(path)[1].get("data", "-"))
            except ConfigError as exc:
                trained_on = f"unreadable: {exc}"
        out.append(BackendInfo(name, path, path.is_file(), trained_on))
    return out


def load(
    name: str = "randlanet",
    weights: str | os.PathLike[str] | None = None,
    *,
    device: str | None = None,
    batch_size: int = 4,
) -> RandLANetPredictor:
    """A ready predictor for backend ``name`` with ``weights`` (default: the bundled ones).

    ``name`` may also be a checkpoint path, for `load("model.pt")`.

    Raises
    ------
    ConfigError
        For an unknown backend or missing/unreadable weights; the message says where to get them.
    """
    if weights is None and name not in DEFAULT_WEIGHTS and Path(name).suffix in {".pt", ".pth"}:
        name, weights = "randlanet", name
    if name not in DEFAULT_WEIGHTS:
        raise ConfigError(
            f"unknown network {name!r}; available: {', '.join(sorted(DEFAULT_WEIGHTS))}"
        )
    path = Path(weights) if weights is not None else DEFAULT_WEIGHTS[name]
    if not path.is_file():
        raise ConfigError(f"no weights for {name!r} at {path}: {WHERE_TO_GET[name]}")
    model, card, _ = load_checkpoint(path)
    return RandLANetPredictor(model, card, device=device, batch_size=batch_size)
