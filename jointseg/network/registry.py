"""Network backends by name, where their weights come from, and one loader for all of them.

A backend's weights are, in this order: the path the caller gives (or the name of pulled
published weights, see :mod:`jointseg.network.published`), the path in the backend's environment
variable, its default published weights once pulled, the weights bundled with the package. DGCNN
has no bundled weights (the published ones are a separate download): ``jointseg models pull
dgcnn-s3dis-5`` fetches the default ones.

Imports no torch: the job service and the web page import this module to know the names, and a
backend's own module is imported only when its weights are read (see
:class:`~jointseg.network.backends.Backend`). A new backend is one module declaring its
``BACKEND`` and one line in :data:`BACKEND_MODULES`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import import_module
from pathlib import Path
from types import MappingProxyType

from jointseg.exceptions import ConfigError
from jointseg.network import published
from jointseg.network.backends import WEIGHTS_DIR, Backend, Options, Predictor

__all__ = [
    "BACKENDS",
    "backend_for_suffix",
    "BACKEND_MODULES",
    "DEFAULT_BACKEND",
    "REGISTRY",
    "BackendInfo",
    "available_backends",
    "backend",
    "has_weights",
    "import_backend",
    "installed_backends",
    "load",
    "resolve_weights",
]

#: The torch-free modules that declare the backends (each a ``BACKEND``), in the order
#: `jointseg models list` shows them.
BACKEND_MODULES = (
    "jointseg.network.randlanet.backend",
    "jointseg.network.dgcnn.backend",
)


def _declared(module: str) -> Backend:
    """The ``BACKEND`` record ``module`` declares."""
    record = getattr(import_module(module), "BACKEND", None)
    if not isinstance(record, Backend):
        raise TypeError(f"{module}.BACKEND is not a jointseg.network.backends.Backend")
    return record


#: Every backend by name.
REGISTRY: Mapping[str, Backend] = MappingProxyType(
    {b.name: b for b in map(_declared, BACKEND_MODULES)}
)
#: The backend used when none is named.
DEFAULT_BACKEND = "randlanet"

#: The backends' names, in the order help texts list them.
BACKENDS: tuple[str, ...] = tuple(REGISTRY)


def backend_for_suffix(path: str) -> str | None:
    """The backend whose weight files end like ``path`` (``.t7``: DGCNN), else None."""
    suffix = Path(path).suffix
    return next((n for n, b in REGISTRY.items() if suffix in b.suffixes), None)


@dataclass(frozen=True)
class BackendInfo:
    """What `jointseg models list` shows for one backend.

    ``weights`` is None when the backend has none configured; ``source`` says where they come
    from ("bundled", "pulled", "$VARIABLE" or "none"); ``where_to_get`` how to obtain them.
    """

    name: str
    weights: Path | None
    available: bool
    trained_on: str
    source: str
    where_to_get: str
    card: str = ""


def backend(name: str) -> Backend:
    """The backend called ``name``.

    Raises
    ------
    ConfigError
        For an unknown name; the message lists the known ones.
    """
    try:
        return REGISTRY[name]
    except KeyError:
        raise ConfigError(f"unknown network {name!r}; available: {', '.join(BACKENDS)}") from None


def resolve_weights(name: str, weights: str | os.PathLike[str] | None = None) -> Path | None:
    """The weights file backend ``name`` would use: ``weights``, else its environment
    variable, else its pulled default or bundled file; None when there is none of them."""
    if weights is not None:
        return _named_or_path(str(weights))
    record = REGISTRY.get(name)
    if record is None:
        return None
    env = os.environ.get(record.env, "")
    if env:
        return _named_or_path(env)
    if record.published is not None:
        return published.pulled_path(record.published)
    return record.bundled


def has_weights(name: str) -> bool:
    """Whether backend ``name`` has the weights it would use by default on this machine.

    Only the file's presence is checked (no torch, no read), so the job service can refuse a
    job it cannot run at submission and the job page can offer only the networks that run.
    """
    if name not in REGISTRY:
        return False
    try:
        path = resolve_weights(name)
    except ConfigError:  # its variable names published weights not pulled yet
        return False
    return path is not None and path.is_file()


def installed_backends() -> tuple[str, ...]:
    """The backends with weights on this machine (:func:`has_weights`), in :data:`BACKENDS`
    order."""
    return tuple(name for name in BACKENDS if has_weights(name))


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


def _card(record: Backend, path: Path) -> tuple[str, str]:
    """What the weights were trained on, and the rest of their card in one line."""
    try:
        return record.read_card(path)
    except ConfigError as exc:
        return f"unreadable: {exc}", ""


def available_backends() -> list[BackendInfo]:
    """Every backend with the weights it would use and whether they are installed."""
    out = []
    for record in REGISTRY.values():
        path = resolve_weights(record.name)
        if os.environ.get(record.env):
            source = f"${record.env}"
        elif path is None:
            source = "none"
        else:
            source = "pulled" if record.published is not None else "bundled"
        present = path is not None and path.is_file()
        trained_on, card = _card(record, path) if present and path is not None else ("-", "")
        out.append(
            BackendInfo(record.name, path, present, trained_on, source, record.where_to_get, card)
        )
    return out


def load(
    name: str = DEFAULT_BACKEND,
    weights: str | os.PathLike[str] | None = None,
    *,
    device: str | None = None,
    batch_size: int | None = None,
    params: Options = None,
    **options: Options,
) -> Predictor:
    """A ready predictor for backend ``name`` with ``weights`` (default: see the module).

    ``name`` may also be a weights path, for ``load("model.pt")`` (RandLA-Net) or
    ``load("model_1.t7")`` (DGCNN). ``batch_size`` is crops (RandLA-Net) or 4 096-point blocks
    (DGCNN) per forward pass; default :func:`default_batch_size`. ``params`` are the backend's
    options (e.g. ``DGCNNParams``); they may also be given under the backend's name,
    ``load("dgcnn", dgcnn=DGCNNParams(...))``, so a caller holding every backend's options
    passes them all and the chosen one's are used.

    Raises
    ------
    ConfigError
        For an unknown backend, invalid options, or missing/unreadable weights; the message says
        where to get weights.
    TypeError
        For a keyword that is no backend's name.
    """
    unknown = sorted(set(options) - set(REGISTRY))
    if unknown:
        raise TypeError(f"load() got unexpected keyword arguments: {', '.join(unknown)}")
    name, path = locate(name, weights)
    record = backend(name)
    chosen = params if params is not None else options.get(name)
    size = batch_size or default_batch_size(device)
    return record.load(path, device=device, batch_size=size, options=chosen)


def load_fast(
    name: str = DEFAULT_BACKEND,
    weights: str | os.PathLike[str] | None = None,
    *,
    device: str | None = None,
    batch_size: int | None = None,
    params: Options = None,
) -> Predictor | None:
    """What :func:`load` returns when the backend can serve the weights without torch (its
    compiled forward pass, :mod:`jointseg.network.randlanet.compiled`); None otherwise, having
    imported nothing heavy. A caller that loads in the background asks this first, and imports
    torch only when it gets None.

    Raises
    ------
    ConfigError
        As :func:`load`.
    """
    name, path = locate(name, weights)
    size = batch_size or default_batch_size(device)
    return backend(name).load_fast(path, device=device, batch_size=size, options=params)


def locate(
    name: str = DEFAULT_BACKEND, weights: str | os.PathLike[str] | None = None
) -> tuple[str, Path]:
    """The backend and the weights file :func:`load` would read, found without reading it
    (no torch): a caller that loads in the background still refuses a missing file at once.

    Raises
    ------
    ConfigError
        For an unknown backend or missing weights, as :func:`load` does.
    """
    by_suffix = backend_for_suffix(name)
    if weights is None and name not in REGISTRY and by_suffix is not None:
        name, weights = by_suffix, name
    record = backend(name)
    path = resolve_weights(name, weights)
    if path is None:
        raise ConfigError(f"no weights for {name!r}: {record.where_to_get}")
    if not path.is_file():
        raise ConfigError(_missing_weights(name, path, record))
    return name, path


def import_backend(name: str = DEFAULT_BACKEND) -> None:
    """Import the code backend ``name`` (or the one a weights path's suffix names) runs on:
    torch and the model, seconds on a cold start, without reading any weights.

    Why: a caller that times :func:`load` (the report's ``load_network``) imports first, so
    the time it reports is the network's own and the imports are counted apart. An unknown
    name imports nothing; :func:`load` says what is wrong with it.
    """
    record = REGISTRY.get(name) or REGISTRY.get(backend_for_suffix(name) or "")
    if record is not None:
        import_module(record.loader.partition(":")[0])


def _missing_weights(name: str, path: Path, record: Backend) -> str:
    """Why ``path`` cannot be loaded: a file missing from the package's own weights folder is an
    incomplete installation (a wheel built without its package data), not weights to fetch."""
    if path.resolve().parent == WEIGHTS_DIR.resolve():
        return (
            f"the bundled weights {path} for {name!r} are missing: the jointseg installation is "
            "incomplete; reinstall jointseg"
        )
    return f"no weights for {name!r} at {path}: {record.where_to_get}"


#: Crops (or blocks) per forward pass by default: on the CPU one at a time is fastest (measured
#: on 2 cores: a 1 M-point room through RandLA-Net in 5.7 s with 1, 6.8 s with 2, 8.3 s with 4;
#: DGCNN on 300 k points 29-33 s with 1, 43 s with 4: the activations of several crops do not
#: fit in the caches); a GPU wants several.
CPU_BATCH_SIZE = 1
GPU_BATCH_SIZE = 8


def default_batch_size(device: str | None) -> int:
    """The forward-pass batch for ``device`` (None: CUDA when present)."""
    if device is None:
        from jointseg.network.devices import cuda_possible  # torch's answer where imported

        device = "cuda" if cuda_possible() else "cpu"
    return GPU_BATCH_SIZE if str(device).startswith("cuda") else CPU_BATCH_SIZE
