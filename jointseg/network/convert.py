"""Import RandLA-Net weights trained by Open3D-ML (``open3d.ml.torch.models.RandLANet``).

Open3D-ML's RandLA-Net and ours have the same architecture and parameter count; only the module
names differ, and three details need care:

* Open3D-ML's decoder uses 1x1 ``ConvTranspose2d`` layers, whose weight is stored as
  (in, out, 1, 1); ours are ``Conv2d`` with (out, in, 1, 1), so those weights are transposed.
* Open3D-ML feeds colour in 0-255, we feed it in 0-1: the colour columns of the first linear
  layer are multiplied by 255, so the converted model gives Open3D-ML's outputs on our inputs.
* Sub-sampling ratios, neighbour count and grid size are not stored in the weights. Only the
  S3DIS configuration (``randlanet_s3dis.yml``: xyz + rgb input, 5 layers, ratios 4, 4, 4, 4, 2,
  16 neighbours, 0.04 m grid) is accepted, which is the one :class:`RandLANetConfig` defaults to.
"""

from __future__ import annotations

import logging
import pickle
import re
import zipfile
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.exceptions import ConfigError
from jointseg.network.digest import file_sha256
from jointseg.network.randlanet.checkpoint import FORMAT, save_checkpoint
from jointseg.network.randlanet.model import RandLANet, RandLANetConfig

log = logging.getLogger(__name__)

#: The Open3D-ML model zoo file this importer was written for.
ZOO_FILE = "randlanet_s3dis_202201071330utc.pth"
ZOO_URL = "https://storage.googleapis.com/open3d-releases/model-zoo/" + ZOO_FILE
ZOO_MIOU = (
    "70.9 mIoU on S3DIS, as published in Open3D-ML's model zoo (model_zoo.md); the zoo does "
    "not name the evaluation split (Open3D-ML's randlanet_s3dis.yml holds out Area 3), so it "
    "is not comparable with Area 5 results"
)

#: Our state-dict key -> Open3D-ML's, applied in order (``re.sub`` on our key).
_OURS_TO_OPEN3D_ML: tuple[tuple[str, str], ...] = (
    (r"^stem\.", "fc0."),
    (r"^stem_bn\.", "bn0."),
    (r"^bottleneck\.", "mlp."),
    (r"^head\.", "fc1."),
    (r"^(encoder\.\d+)\.mlp_in\.", r"\1.mlp1."),
    (r"^(encoder\.\d+)\.encode1\.", r"\1.lse1.mlp."),
    (r"^(encoder\.\d+)\.encode2\.", r"\1.lse2.mlp."),
    (r"^(encoder\.\d+\.pool\d)\.score\.", r"\1.score_fn.0."),
    (r"^(encoder\.\d+)\.mlp_out\.", r"\1.mlp2."),
    (r"\.bn\.", ".batch_norm."),
)
_TRANSPOSED = re.compile(r"^decoder\.\d+\.conv\.weight$")
_COLOUR = slice(3, 6)


def open3d_ml_name(key: str) -> str:
    """Open3D-ML's name for one of our RandLA-Net state-dict keys.

    Parameters
    ----------
    key : str
        A key of ``RandLANet().state_dict()``, e.g. ``"encoder.0.encode1.bn.weight"``.

    Returns
    -------
    str
        The matching key of Open3D-ML's ``RandLANet``, e.g.
        ``"encoder.0.lse1.mlp.batch_norm.weight"``.
    """
    for pattern, replacement in _OURS_TO_OPEN3D_ML:
        key = re.sub(pattern, replacement, key)
    return key


def open3d_ml_config(state: Mapping[str, torch.Tensor]) -> RandLANetConfig:
    """The :class:`RandLANetConfig` matching an Open3D-ML RandLA-Net state dict.

    The number of classes is read from the last layer; everything else must be the S3DIS
    architecture, because the sub-sampling ratios and neighbour count are not in the weights.

    Parameters
    ----------
    state : mapping of str to Tensor
        Open3D-ML's ``model_state_dict`` (without a ``module.`` prefix).

    Returns
    -------
    RandLANetConfig
        S3DIS defaults with ``num_classes`` from the checkpoint.

    Raises
    ------
    ConfigError
        When a key needed to read the architecture is missing, or the architecture is not the
        S3DIS one (other input channels, number of layers or widths).
    """
    fc0 = _tensor(state, "fc0.weight")
    if fc0.ndim != 2:
        raise ConfigError(f"'fc0.weight' has shape {tuple(fc0.shape)}, expected (8, 6)")
    d_stem, in_channels = (int(n) for n in fc0.shape)
    layers = sorted({int(m[1]) for k in state if (m := re.match(r"encoder\.(\d+)\.", k))})
    d_out = tuple(
        int(_tensor(state, f"encoder.{i}.mlp2.conv.weight").shape[0]) // 2 for i in layers
    )
    heads = sorted(int(m[1]) for k in state if (m := re.fullmatch(r"fc1\.(\d+)\.conv\.weight", k)))
    if not heads:
        raise ConfigError("missing key 'fc1.3.conv.weight' (the classifier)")
    num_classes = int(_tensor(state, f"fc1.{heads[-1]}.conv.weight").shape[0])

    s3dis = RandLANetConfig()
    problems = []
    if in_channels != s3dis.in_channels:
        problems.append(
            f"{in_channels} input channels (jointseg feeds {s3dis.in_channels}: xyz + rgb)"
        )
    if len(layers) != len(s3dis.d_out):
        problems.append(f"{len(layers)} encoder layers (S3DIS: {len(s3dis.d_out)})")
    elif d_out != s3dis.d_out or d_stem != s3dis.d_stem:
        problems.append(
            f"widths {d_stem}/{list(d_out)} (S3DIS: {s3dis.d_stem}/{list(s3dis.d_out)})"
        )
    if problems:
        raise ConfigError(
            f"not Open3D-ML's S3DIS RandLA-Net: the checkpoint has {'; '.join(problems)}; "
            f"{num_classes} classes. Only the randlanet_s3dis.yml architecture can be imported "
            "(sub-sampling ratios and neighbour count are not stored in the weights), e.g. "
            f"{ZOO_FILE}"
        )
    if num_classes < 2:
        raise ConfigError(f"the classifier 'fc1.{heads[-1]}' has {num_classes} output(s)")
    return RandLANetConfig(num_classes=num_classes)


def convert_open3d_ml_state(state: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Convert an Open3D-ML RandLA-Net state dict into one for :class:`RandLANet`.

    Renames every key, transposes the decoder's ``ConvTranspose2d`` weights and multiplies the
    colour columns of the first layer by 255 (Open3D-ML sees colour in 0-255, we feed 0-1), so
    the result gives Open3D-ML's logits on jointseg's inputs.

    Parameters
    ----------
    state : mapping of str to Tensor
        Open3D-ML's ``model_state_dict``; a ``module.`` prefix (DataParallel) is removed.

    Returns
    -------
    dict of str to Tensor
        Float32 copies, loadable with ``load_state_dict(strict=True)`` into
        ``RandLANet(open3d_ml_config(state))``.

    Raises
    ------
    ConfigError
        Naming the missing or unexpected keys, or a tensor whose shape does not fit, or when the
        architecture is not the S3DIS one (see :func:`open3d_ml_config`).
    """
    state = _strip_module(state)
    config = open3d_ml_config(state)
    with torch.device("meta"):
        expected = RandLANet(config).state_dict()
    names = {ours: open3d_ml_name(ours) for ours in expected}

    missing = [theirs for ours, theirs in names.items() if theirs not in state]
    # Checkpoints written before PyTorch 0.4.1 have no BatchNorm step counters.
    missing_counters = [k for k in missing if k.endswith(".num_batches_tracked")]
    missing = [k for k in missing if not k.endswith(".num_batches_tracked")]
    unexpected = sorted(set(state) - set(names.values()))
    if missing or unexpected:
        parts = []
        if missing:
            parts.append(f"missing keys: {_listing(missing)}")
        if unexpected:
            parts.append(f"unexpected keys: {_listing(unexpected)}")
        raise ConfigError("not an Open3D-ML RandLA-Net state dict; " + "; ".join(parts))

    out: dict[str, torch.Tensor] = {}
    for ours, theirs in names.items():
        if theirs in missing_counters:
            out[ours] = torch.zeros((), dtype=torch.long)
            continue
        value = _tensor(state, theirs).detach().to("cpu")
        if _TRANSPOSED.match(ours) and value.ndim == 4:
            value = value.transpose(0, 1)
        if tuple(value.shape) != tuple(expected[ours].shape):
            raise ConfigError(
                f"shape mismatch for {theirs!r}: the checkpoint has {tuple(value.shape)}, a "
                f"{config.num_classes}-class S3DIS RandLA-Net needs "
                f"{tuple(_open3d_ml_shape(ours, expected[ours]))}"
            )
        out[ours] = value.float().contiguous() if value.is_floating_point() else value.clone()
    out["stem.weight"] = out["stem.weight"].clone()
    out["stem.weight"][:, _COLOUR] *= 255.0
    log.debug("converted %d Open3D-ML tensors (%d classes)", len(out), config.num_classes)
    return out


def import_open3d_ml(src: Path, dst: Path, *, allow_pickle: bool = False) -> Path:
    """Convert an Open3D-ML RandLA-Net checkpoint file into a jointseg checkpoint.

    Parameters
    ----------
    src : Path
        Open3D-ML's ``.pth`` file (e.g. the model zoo's ``randlanet_s3dis_202201071330utc.pth``):
        a dict holding ``model_state_dict`` (or ``state_dict``), or a bare state dict.
    dst : Path
        Where to write the jointseg checkpoint (parent folders are created).
    allow_pickle : bool
        The file is first read with ``torch.load(weights_only=True)``. If it holds Python
        objects beyond tensors and plain containers, it is read again with
        ``weights_only=False`` (which can run code stored in the file) when this is true, with
        a warning; when false a :class:`ConfigError` is raised instead.

    Returns
    -------
    Path
        ``dst``.

    Raises
    ------
    ConfigError
        When ``src`` is missing, not a PyTorch file, holds no RandLA-Net state dict, is not the
        S3DIS architecture or does not have the 13 S3DIS classes. The message names the file.
    """
    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise ConfigError(f"Open3D-ML checkpoint not found: {src}")
    if dst.resolve() == src.resolve():
        raise ConfigError(f"{src}: refusing to overwrite the Open3D-ML checkpoint with its import")
    digest = file_sha256(src)
    body = _load(src, digest, allow_pickle=allow_pickle)
    state = _state_dict(src, body)
    try:
        config = open3d_ml_config(_strip_module(state))
        converted = convert_open3d_ml_state(state)
    except ConfigError as exc:
        raise ConfigError(f"{src}: {exc}") from exc
    if config.num_classes != NUM_CLASSES:
        raise ConfigError(
            f"{src}: the checkpoint has {config.num_classes} classes; jointseg labels with the "
            f"{NUM_CLASSES} S3DIS classes ({', '.join(CLASS_NAMES)})"
        )
    model = RandLANet(config)
    try:
        model.load_state_dict(converted, strict=True)
    except RuntimeError as exc:  # pragma: no cover - convert_open3d_ml_state checks keys/shapes
        raise ConfigError(f"{src}: converted weights do not load ({exc})") from exc
    model.eval()

    is_zoo = src.name == ZOO_FILE
    card = _open3d_ml_card(src, digest, is_zoo)
    if not is_zoo:
        log.warning(
            "%s is not Open3D-ML's model zoo file %s: assuming S3DIS class order; the model "
            "card records no published score",
            src.name,
            ZOO_FILE,
        )
    if isinstance(body, Mapping) and isinstance(body.get("epoch"), int):
        card["source_epoch"] = body["epoch"]
    dst.parent.mkdir(parents=True, exist_ok=True)
    save_checkpoint(dst, model, card)
    log.info("imported %s (sha256 %s) -> %s", src.name, digest, dst)
    return dst


def _open3d_ml_card(src: Path, digest: str, is_zoo: bool) -> dict[str, Any]:
    """Model card of an imported checkpoint; only the zoo file gets a source URL and score."""
    card: dict[str, Any] = {
        "architecture": "RandLA-Net (Hu et al. 2020), S3DIS configuration",
        "classes": list(CLASS_NAMES),
        "data": "S3DIS (trained by Open3D-ML)" if is_zoo else "S3DIS? (trained with Open3D-ML)",
        "source": f"converted from Open3D-ML checkpoint {src.name}",
        "source_sha256": digest,
        "source_url": ZOO_URL if is_zoo else None,
        "published_miou": ZOO_MIOU if is_zoo else None,
        "conversion": (
            "module names mapped; decoder ConvTranspose2d 1x1 weights transposed to Conv2d; "
            "first-layer colour weights x255 so colour in [0, 1] reproduces Open3D-ML's "
            "outputs for colour in [0, 255]"
        ),
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    return {k: v for k, v in card.items() if v is not None}


def _load(src: Path, digest: str, *, allow_pickle: bool) -> Any:
    # torch files are zip archives (or, before torch 1.6, pickles starting with 0x80)
    with open(src, "rb") as fh:
        head = fh.read(4)
    if not (zipfile.is_zipfile(src) or head[:1] == b"\x80"):
        raise ConfigError(f"{src}: not a readable PyTorch checkpoint (neither a zip nor a pickle)")
    try:
        return torch.load(src, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        if "weights only load failed" not in str(exc).lower():
            raise ConfigError(f"{src}: not a readable PyTorch checkpoint ({exc})") from exc
        if not allow_pickle:
            raise ConfigError(
                f"{src}: holds Python objects besides weights, and loading those could run code "
                "stored in the file; re-run allowing it only if you trust the file's source"
            ) from exc
        log.warning(
            "%s holds Python objects besides weights; loading it with weights_only=False, "
            "which can run code stored in the file (sha256 %s): only do this for files from a "
            "source you trust",
            src,
            digest,
        )
    except Exception as exc:  # torch raises many types for a file that is not a checkpoint
        raise ConfigError(f"{src}: not a readable PyTorch checkpoint ({exc})") from exc
    try:
        return torch.load(src, map_location="cpu", weights_only=False)
    except Exception as exc:
        raise ConfigError(f"{src}: not a readable PyTorch checkpoint ({exc})") from exc


def _state_dict(src: Path, body: Any) -> Mapping[str, torch.Tensor]:
    if not isinstance(body, Mapping):
        raise ConfigError(f"{src}: holds a {type(body).__name__}, not a state dict")
    if body.get("format") == FORMAT:
        raise ConfigError(f"{src}: already a jointseg checkpoint; nothing to import")
    for key in ("model_state_dict", "state_dict"):
        if key in body:
            state = body[key]
            break
    else:
        state = body
    if not isinstance(state, Mapping) or not state:
        raise ConfigError(f"{src}: no model state dict ('model_state_dict' or 'state_dict')")
    bad = [k for k, v in state.items() if not isinstance(k, str) or not torch.is_tensor(v)]
    if bad:
        raise ConfigError(
            f"{src}: holds no RandLA-Net state dict (keys {_listing([str(k) for k in bad])} are "
            "not tensors); expected 'model_state_dict' as saved by Open3D-ML"
        )
    return state


def _strip_module(state: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return {k.removeprefix("module."): v for k, v in state.items()}


def _tensor(state: Mapping[str, Any], key: str) -> torch.Tensor:
    if key not in state:
        raise ConfigError(f"missing key {key!r}")
    value = state[key]
    if not torch.is_tensor(value):
        raise ConfigError(f"{key!r} is a {type(value).__name__}, not a tensor")
    return value


def _open3d_ml_shape(ours: str, tensor: torch.Tensor) -> tuple[int, ...]:
    shape = tuple(int(n) for n in tensor.shape)
    if _TRANSPOSED.match(ours) and len(shape) == 4:
        return (shape[1], shape[0], *shape[2:])
    return shape


def _listing(keys: list[str], limit: int = 8) -> str:
    shown = ", ".join(repr(k) for k in keys[:limit])
    return shown + (f" and {len(keys) - limit} more" if len(keys) > limit else "")


def to_open3d_ml_state(state: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The inverse of :func:`convert_open3d_ml_state`: our weights in Open3D-ML's layout.

    Used to run the very same network inside Open3D-ML (benchmarks, cross-checks).

    Parameters
    ----------
    state : mapping of str to Tensor
        ``RandLANet().state_dict()``.

    Returns
    -------
    dict of str to Tensor
        Loadable by ``open3d.ml.torch.models.RandLANet`` with the S3DIS configuration.
    """
    out: dict[str, torch.Tensor] = {}
    for key, value in state.items():
        tensor = value.detach().clone().float() if value.is_floating_point() else value.clone()
        if _TRANSPOSED.match(key):
            tensor = tensor.transpose(0, 1).contiguous()
        if key == "stem.weight":
            tensor[:, _COLOUR] /= 255.0
        out[open3d_ml_name(key)] = tensor
    return out
