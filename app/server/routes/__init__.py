"""REST and WebSocket routes, one module per area; thin shells over SessionManager."""
