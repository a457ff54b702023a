"""Dependencies shared by the routes: settings, registry, job service, the bearer token check."""

from __future__ import annotations

import hmac
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from server.registry import SpaceRegistry
from server.settings import Settings

_bearer = HTTPBearer(auto_error=False, description="the server's token (MORPHSPACE_TOKEN), when it has one")


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_registry(request: Request) -> SpaceRegistry:
    return request.app.state.registry


def get_jobs(request: Request):
    return request.app.state.jobs


def require_token(request: Request,
                  credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> None:
    """Mutating endpoints need ``Authorization: Bearer <token>`` when the server has a token."""
    token = request.app.state.settings.token_value()
    if token is None:
        return
    if credentials is None or not hmac.compare_digest(credentials.credentials.encode(), token.encode()):
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "a valid bearer token is required for this endpoint",
                            headers={"WWW-Authenticate": "Bearer"})


SettingsDep = Annotated[Settings, Depends(get_settings)]
RegistryDep = Annotated[SpaceRegistry, Depends(get_registry)]
Authorised = Depends(require_token)
