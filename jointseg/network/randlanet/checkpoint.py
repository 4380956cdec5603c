"""RandLA-Net's checkpoints, which carry a model card: what the weights are, what they were
trained on, and the input conventions a caller must honour.

Packed weights (gzip-compressed or float16, as bundled and as ``jointseg models pack`` writes
them) are unpacked once into the user's cache (``$JOINTSEG_CACHE/unpacked``, default
``~/.cache/jointseg/unpacked``) and read from there by later processes: the packed bundled
network (gunzip, unpickle 330 tensors, float16 to float32, copy into a model initialised at
random first) took about 0.6 s of CPU, the copy (two flat tensors, memory-mapped, copied out)
under 0.1 s. The copy holds the float32 tensors the packed file loads as, so the model is the
same bit for bit.
"""

from __future__ import annotations

import gzip
import hashlib
import io
import logging
import os
from pathlib import Path
from typing import Any

import torch
from pydantic import ValidationError

from jointseg.exceptions import ConfigError, library_reason
from jointseg.io.atomic import atomic_open
from jointseg.network.cards import portable_card
from jointseg.network.randlanet.model import RandLANet, RandLANetConfig
from jointseg.network.torch_files import gzipped, read_torch_file, state_mismatch

log = logging.getLogger(__name__)

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
    ``compress`` gzips the file: about 9 % smaller, read back transparently). The card's paths of
    this machine are written as their last part (:func:`jointseg.network.cards.portable_card`):
    every checkpoint may be shipped."""
    state = {
        k: (v.half() if half and v.is_floating_point() else v).cpu()
        for k, v in model.state_dict().items()
    }
    body = {
        "format": FORMAT,
        "config": model.config.model_dump(),
        "state_dict": state,
        "card": portable_card({**card, "input_conventions": INPUT_CONVENTIONS}),
        **(extra or {}),
    }
    buffer = io.BytesIO()
    torch.save(body, buffer)
    data = buffer.getvalue()
    if compress:
        data = gzip.compress(data, compresslevel=9, mtime=0)
    with atomic_open(Path(path)) as fh:
        fh.write(data)


def _config_problem(exc: ValidationError) -> str:
    """The first problem of an invalid stored configuration, as ``field: message``."""
    errors = exc.errors()
    first = errors[0]
    where = ".".join(str(part) for part in first.get("loc", ())) or "config"
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    return f"{where}: {first.get('msg', 'invalid')}{more}"


def load_checkpoint(path: str | os.PathLike[str]) -> tuple[RandLANet, dict[str, Any], dict]:
    """Load a checkpoint written by :func:`save_checkpoint`.

    Packed weights come from their unpacked copy in the cache when it is current (see the
    module); the first load writes it, and a cache folder that cannot be written only costs the
    time of reading the packed file each time.

    Returns
    -------
    (model in eval mode, card, the whole checkpoint dict)
        The dict's ``state_dict`` is the one the model holds: floating tensors as float32.

    Raises
    ------
    ConfigError
        When the file is missing, not a torch file, or not a jointseg RandLA-Net checkpoint.
    """
    path = Path(path)
    source = _source_key(path)
    if source is not None:
        unpacked = _read_unpacked(path, source)
        if unpacked is not None:
            return unpacked
    body = read_torch_file(path)
    if not isinstance(body, dict) or body.get("format") != FORMAT:
        raise ConfigError(
            f"{path}: not a jointseg RandLA-Net checkpoint (format {FORMAT!r}); convert "
            "Open3D-ML checkpoints with `jointseg models import open3d-ml FILE`"
        )
    config, state = body.get("config"), body.get("state_dict")
    if not isinstance(config, dict) or not isinstance(state, dict):
        raise ConfigError(f"{path}: the checkpoint lacks its 'config' or 'state_dict' mapping")
    packed = _is_packed(path, body, state)
    model, state = _model_with(path, config, state)
    body = {**body, "state_dict": state}
    if packed and source is not None:
        _write_unpacked(path, source, body)
    return model, body.get("card", {}), body


def _model_with(path: Path, config: dict, state: dict[str, Any]) -> tuple[RandLANet, dict]:
    """The model ``config`` describes holding ``state`` (floating tensors made float32), in
    eval mode; the state as the model holds it.

    Why the meta device: the tensors are taken as the parameters (``assign``) instead of copied
    into ones initialised at random first, which cost a third of a second on 2 cores.
    """
    try:
        with torch.device("meta"):
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
        model.load_state_dict(state, assign=True)
    except RuntimeError as exc:
        raise ConfigError(
            f"{path}: weights do not fit the stored configuration "
            f"({library_reason(exc, 'they do not load')})"
        ) from exc
    if any(t.is_meta for t in (*model.parameters(), *model.buffers())):
        # a tensor the state does not hold (none today): built on the CPU and copied instead
        model = RandLANet(RandLANetConfig(**config))
        model.load_state_dict(state)
    model.eval()
    return model, state


#: Layout of the unpacked copies; a copy of another layout is written again.
UNPACKED_FORMAT = "jointseg-unpacked/1"
#: What a packed checkpoint holds: weights and card, no training state (optimiser, epoch).
PACKED_KEYS = frozenset({"format", "config", "state_dict", "card"})


def unpacked_dir() -> Path:
    """Where unpacked copies of packed weights live: ``$JOINTSEG_CACHE/unpacked``, default
    ``~/.cache/jointseg/unpacked`` (beside pulled weights, not among them)."""
    root = os.environ.get("JOINTSEG_CACHE") or Path.home() / ".cache" / "jointseg"
    return Path(root) / "unpacked"


def unpacked_path(path: Path) -> Path:
    """The unpacked copy of the weights at ``path``: one per source path (a changed file's copy
    is replaced, not added to)."""
    where = hashlib.sha256(str(path.resolve()).encode()).hexdigest()[:16]
    return unpacked_dir() / f"{path.stem}-{where}.pt"


def _source_key(path: Path) -> dict[str, int] | None:
    """What the copy of ``path`` must have been made from: its size, times and inode (the
    change time moves with any rewrite, even one that keeps the modification time); None when
    there is no file."""
    try:
        st = path.stat()
    except OSError:
        return None
    return {
        "size": st.st_size,
        "mtime_ns": st.st_mtime_ns,
        "ctime_ns": st.st_ctime_ns,
        "inode": st.st_ino,
    }


def _is_packed(path: Path, body: dict, state: dict[str, Any]) -> bool:
    """Whether ``body`` is packed weights worth an unpacked copy: weights and card only, stored
    compressed or at a floating dtype other than float32."""
    if not set(body) <= PACKED_KEYS:
        return False
    narrow = any(
        isinstance(v, torch.Tensor) and v.is_floating_point() and v.dtype != torch.float32
        for v in state.values()
    )
    return narrow or gzipped(path)


def _flatten(state: dict[str, torch.Tensor]) -> tuple[dict[str, torch.Tensor], list[tuple]]:
    """The state as one flat tensor per dtype and where each tensor lies in it: a copy of two
    tensors maps and unpickles in milliseconds, one of 330 in a tenth of a second."""
    parts: dict[str, list[torch.Tensor]] = {}
    layout = []
    sizes: dict[str, int] = {}
    for name, tensor in state.items():
        dtype = str(tensor.dtype).removeprefix("torch.")
        offset = sizes.get(dtype, 0)
        layout.append((name, dtype, offset, tuple(tensor.shape)))
        parts.setdefault(dtype, []).append(tensor.detach().reshape(-1))
        sizes[dtype] = offset + tensor.numel()
    return {dtype: torch.cat(chunks) for dtype, chunks in parts.items()}, layout


def _unflatten(flat: dict[str, torch.Tensor], layout: list) -> dict[str, torch.Tensor]:
    """The tensors :func:`_flatten` laid out, each copied out of the flat ones.

    Why copies, not views of the mapped file: with its weights left in the file's mapping the
    network ran 2-4x slower in ``jointseg segment`` on 2 cores (its OpenMP threads spinning
    at barriers; measured on a 300 k-point room, the cause inside torch not found), and each
    tensor keeps a storage of its own, as a model read any other way has.
    """
    state = {}
    for name, dtype, offset, shape in layout:
        numel = 1
        for n in shape:
            numel *= n
        state[name] = flat[dtype][offset : offset + numel].view(shape).clone()
    return state


def _read_unpacked(
    path: Path, source: dict[str, int]
) -> tuple[RandLANet, dict[str, Any], dict] | None:
    """The checkpoint from its unpacked copy; None when there is no current copy (a stale or
    unreadable one is logged and left to be written again)."""
    copy = unpacked_path(path)
    if not copy.is_file():
        return None
    try:
        data = torch.load(copy, mmap=True, weights_only=True, map_location="cpu")
        if not isinstance(data, dict) or data.get("format") != UNPACKED_FORMAT:
            raise ValueError("another layout")
        if data.get("source") != source:
            log.info("weights %s changed since they were unpacked: unpacked again", path)
            return None
        body = data["body"]
        state = _unflatten(data["flat"], data["layout"])
        model, state = _model_with(path, body["config"], state)
    except Exception as exc:  # noqa: BLE001 - any fault of the copy: read the weights instead
        log.info("ignored the unpacked copy %s of %s (%s); written again", copy, path, exc)
        return None
    return model, body.get("card", {}), {**body, "state_dict": state}


def _write_unpacked(path: Path, source: dict[str, int], body: dict) -> None:
    """Keep an unpacked copy of the checkpoint ``body`` read from ``path`` (replaced at once, so
    a process reading it meanwhile sees the old copy or the new one); a cache that cannot be
    written is logged and skipped."""
    copy = unpacked_path(path)
    flat, layout = _flatten(body["state_dict"])
    data = {
        "format": UNPACKED_FORMAT,
        "source": source,
        "body": {k: v for k, v in body.items() if k != "state_dict"},
        "layout": layout,
        "flat": flat,
    }
    try:
        copy.parent.mkdir(parents=True, exist_ok=True)
        with atomic_open(copy) as fh:
            torch.save(data, fh)
    except (OSError, RuntimeError) as exc:  # torch's writer reports a full disk as RuntimeError
        log.info(
            "could not keep an unpacked copy of %s in %s (%s): it is read whole each time",
            path,
            copy.parent,
            exc,
        )
        return
    log.debug("unpacked %s into %s", path, copy)
