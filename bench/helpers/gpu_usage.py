"""GPU utilisation while something runs, sampled from `nvidia-smi` in a background thread (the
figure `nvidia-smi` shows: the share of time a kernel was running, not how busy the SMs were)."""

from __future__ import annotations

import shutil
import subprocess
import threading
from types import TracebackType

QUERY = ["--query-gpu=utilization.gpu", "--format=csv,noheader,nounits"]


class GpuUsage:
    """``with GpuUsage() as usage: work()``; then ``usage.mean`` and ``usage.peak`` (percent of
    the first GPU), None when `nvidia-smi` is absent or gave nothing."""

    def __init__(self, every_s: float = 0.1) -> None:
        self.every_s = every_s
        self.samples: list[float] = []
        self._tool = shutil.which("nvidia-smi")
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _sample(self) -> None:
        assert self._tool is not None
        while not self._stop.is_set():
            try:
                out = subprocess.run(
                    [self._tool, *QUERY], capture_output=True, text=True, timeout=5, check=True
                ).stdout
                self.samples.append(float(out.split()[0]))
            except (subprocess.SubprocessError, OSError, ValueError, IndexError):
                return
            self._stop.wait(self.every_s)

    def __enter__(self) -> GpuUsage:
        if self._tool is not None:
            self._thread = threading.Thread(target=self._sample, daemon=True)
            self._thread.start()
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    @property
    def mean(self) -> float | None:
        return sum(self.samples) / len(self.samples) if self.samples else None

    @property
    def peak(self) -> float | None:
        return max(self.samples) if self.samples else None
