"""The port check the commands that listen share: a taken port is one clear line and exit
status 2 (naming the flag that picks another), not a traceback from deep in the server."""

from __future__ import annotations

import socket
import sys


def port_in_use(host: str, port: int) -> bool:
    """True if a listener already holds `port` on `host` (port 0, any free port, never is).

    Binds as the servers do (SO_REUSEADDR, so a port left in TIME_WAIT by a stopped server
    counts as free); the port could still be taken between this check and the real bind."""
    if port == 0:
        return False
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError:
            return True
    return False


def busy_port_message(command: str, port: int, flag: str = "--port") -> str:
    return f"semanticxr {command}: port {port} is in use; pass {flag} with a free port"


def check_ports(command: str, *ports: tuple[str, int, str]) -> bool:
    """Print one line to stderr for the first (host, port, flag) in use; False if one is."""
    for host, port, flag in ports:
        if port_in_use(host, port):
            print(busy_port_message(command, port, flag), file=sys.stderr)
            return False
    return True
