"""Network backends by name, where their weights come from, and one loader for all of them.

A backend's weights are, in this order: the path the caller gives (or the name of pulled
published weights, see :mod:`jointseg.network.published`), the path in the backend's environment
variable, the weights bundled with the package. DGCNN has no bundled weights (the published ones
are a separate download): ``jointseg models pull dgcnn-s3dis-5`` fetches the default ones.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from jointseg.exceptions import ConfigError
from jointseg.network import published
from jointseg.network.checkpoint import load_checkpoint
from jointseg.network.dgcnn_predict import (
    DGCNNParams,
    DGCNNPredictor,
    load_dgcnn_state,
)
from jointseg.network.predict import RandLANetPredictor

WEIGHTS_DIR = Path(__file__).parent / "weights"
BACKENDS = ("randlanet", "dgcnn")
DEFAULT_WEIGHTS = {"randlanet": WEIGHTS_DIR / "randlanet_s3dis_area6.pt"}
#: Published weights a backend without bundled ones uses once they are pulled.
DEFAULT_PULLED = {"dgcnn": published.DEFAULT_DGCNN}
WEIGHTS_ENV = {"randlanet": "JOINTSEG_RANDLANET_WEIGHTS", "dgcnn": "JOINTSEG_DGCNN_WEIGHTS"}
WHERE_TO_GET = {
    "randlanet": (
        "train them with `jointseg train --data synth --out model.pt`, or convert Open3D-ML's "
        "randlanet_s3dis_202201071330utc.pth with `jointseg models import open3d-ml FILE`"
    ),
    "dgcnn": (
        f"run `jointseg models pull {published.DEFAULT_DGCNN}` (or dgcnn-s3dis-1 ... -6: model N "
        f"leaves S3DIS Area N out), or pass a file with --weights or set {WEIGHTS_ENV['dgcnn']}"
    ),
}
#: Weight file suffixes that name their backend when a path is given instead of a name.
SUFFIX_BACKEND = {".pt": "randlanet", ".pth": "randlanet", ".t7": "dgcnn"}


#: A loaded network of any backend: ``predict(scan, progress, cancel, *, seed)`` gives a
#: :class:`~jointseg.network.predict.NetworkResult`.
Predictor = RandLANetPredictor | DGCNNPredictor


@dataclass(frozen=True)
class BackendInfo:
    """What `jointseg models list` shows for one backend.

    ``weights`` is None when the backend has none configured; ``source`` says where they come
    from ("bundled", "$VARIABLE" or "none"); ``where_to_get`` how to obtain them.
    """

    name: str
    weights: Path | None
    available: bool
    trained_on: str
    source: str
    where_to_get: str
    card: str = ""


def resolve_weights(name: str, weights: str | os.PathLike[str] | None = None) -> Path | None:
    """The weights file backend ``name`` would use: ``weights``, else its environment
    variable, else the bundled file; None when there is none of them."""
    if weights is not None:
        return _named_or_path(str(weights))
    env = os.environ.get(WEIGHTS_ENV.get(name, ""), "")
    if env:
        return _named_or_path(env)
    if name in DEFAULT_PULLED:
        return published.pulled_path(DEFAULT_PULLED[name])
    return DEFAULT_WEIGHTS.get(name)


def _named_or_path(weights: str) -> Path:
    """A weights path, or the cached file of published weights called so (a file of that name in
    the working folder wins); a published name not pulled yet says how to pull it."""
    path = Path(weights)
    if path.exists() or os.sep in weights or weights not in published.catalogue():
        return path
    pulled = published.pulled_path(weights)
    if pulled is None:
        raise ConfigError(
            f"weights {weights!r} are not pulled yet: run `jointseg models pull {weights}`"
        )
    return pulled


def card_summary(card: dict) -> str:
    """One line of a model card: epochs, validation score, hardware, command, terms."""
    parts = []
    if card.get("epochs"):
        parts.append(f"{card['epochs']} epochs")
    val = card.get("validation") or {}
    if val.get("best_miou") is not None:
        parts.append(
            f"validation mIoU {val['last_miou']:.3f} (best {val['best_miou']:.3f}, epoch "
            f"{val['best_epoch']})"
        )
    for key in ("hardware", "command", "terms"):
        if card.get(key):
            parts.append(f"{key}: {card[key]}")
    return "; ".join(parts)


def _card(name: str, path: Path) -> tuple[str, str]:
    """What the weights were trained on, and the rest of their card in one line."""
    try:
        if name == "dgcnn":
            return str(load_dgcnn_state(path)[1]["data"]), ""
        card = load_checkpoint(path)[1]
        return str(card.get("data", "-")), card_summary(card)
    except ConfigError as exc:
        return f"unreadable: {exc}", ""


def available_backends() -> list[BackendInfo]:
    """Every backend with the weights it would use and whether they are installed."""
    out = []
    for name in BACKENDS:
        path = resolve_weights(name)
        env = WEIGHTS_ENV[name]
        if os.environ.get(env):
            source = f"${env}"
        elif path is None:
            source = "none"
        else:
            source = "pulled" if name in DEFAULT_PULLED else "bundled"
        present = path is not None and path.is_file()
        trained_on, card = _card(name, path) if present and path is not None else ("-", "")
        out.append(BackendInfo(name, path, present, trained_on, source, WHERE_TO_GET[name], card))
    return out


def load(
    name: str = "randlanet",
    weights: str | os.PathLike[str] | None = None,
    *,
    device: str | None = None,
    batch_size: int = 4,
    dgcnn: DGCNNParams | None = None,
) -> Predictor:
    """A ready predictor for backend ``name`` with ``weights`` (default: see the module).

    ``name`` may also be a weights path, for ``load("model.pt")`` (RandLA-Net) or
    ``load("model_1.t7")`` (DGCNN). ``batch_size`` is crops (RandLA-Net) or 4 096-point blocks
    (DGCNN) per forward pass; ``dgcnn`` sets DGCNN's block and normalisation options.

    Raises
    ------
    ConfigError
        For an unknown backend or missing/unreadable weights; the message says where to get them.
    """
    if weights is None and name not in BACKENDS and Path(name).suffix in SUFFIX_BACKEND:
        name, weights = SUFFIX_BACKEND[Path(name).suffix], name
    if name not in BACKENDS:
        raise ConfigError(f"unknown network {name!r}; available: {', '.join(BACKENDS)}")
    path = resolve_weights(name, weights)
    if path is None:
        raise ConfigError(f"no weights for {name!r}: {WHERE_TO_GET[name]}")
    if not path.is_file():
        raise ConfigError(f"no weights for {name!r} at {path}: {WHERE_TO_GET[name]}")
    if name == "dgcnn":
        net, card = load_dgcnn_state(path)
        return DGCNNPredictor(net, card, device=device, batch_size=batch_size, params=dgcnn)
    model, card, _ = load_checkpoint(path)
    return RandLANetPredictor(model, card, device=device, batch_size=batch_size)
