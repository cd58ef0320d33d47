"""The service: FastAPI app, sessions, persistence (SQLite store), REST and WebSocket routes."""
