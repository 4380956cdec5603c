"""Optional API keys: a FastAPI dependency every /v1 route (and the viewer's routes) can reuse.

With no keys configured the service is open. With keys, a request needs
``Authorization: Bearer <key>``; keys are compared in constant time and never logged.
"""

from __future__ import annotations

import hmac

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from jointseg.exceptions import AuthenticationError
from server.settings import Settings

bearer = HTTPBearer(auto_error=False, description="An API key, when the service has any.")


def key_accepted(settings: Settings, presented: str | None) -> bool:
    """Whether ``presented`` is one of the configured keys (always true without keys)."""
    keys = settings.api_key_values()
    if not keys:
        return True
    if not presented:
        return False
    given = presented.encode()
    return any(hmac.compare_digest(given, key.encode()) for key in keys)


def require_api_key(
    request: Request,
    credentials: HTTPAuthorizationCredentials | None = Depends(bearer),  # noqa: B008
) -> None:
    """Refuse the request (401) unless it carries an accepted key or no keys are configured.

    Raises
    ------
    AuthenticationError
    """
    settings: Settings = request.app.state.services.settings
    if not settings.api_keys:
        return
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise AuthenticationError("missing API key: send 'Authorization: Bearer <key>'")
    if not key_accepted(settings, credentials.credentials):
        raise AuthenticationError("invalid API key")
