"""Server settings: one typed dataclass; CLI flags and SEMANTICXR_* environment variables map
onto its fields (flag > environment > default)."""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass


@dataclass
class ServerSettings:
    host: str = "127.0.0.1"
    """Interface to listen on."""
    port: int = 8000
    """TCP port."""
    data_dir: str = "data"
    """Folder of the SQLite database (sessions, knobs, confirmed objects, delta seq)."""
    api_key: str | None = None
    """Key needed to create and list sessions; each session then has its own token. None runs open."""
    max_message_bytes: int = 8 << 20
    """Largest WebSocket message accepted (bigger closes the socket with code 1009)."""
    max_body_bytes: int = 1 << 20
    """Largest REST request body."""
    max_sessions: int = 64
    """Sessions the server holds at once."""
    mapping_workers: int = 2
    """Threads that decode and map frames (sessions map one frame at a time each)."""
    max_subscribers: int = 32
    """Update subscribers per session."""
    max_bad_frames: int = 50
    """Consecutive bad frames before a stream is closed as abusive (code 1008)."""
    max_query_k: int = 100
    """Largest k a query may ask for."""
    log_level: str = "info"
    """uvicorn log level."""

    @classmethod
    def from_env(cls, **overrides) -> ServerSettings:
        """Defaults, then SEMANTICXR_<FIELD> environment variables, then non-None overrides."""
        values = {}
        for f in dataclasses.fields(cls):
            env = os.environ.get(f"SEMANTICXR_{f.name.upper()}")
            if env is not None:
                values[f.name] = env if f.type in ("str", "str | None") else int(env)
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)
