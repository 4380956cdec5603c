"""``network.weights: "model:<id>"``: a job that uses a model learnt from corrections.

Why apart from :mod:`server.weights`: a model is a row and a file of this service, so whether a
job may name it depends on who submits the job (a tenant uses its own models), which a file in
the weights folders does not. The API checks the owner at submission (:func:`check_model_ref`);
the worker resolves the id again to the file (:func:`model_file`) and opens nothing else.
"""

from __future__ import annotations

import os
from pathlib import Path

from jointseg.exceptions import ConfigError, JobNotFound, JobStateError
from server.state import model_jobs
from server.state.db import SessionFactory
from server.storage import Storage

FIELD = "config.network.weights"


def model_ref(value: str | os.PathLike[str] | None) -> str | None:
    """The model id ``value`` names (``model:<id>``), or None for any other weights."""
    if value is None:
        return None
    text = os.fspath(value)
    if not text.startswith(model_jobs.MODEL_PREFIX):
        return None
    return text[len(model_jobs.MODEL_PREFIX) :]


def check_model_ref(sessions: SessionFactory, model_id: str, *, owned_by: str | None) -> None:
    """Refuse a job's model that is not ``owned_by``'s succeeded model.

    Raises
    ------
    ConfigError
        Naming :data:`FIELD`: the same answer for an unknown model and another owner's, so
        their existence does not leak; another for one of the caller's not (yet) succeeded.
    """
    try:
        with sessions() as session:
            model_jobs.usable_model(session, model_id, owned_by=owned_by)
    except JobNotFound:
        raise ConfigError(
            f"{FIELD}: no model {model_id} of yours on this service (GET /v1/models)"
        ) from None
    except JobStateError as exc:
        raise ConfigError(f"{FIELD}: {exc}; a job uses a model that succeeded") from None


def model_file(sessions: SessionFactory, storage: Storage, model_id: str) -> Path:
    """The checkpoint of succeeded model ``model_id`` (the worker's side: the API checked
    whose it is when the job was submitted).

    Raises
    ------
    ConfigError
        When the model is gone (deleted since), has not succeeded, or lacks its file.
    """
    check_model_ref(sessions, model_id, owned_by=None)
    path = storage.model_path(model_id)
    if not path.is_file():
        raise ConfigError(f"{FIELD}: model {model_id} has no file (deleted?)")
    return path
