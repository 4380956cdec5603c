"""Optional API keys and tenants: a FastAPI dependency every /v1 route (and the viewer) reuses.

With no keys configured the service is open and every caller sees every job. With keys, a
request needs ``Authorization: Bearer <key>``; keys are compared in constant time and never
logged. Each key is a tenant: the jobs it submits carry :func:`owner_of` its key (a hash, never
the key) and only it sees them; ``admin_keys`` see every job.
"""

from __future__ import annotations

import hashlib
import hmac
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from jointseg.exceptions import AuthenticationError
from server.settings import Settings

bearer = HTTPBearer(auto_error=False, description="An API key, when the service has any.")

#: Domain separation of the owner hash (the same key hashed elsewhere gives another digest).
_OWNER_CONTEXT = b"jointseg job owner\x00"


def owner_of(key: str) -> str:
    """The job table's owner of jobs submitted with ``key``: 64 hex digits of SHA-256, so the
    table never holds a key (keys should be long random strings; a short one could be guessed
    back from its hash)."""
    return hashlib.sha256(_OWNER_CONTEXT + key.encode()).hexdigest()


@dataclass(frozen=True)
class Tenant:
    """Who is calling: the owner stamped on the jobs it submits, and whether it sees all jobs.

    ``owner`` is None in open mode (no keys configured): such jobs belong to nobody in
    particular and open-mode callers see every job, as before tenants existed.
    """

    owner: str | None
    admin: bool = False

    @property
    def scope(self) -> str | None:
        """The owner whose jobs this caller may see; None: every job (open mode, admin keys)."""
        return None if self.admin else self.owner


#: The caller of an open service (no keys configured).
OPEN = Tenant(owner=None)


def _matches(given: bytes, keys: list[str]) -> bool:
    """Whether ``given`` is one of ``keys``, comparing against each (constant time per key)."""
    found = False
    for key in keys:
        found |= hmac.compare_digest(given, key.encode())
    return found


def tenant_for(settings: Settings, presented: str | None) -> Tenant | None:
    """The tenant a presented key (None: none) stands for; None when the key is refused.

    Without keys configured every caller is :data:`OPEN`.
    """
    if not settings.keys_required:
        return OPEN
    if not presented:
        return None
    given = presented.encode()
    admin = _matches(given, settings.admin_key_values())
    if admin or _matches(given, settings.api_key_values()):
        return Tenant(owner=owner_of(presented), admin=admin)
    return None


def key_accepted(settings: Settings, presented: str | None) -> bool:
    """Whether ``presented`` is one of the configured keys (always true without keys)."""
    return tenant_for(settings, presented) is not None


def require_api_key(
    request: Request,
    credentials: HTTPAuthorizationCredentials | None = Depends(bearer),  # noqa: B008
) -> Tenant:
    """The caller's tenant; refuse the request (401) unless it carries an accepted key or no
    keys are configured.

    Raises
    ------
    AuthenticationError
    """
    settings: Settings = request.app.state.services.settings
    if not settings.keys_required:
        return OPEN
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise AuthenticationError("missing API key: send 'Authorization: Bearer <key>'")
    tenant = tenant_for(settings, credentials.credentials)
    if tenant is None:
        raise AuthenticationError("invalid API key")
    return tenant


#: A route's caller (FastAPI runs the dependency once per request, however often it is named).
TenantDep = Annotated[Tenant, Depends(require_api_key)]
