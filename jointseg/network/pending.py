"""A network that loads in a thread while the scan is read, its frame decided and its geometry
segmented: the first use waits for it.

Why: a command-line run starts by importing torch and reading the weights (2.1 s on the 2-core
AMD EPYC of ``bench/speed.py``), which nothing before the network stage needs when the frame
stage does not ask the network; the geometry stage, which runs beside the network, needs no
torch at all. Loading beside them hides most of those seconds on two cores.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from jointseg.network.backends import Predictor
from jointseg.network.results import NetworkResult
from jointseg.progress import CancelToken, ProgressFn
from jointseg.scan import Scan

if TYPE_CHECKING:
    import torch


class PendingPredictor:
    """A :class:`~jointseg.network.backends.Predictor` being loaded in a daemon thread.

    Any attribute (``predict``, ``card``, ``model``, ...) is the loaded predictor's, waited for;
    an error of the load (a ConfigError for unreadable weights) is raised there, to the first
    user, and again to every later one. :func:`resolve` gives the loaded predictor itself, for
    callers that check its type.
    """

    def __init__(self, prepare: Callable[[], None], load: Callable[[], Predictor]) -> None:
        """Start ``prepare()`` (imports, not timed) and then ``load()`` (timed as
        :attr:`load_s`) in a thread."""
        self._predictor: Predictor | None = None
        self._error: BaseException | None = None
        self.load_s = 0.0
        self._thread = threading.Thread(
            target=self._run, args=(prepare, load), name="network-load", daemon=True
        )
        self._thread.start()

    def _run(self, prepare: Callable[[], None], load: Callable[[], Predictor]) -> None:
        try:
            prepare()
            started = time.perf_counter()
            self._predictor = load()
            self.load_s = time.perf_counter() - started
        except BaseException as exc:  # handed to the first user, who raises it
            self._error = exc

    @property
    def ready(self) -> bool:
        """Whether the load has ended (loaded or failed)."""
        return not self._thread.is_alive()

    def get(self) -> Predictor:
        """The loaded predictor, after waiting for it.

        Raises
        ------
        Exception
            Whatever the load raised.
        """
        self._thread.join()
        if self._error is not None:
            raise self._error
        assert self._predictor is not None
        return self._predictor

    # the Predictor protocol's members, each the loaded predictor's
    @property
    def name(self) -> str:
        """The backend's name."""
        return self.get().name

    @property
    def card(self) -> dict[str, Any]:
        """The weights' model card."""
        return self.get().card

    @property
    def device(self) -> torch.device:
        """Where the network runs."""
        return self.get().device

    @property
    def model(self) -> torch.nn.Module:
        """The network itself."""
        return self.get().model

    @property
    def batch_size(self) -> int:
        """Crops (or samples) per forward pass."""
        return self.get().batch_size

    def predict(
        self,
        scan: Scan,
        progress: ProgressFn | None = None,
        cancel: CancelToken | None = None,
        *,
        seed: int = 0,
    ) -> NetworkResult:
        """The loaded predictor's :meth:`predict`."""
        return self.get().predict(scan, progress, cancel, seed=seed)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):  # not found on this object itself: never the predictor's
            raise AttributeError(name)
        return getattr(self.get(), name)


def resolve(predictor: Predictor) -> Predictor:
    """The predictor itself: a pending one's after waiting for it."""
    return predictor.get() if isinstance(predictor, PendingPredictor) else predictor
