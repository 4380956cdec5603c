"""The device names a predictor runs on, checked without torch.

Why here: the configuration (its field pattern, the API's 422) and the command line's override
must refuse the same names with the same words as :func:`jointseg.network.base.pick_device`,
which imports torch; this module does not, so `jointseg --help` and the API stay light.
"""

from __future__ import annotations

import re

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
