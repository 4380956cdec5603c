"""What a network backend is: one :class:`Backend` record per backend, and the :class:`Predictor`
protocol every loaded backend satisfies.

A record is plain data plus two ``"module:function"`` paths (its loader and its card reader), so
the registry, the configuration and the job service learn a backend's name, options and weights
without importing torch: the backend's module is imported when its weights are first read.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib import import_module
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, cast, runtime_checkable

from pydantic import BaseModel, ValidationError

from jointseg.exceptions import ConfigError
from jointseg.progress import CancelToken, ProgressFn

if TYPE_CHECKING:
    import numpy as np
    import torch

    from jointseg.network.anchored import AnchoredCloud, CropPlan
    from jointseg.network.results import CellSums, NetworkResult
    from jointseg.scan import Scan

log = logging.getLogger(__name__)

#: Weights shipped inside the package.
WEIGHTS_DIR = Path(__file__).parent / "weights"

#: A backend's options as callers give them: its params model, a mapping of its fields, or None.
Options = BaseModel | Mapping[str, Any] | None


class Predictor(Protocol):
    """A loaded network of any backend, ready to label whole scans."""

    @property
    def name(self) -> str:
        """The backend's name."""
        ...

    @property
    def card(self) -> dict[str, Any]:
        """The weights' model card (``data``: what they were trained on, ...)."""
        ...

    @property
    def device(self) -> torch.device:
        """Where the network runs."""
        ...

    @property
    def model(self) -> torch.nn.Module:
        """The network itself, in eval mode on :attr:`device`."""
        ...

    @property
    def batch_size(self) -> int:
        """Crops (or samples) per forward pass."""
        ...

    def predict(
        self,
        scan: Scan,
        progress: ProgressFn | None = None,
        cancel: CancelToken | None = None,
        *,
        seed: int = 0,
    ) -> NetworkResult:
        """Labels and class probabilities for every point of ``scan``."""
        ...


#: ``loader(path, *, device, batch_size, params)``: a ready predictor from a weights file.
Loader = Callable[..., Predictor]
#: ``card_reader(path)``: what the weights were trained on, and the rest of their card in one
#: line ("" when none); raises ConfigError for an unreadable file.
CardReader = Callable[[Path], tuple[str, str]]


@dataclass(frozen=True)
class Backend:
    """Everything jointseg knows about one network backend before its weights are read.

    Attributes
    ----------
    name : str
        What ``--network`` and ``network.name`` call it.
    loader, card_reader : str
        ``"module:function"`` paths of a :data:`Loader` and a :data:`CardReader`, imported on
        first use (they import torch).
    env : str
        Environment variable naming its weights file (or published weights).
    where_to_get : str
        How to obtain weights, shown when there are none.
    params : pydantic model class, optional
        Its options; they live in the pipeline configuration's ``network.<name>`` section.
        None: the backend takes none.
    params_help : str
        What its options are about (the configuration's description of that section).
    bundled : Path, optional
        Weights shipped with the package.
    published : str, optional
        Published weights (:mod:`jointseg.network.published`) used once pulled, when nothing
        else is given.
    suffixes : tuple of str
        Weight file suffixes that name this backend when a path is given instead of a name.
    fast_loader : str, optional
        ``"module:function"`` path of a loader that imports no torch and returns None when it
        cannot serve the weights (:mod:`jointseg.network.randlanet.compiled`); tried first.
    """

    name: str
    loader: str
    card_reader: str
    env: str
    where_to_get: str
    params: type[BaseModel] | None = None
    params_help: str = ""
    bundled: Path | None = None
    published: str | None = None
    suffixes: tuple[str, ...] = ()
    fast_loader: str | None = None

    def options(self, value: Options = None) -> BaseModel | None:
        """``value`` validated by this backend's params model (its defaults for None).

        Raises
        ------
        ConfigError
            When the options are not this backend's, or the backend takes none.
        """
        if self.params is None:
            if value is None or (isinstance(value, Mapping) and not value):
                return None
            raise ConfigError(f"network {self.name!r} takes no options")
        if value is None:
            return self.params()
        if isinstance(value, self.params):
            return value
        if isinstance(value, BaseModel):
            raise ConfigError(
                f"network {self.name!r} takes {self.params.__name__}, not {type(value).__name__}"
            )
        try:
            return self.params.model_validate(value)
        except ValidationError as exc:
            raise ConfigError(f"network {self.name!r} options: {exc}") from exc

    def load(
        self, path: Path, *, device: str | None, batch_size: int, options: Options = None
    ) -> Predictor:
        """A ready predictor with the weights at ``path`` (imports the backend's module).

        Raises
        ------
        ConfigError
            For invalid options or unreadable weights.
        """
        fast = self.load_fast(path, device=device, batch_size=batch_size, options=options)
        if fast is not None:
            return fast
        params = self.options(options)
        loader = cast(Loader, _resolve(self.loader))
        log.debug("network %s: loading %s", self.name, path)
        return loader(path, device=device, batch_size=batch_size, params=params)

    def load_fast(
        self, path: Path, *, device: str | None, batch_size: int, options: Options = None
    ) -> Predictor | None:
        """The predictor of :attr:`fast_loader` (no torch imported), or None when the backend
        has none or it cannot serve these weights here.

        Raises
        ------
        ConfigError
            For invalid options.
        """
        if self.fast_loader is None:
            return None
        params = self.options(options)
        fast = cast(Callable[..., "Predictor | None"], _resolve(self.fast_loader))(
            path, device=device, batch_size=batch_size, params=params
        )
        if fast is not None:
            log.debug("network %s: %s, compiled", self.name, path)
        return fast

    def read_card(self, path: Path) -> tuple[str, str]:
        """What the weights at ``path`` were trained on, and their card in one line."""
        return cast(CardReader, _resolve(self.card_reader))(path)


def _resolve(target: str) -> Callable[..., Any]:
    """The function a ``"module:function"`` path names."""
    module, _, attr = target.partition(":")
    value = getattr(import_module(module), attr)
    if not callable(value):
        raise TypeError(f"{target} is not callable")
    return cast(Callable[..., Any], value)


def card_summary(card: dict[str, Any]) -> str:
    """One line of a jointseg model card: epochs, validation score, hardware, command, terms."""
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


@runtime_checkable
class TilePredictor(Protocol):
    """A predictor that can share one whole-scan inference among tiles (RandLA-Net): the
    whole scan's crop plan is made once, each tile evaluates the crops centred in its core,
    and the sums per sub-sampled cell are added over tiles (:mod:`jointseg.network.anchored`).
    """

    @property
    def grid_size(self) -> float:
        """Side (m) of the sub-sampling grid."""
        ...

    def plan(self, cloud: AnchoredCloud, seed: int) -> CropPlan:
        """The crop plan of a whole scan's sub-sample."""
        ...

    def predict_cells(
        self,
        scan: Scan,
        plan: CropPlan,
        lower: np.ndarray,
        crops: np.ndarray,
        progress: ProgressFn | None = None,
        cancel: CancelToken | None = None,
        *,
        seed: int = 0,
    ) -> CellSums:
        """A tile's share of the whole-scan inference."""
        ...
