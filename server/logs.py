"""Logging of every service process (API, workers, viewer) in one format.

Several workers and the viewer often share one terminal, so each line carries the process id.
"""

from __future__ import annotations

import logging

from server.settings import Settings


def configure_logging(settings: Settings) -> None:
    """Log at ``settings.log_level`` with time, level, process id and logger name."""
    logging.basicConfig(
        level=settings.log_level.upper(),
        format="%(asctime)s %(levelname)s [%(process)d] %(name)s: %(message)s",
        force=True,
    )
