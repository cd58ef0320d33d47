"""The network emulator: a loopback proxy with latency, jitter and outages.

Everything goes through a real echo server on loopback. Timing assertions are lower
bounds only (a loaded machine can make things slower, never faster); waits are on
conditions with timeouts.
"""

from __future__ import annotations

import os
import select
import signal
import socket
import socketserver
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from client_sim.netem import NetemProxy, main

pytestmark = pytest.mark.timeout(30)

REPO_ROOT = Path(__file__).resolve().parents[2]
IO_TIMEOUT_S = 10.0


class _Echo(socketserver.BaseRequestHandler):
    def handle(self) -> None:
        while data := self.request.recv(65536):
            self.request.sendall(data)


@pytest.fixture
def echo_port() -> Iterator[int]:
    """Port of a threaded TCP echo server on 127.0.0.1."""
    server = socketserver.ThreadingTCPServer(("127.0.0.1", 0), _Echo)
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, args=(0.02,), daemon=True)
    thread.start()
    yield server.server_address[1]
    server.shutdown()
    server.server_close()


@pytest.fixture
def proxy_for(echo_port) -> Iterator[Callable[..., NetemProxy]]:
    """proxy_for(**kwargs): a started NetemProxy in front of the echo server."""
    proxies = []

    def start(**kwargs) -> NetemProxy:
        proxy = NetemProxy("127.0.0.1", echo_port, **kwargs)
        proxy.start()
        proxies.append(proxy)
        return proxy

    yield start
    for proxy in proxies:
        proxy.stop()


def connect(proxy: NetemProxy) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", proxy.port), timeout=IO_TIMEOUT_S)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def receive_exactly(sock: socket.socket, n_bytes: int) -> bytes:
    parts, received = [], 0
    while received < n_bytes:
        part = sock.recv(min(1 << 20, n_bytes - received))
        if not part:
            raise ConnectionError(f"closed after {received} of {n_bytes} bytes")
        parts.append(part)
        received += len(part)
    return b"".join(parts)


def echo(sock: socket.socket, payload: bytes) -> bytes:
    """Send `payload` (from a thread, so big payloads cannot deadlock) and read it back."""
    sender = threading.Thread(target=sock.sendall, args=(payload,), daemon=True)
    sender.start()
    received = receive_exactly(sock, len(payload))
    sender.join(IO_TIMEOUT_S)
    return received


def round_trip_s(sock: socket.socket) -> float:
    start = time.perf_counter()
    assert echo(sock, b"p") == b"p"
    return time.perf_counter() - start


def is_closed_by_peer(sock: socket.socket) -> bool:
    """True once the peer closed or reset `sock` (waits up to IO_TIMEOUT_S for it)."""
    try:
        return sock.recv(1) == b""
    except ConnectionError:
        return True


def wait_until(condition: Callable[[], bool], timeout_s: float = IO_TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        time.sleep(0.005)


def test_bytes_pass_through_intact_and_are_counted(proxy_for):
    proxy = proxy_for()
    payload = os.urandom(6 * 1024 * 1024 + 17)  # several buffers' worth: exercises backpressure
    with connect(proxy) as sock:
        assert echo(sock, b"hello") == b"hello"
        assert echo(sock, payload) == payload
    assert proxy.bytes_up == proxy.bytes_down == len(payload) + 5


def test_latency_shows_in_the_round_trip_and_can_be_changed_live(proxy_for):
    proxy = proxy_for(latency_ms=40)
    with connect(proxy) as sock:
        assert min(round_trip_s(sock) for _ in range(3)) >= 2 * 0.040 * 0.9
        proxy.set_latency(90)
        assert min(round_trip_s(sock) for _ in range(2)) >= 2 * 0.090 * 0.9


def test_jitter_never_reorders_the_stream(proxy_for):
    proxy = proxy_for(latency_ms=5, jitter_ms=5, seed=3)
    messages = [f"<{i:04d}>".encode() for i in range(300)]
    with connect(proxy) as sock:
        for message in messages:  # separate small writes, so many separately delayed chunks
            sock.sendall(message)
        assert receive_exactly(sock, sum(map(len, messages))) == b"".join(messages)


def test_cut_drops_live_connections_and_closes_new_ones_at_once(proxy_for):
    proxy = proxy_for()
    with connect(proxy) as live:
        assert echo(live, b"before") == b"before"
        proxy.cut()
        assert proxy.is_cut
        assert is_closed_by_peer(live)
    assert proxy.active_connections == 0
    try:
        fresh = connect(proxy)
    except ConnectionRefusedError:
        return
    with fresh:
        assert is_closed_by_peer(fresh)


def test_restore_lets_new_connections_through(proxy_for):
    proxy = proxy_for(latency_ms=10)
    proxy.cut()
    proxy.restore()
    assert not proxy.is_cut
    with connect(proxy) as sock:
        assert echo(sock, b"after the outage") == b"after the outage"


def test_connections_beyond_the_limit_are_closed(proxy_for):
    proxy = proxy_for(max_connections=2)
    with connect(proxy) as first, connect(proxy) as second:
        assert echo(first, b"1") == b"1" and echo(second, b"2") == b"2"
        wait_until(lambda: proxy.active_connections == 2)
        with connect(proxy) as third:
            assert is_closed_by_peer(third)
        assert echo(first, b"still up") == b"still up"
    wait_until(lambda: proxy.active_connections == 0)


def test_a_closed_connection_is_released(proxy_for):
    proxy = proxy_for()
    with connect(proxy) as sock:
        assert echo(sock, b"x") == b"x"
        sock.shutdown(socket.SHUT_WR)
        assert is_closed_by_peer(sock)  # the half-close reached the server and back
    wait_until(lambda: proxy.active_connections == 0)


def test_start_on_a_busy_port_raises_the_bind_error(proxy_for):
    busy = proxy_for()
    with pytest.raises(OSError):
        NetemProxy("127.0.0.1", busy.target_port, listen_port=busy.port).start()


@pytest.mark.parametrize("host", ["10.0.0.1", "192.168.1.20", "example.com", "0.0.0.0", "::"])
def test_only_loopback_targets_are_allowed(host):
    with pytest.raises(ValueError, match="loopback"):
        NetemProxy(host, 80)


def test_only_loopback_listen_addresses_are_allowed():
    with pytest.raises(ValueError, match="loopback"):
        NetemProxy("127.0.0.1", 80, listen_host="0.0.0.0")


def test_cli_refuses_a_non_loopback_target(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--target", "8.8.8.8:53"])
    assert exit_info.value.code == 2
    assert "loopback" in capsys.readouterr().err


def _ctrl_c_as_from_a_terminal() -> None:
    """In the CLI's child process: SIGINT at its default, as a shell's foreground job has it.
    A suite started in the background of a non-interactive shell (`make test &`) runs with
    SIGINT ignored, every child inherits that, and a Python started so never raises
    KeyboardInterrupt: the Ctrl-C below would then never arrive."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_cli_proxies_and_takes_commands_on_stdin(echo_port):
    command = [sys.executable, "-m", "client_sim.netem", "--target", f"127.0.0.1:{echo_port}"]
    with subprocess.Popen(
        [*command, "--latency-ms", "20"],
        cwd=REPO_ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        preexec_fn=_ctrl_c_as_from_a_terminal,
    ) as process:

        def read_line() -> str:
            ready, _, _ = select.select([process.stdout], [], [], IO_TIMEOUT_S)
            assert ready, "the CLI printed nothing"
            return process.stdout.readline()

        try:
            banner = read_line()
            assert banner.startswith("netem listening on tcp://127.0.0.1:")
            port = int(banner.split()[3].rsplit(":", 1)[1])
            with socket.create_connection(("127.0.0.1", port), timeout=IO_TIMEOUT_S) as sock:
                assert echo(sock, b"via cli") == b"via cli"
                process.stdin.write("cut\n")
                process.stdin.flush()
                assert "cut=True" in read_line()
                assert is_closed_by_peer(sock)
            process.send_signal(signal.SIGINT)  # Ctrl-C: a clean exit
            assert process.wait(IO_TIMEOUT_S) == 0
        finally:
            if process.poll() is None:
                process.kill()
