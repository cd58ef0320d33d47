"""What the routes get by FastAPI's dependency injection: the server's session manager."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends
from starlette.requests import HTTPConnection

from app.server.sessions import SessionManager


def session_manager(connection: HTTPConnection) -> SessionManager:
    """The server's sessions (made at start-up by the app's lifespan); for requests and
    sockets alike."""
    return connection.app.state.manager


Manager = Annotated[SessionManager, Depends(session_manager)]
"""A route parameter `manager: Manager` is the server's `SessionManager`."""
