"""The device names a predictor runs on, checked without torch.

Why here: the configuration (its field pattern, the API's 422) and the command line's override
must refuse the same names with the same words as :func:`jointseg.network.base.pick_device`,
which imports torch; this module does not, so `jointseg --help` and the API stay light.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from jointseg.exceptions import ConfigError

#: The devices the code paths are written and tested for.
DEVICE_NAMES = r"cpu|cuda(:[0-9]+)?"
_DEVICE = re.compile(DEVICE_NAMES)


def check_device_name(device: str) -> None:
    """Refuse a device name other than ``cpu``, ``cuda`` or ``cuda:N``.

    Raises
    ------
    ConfigError
    """
    if _DEVICE.fullmatch(str(device)) is None:
        raise ConfigError(f"device {device!r}: unknown device; use 'cpu', 'cuda' or 'cuda:N'")


def cuda_possible() -> bool:
    """Whether torch would find a CUDA device here: its own answer, asked only where torch is
    already imported or an NVIDIA driver is loaded (without one there is no device, and a
    command-line run on a CPU machine need not import torch to know it)."""
    if "torch" not in sys.modules and not (
        Path("/proc/driver/nvidia/version").exists() or Path("/dev/nvidiactl").exists()
    ):
        return False
    import torch

    return bool(torch.cuda.is_available())
