"""The one client of the API (wire protocol v1), used by the device, the viewer, the demo and
the benches: URLs and auth, the REST session calls, and the resumable updates subscriber.

Messages themselves are parsed by their users (app.protocol); this package moves them.
"""

from app.client.connection import (
    CONNECTION_ERRORS,
    Backoff,
    auth_headers,
    http_base_url,
    open_websocket,
    trusting,
    websocket_base_url,
)
from app.client.rest import ApiError, SessionApi, create_session
from app.client.updates import Disconnect, UpdatesSubscriber

__all__ = [
    "CONNECTION_ERRORS",
    "ApiError",
    "Backoff",
    "Disconnect",
    "SessionApi",
    "UpdatesSubscriber",
    "auth_headers",
    "create_session",
    "http_base_url",
    "open_websocket",
    "trusting",
    "websocket_base_url",
]
