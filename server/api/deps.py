"""What a request handler gets injected: the app's :class:`Services` and a database session.

The services are built once by the app's lifespan (:func:`server.api.app.create_app`) and kept in
``app.state``; routes (the viewer's too) reach them only through these dependencies.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Request
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from server.api.checks import UploadChecker
from server.queue import JobQueue
from server.settings import Settings
from server.state.db import SessionFactory
from server.storage import Storage


@dataclass
class Services:
    """What the routes need, built once per app from its settings."""

    settings: Settings
    engine: Engine
    sessions: SessionFactory
    storage: Storage
    queue: JobQueue
    checker: UploadChecker


def get_services(request: Request) -> Services:
    """The app's services (built by its lifespan)."""
    services: Services = request.app.state.services
    return services


def get_session(services: Annotated[Services, Depends(get_services)]) -> Iterator[Session]:
    """One database session per request."""
    with services.sessions() as session:
        yield session


ServicesDep = Annotated[Services, Depends(get_services)]
SessionDep = Annotated[Session, Depends(get_session)]
