"""Domain errors raised by jointseg.

Every error a user can cause carries a message that names what is wrong and where, so the CLI
can print it as is and the service can map each class to one HTTP status.
"""

from __future__ import annotations


class JointsegError(Exception):
    """Base class of every error jointseg raises on purpose."""


class ScanFormatError(JointsegError, ValueError):
    """A scan file (or array) is malformed, unsupported or too large.

    The message says what is wrong and, where it can, which line, element or field.
    """


class ConfigError(JointsegError, ValueError):
    """A configuration value is invalid; the message names the parameter and the value."""


class Cancelled(JointsegError):
    """Work was stopped because its cancel event was set."""
