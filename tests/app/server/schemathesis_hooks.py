"""Our own schemathesis check, loaded by schemathesis.toml (`hooks`): the one 5xx a client
may meet is a 503 that says when to try again."""

from __future__ import annotations

import schemathesis


@schemathesis.check
def unavailable_says_when_to_retry(ctx, response, case) -> None:
    """A 503 carries Retry-After (not_a_server_error lets 503 through for this check;
    status_code_conformance holds it to the documented ones)."""
    if response.status_code == 503 and "retry-after" not in {
        name.lower() for name in response.headers
    }:
        raise AssertionError(f"503 without Retry-After: {response.text[:200]}")


@schemathesis.serializer("audio/wav", "audio/webm", "audio/ogg", "audio/mp4")
def audio_bytes(ctx, value) -> bytes:
    """A spoken question's body as generated (binary strings, or anything else as its text):
    random bytes, which the server must refuse with a documented 4xx, never a 5xx."""
    if isinstance(value, bytes):
        return value
    return str(value).encode()
