"""A loopback TCP proxy that emulates a bad network: latency, jitter and outages.

Put it between a client and the server (both on this machine) to see what a device sees
on a slow or broken link:

    proxy = NetemProxy("127.0.0.1", server_port, latency_ms=150, jitter_ms=20)
    proxy.start()
    client.connect(proxy.url("ws"))
    proxy.cut()        # outage: live connections drop, new ones are closed at once
    proxy.restore()    # the link is back
    proxy.stop()

or from a shell (commands on stdin: cut, restore, latency MS [JITTER_MS], stats, quit):

    python -m client_sim.netem --target 127.0.0.1:8000 --listen 127.0.0.1:8001 \\
        --latency-ms 150 --jitter-ms 20

Delay model: every chunk read from one side is written to the other side
latency + U(-jitter, +jitter) ms later (never negative), and never before the chunk read
before it, so a byte stream stays in order (TCP cannot reorder) and jitter shows up as
bunching. Each direction is delayed independently, so a request/response round trip takes
at least 2 x latency.

It only ever connects to loopback addresses: this is a test and benchmark tool, and
forwarding traffic to other machines is not something it should be able to do by accident.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import ipaddress
import random
import sys
import threading
from dataclasses import dataclass, field

CHUNK_BYTES = 64 * 1024
"""Largest chunk read from a socket at once: the unit the delay applies to."""
DEFAULT_MAX_CONNECTIONS = 64
DEFAULT_MAX_BUFFERED_BYTES = 1024 * 1024
"""Per connection and direction; a full buffer stops reading from the sender (backpressure),
so the proxy holds at most about 2 x max_connections x this much data."""
CONNECT_TIMEOUT_S = 5.0
CONTROL_TIMEOUT_S = 10.0
"""How long start/stop/cut wait for the proxy's event loop before giving up."""


def require_loopback(host: str, role: str) -> str:
    """`host` as a literal loopback IP ("localhost" -> "127.0.0.1"), else ValueError.

    Names other than "localhost" are refused without resolving them: a DNS answer could
    point anywhere.
    """
    literal = "127.0.0.1" if host == "localhost" else host.strip("[]")
    try:
        is_loopback = ipaddress.ip_address(literal).is_loopback
    except ValueError:
        is_loopback = False
    if not is_loopback:
        raise ValueError(
            f"netem {role} must be a loopback address (127.0.0.0/8, ::1 or localhost), "
            f"got {host!r}: this proxy never forwards traffic off this machine"
        )
    return literal


class _DelayLine:
    """One direction's in-flight chunks, bounded in bytes: [(due loop time s, chunk)].

    An empty chunk is the sender's end-of-stream, delivered in order like data.
    """

    def __init__(self, max_bytes: int):
        self.max_bytes = max_bytes
        self._chunks: collections.deque[tuple[float, bytes]] = collections.deque()
        self._bytes = 0
        self._changed = asyncio.Condition()

    async def put(self, due_s: float, chunk: bytes) -> None:
        async with self._changed:
            # An oversized chunk still goes through alone, or the line would deadlock.
            await self._changed.wait_for(
                lambda: not self._chunks or self._bytes + len(chunk) <= self.max_bytes
            )
            self._chunks.append((due_s, chunk))
            self._bytes += len(chunk)
            self._changed.notify_all()

    async def get(self) -> tuple[float, bytes]:
        async with self._changed:
            await self._changed.wait_for(lambda: bool(self._chunks))
            due_s, chunk = self._chunks.popleft()
            self._bytes -= len(chunk)
            self._changed.notify_all()
            return due_s, chunk


@dataclass(eq=False)
class _Link:
    """One proxied connection: the client's socket, the target's, and the task serving them."""

    client: asyncio.StreamWriter
    task: asyncio.Task | None = None
    target: asyncio.StreamWriter | None = None
    closed: bool = field(default=False)

    def abort(self) -> None:
        """Drop both sockets now (no flush, like a cable pulled) and stop the relay."""
        self.closed = True
        for writer in (self.client, self.target):
            if writer is not None:
                writer.transport.abort()
        if self.task is not None and self.task is not asyncio.current_task():
            self.task.cancel()


class NetemProxy:
    """A TCP proxy on loopback adding latency and jitter, with outages on demand.

    target_host/target_port: where connections are forwarded (loopback only).
    listen_host/listen_port: where the proxy listens (loopback only; port 0 = any free
    port, see `port` after `start()`). latency_ms/jitter_ms: one-way delay added to each
    direction, uniform in latency ± jitter. seed: seeds the jitter.
    max_connections: connections beyond this are closed at once.
    max_buffered_bytes: in-flight data per connection and direction before backpressure.

    Control methods (`start`, `stop`, `cut`, `restore`, `set_latency`) are called from any
    thread; the proxy runs its own asyncio loop in a background thread.
    """

    def __init__(
        self,
        target_host: str,
        target_port: int,
        listen_host: str = "127.0.0.1",
        listen_port: int = 0,
        latency_ms: float = 0.0,
        jitter_ms: float = 0.0,
        seed: int = 0,
        *,
        max_connections: int = DEFAULT_MAX_CONNECTIONS,
        max_buffered_bytes: int = DEFAULT_MAX_BUFFERED_BYTES,
    ):
        self.target_host = require_loopback(target_host, "target")
        self.listen_host = require_loopback(listen_host, "listen address")
        for name, port in (("target_port", target_port), ("listen_port", listen_port)):
            if not 0 <= port <= 65535 or (name == "target_port" and port == 0):
                raise ValueError(f"{name} must be a TCP port number, got {port!r}")
        if max_connections < 1 or max_buffered_bytes < 1:
            raise ValueError("max_connections and max_buffered_bytes must be positive")
        self.target_port = target_port
        self.max_connections = max_connections
        self.max_buffered_bytes = max_buffered_bytes
        self._port = listen_port
        self._delay_ms = (0.0, 0.0)
        self.set_latency(latency_ms, jitter_ms)
        self._random = random.Random(seed)
        self._cut = False
        self._bytes_up = 0
        self._bytes_down = 0
        self._links: set[_Link] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: asyncio.Server | None = None
        self._thread: threading.Thread | None = None
        self._stopping: asyncio.Event | None = None

    # --- public state ------------------------------------------------------------------

    @property
    def port(self) -> int:
        """The port the proxy listens on (resolved by `start()` if 0 was asked for)."""
        return self._port

    def url(self, scheme: str = "http") -> str:
        """e.g. "http://127.0.0.1:40123": the proxy's address for a client to connect to."""
        host = f"[{self.listen_host}]" if ":" in self.listen_host else self.listen_host
        return f"{scheme}://{host}:{self.port}"

    @property
    def is_cut(self) -> bool:
        """True during an outage (between `cut()` and `restore()`)."""
        return self._cut

    @property
    def bytes_up(self) -> int:
        """Bytes delivered client -> target so far."""
        return self._bytes_up

    @property
    def bytes_down(self) -> int:
        """Bytes delivered target -> client so far."""
        return self._bytes_down

    @property
    def active_connections(self) -> int:
        """Connections being relayed right now."""
        return len(self._links)

    @property
    def latency_ms(self) -> float:
        return self._delay_ms[0]

    @property
    def jitter_ms(self) -> float:
        return self._delay_ms[1]

    # --- control -----------------------------------------------------------------------

    def start(self) -> None:
        """Start listening (in a background thread); returns once connections are accepted."""
        if self._thread is not None:
            raise RuntimeError("proxy already started")
        ready = threading.Event()
        failure: list[BaseException] = []
        self._thread = threading.Thread(
            target=self._run, args=(ready, failure), name=f"netem:{self._port}", daemon=True
        )
        self._thread.start()
        if not ready.wait(CONTROL_TIMEOUT_S):
            raise RuntimeError("netem proxy did not start in time")
        if failure:
            self._thread.join(CONTROL_TIMEOUT_S)
            self._thread = None
            raise failure[0]

    def stop(self) -> None:
        """Close every connection and the listening socket; safe to call twice."""
        thread, loop = self._thread, self._loop
        if thread is None or loop is None or self._stopping is None:
            return
        if thread.is_alive():
            loop.call_soon_threadsafe(self._stopping.set)
            thread.join(CONTROL_TIMEOUT_S)
        self._thread = None

    def set_latency(self, latency_ms: float, jitter_ms: float = 0.0) -> None:
        """One-way delay for chunks read from now on: latency ± jitter ms (uniform)."""
        if not (latency_ms >= 0 and jitter_ms >= 0):
            raise ValueError(f"latency and jitter must be >= 0 ms, got {latency_ms}, {jitter_ms}")
        self._delay_ms = (float(latency_ms), float(jitter_ms))  # one assignment: thread-safe

    def cut(self) -> None:
        """Outage: drop every live connection; close new ones at once until `restore()`.

        Returns after the live connections are closed.
        """
        self._call_in_loop(self._cut_now)

    def restore(self) -> None:
        """End the outage: new connections are relayed again (dropped ones stay dropped)."""
        self._call_in_loop(self._restore_now)

    def __enter__(self) -> NetemProxy:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    # --- the event loop ----------------------------------------------------------------

    def _call_in_loop(self, function) -> None:
        """Run `function()` on the proxy's loop and wait for it (directly if not started)."""
        loop = self._loop
        if loop is None or self._thread is None or not self._thread.is_alive():
            function()
            return

        async def call() -> None:
            function()

        asyncio.run_coroutine_threadsafe(call(), loop).result(CONTROL_TIMEOUT_S)

    def _cut_now(self) -> None:
        self._cut = True
        for link in list(self._links):
            link.abort()
        self._links.clear()  # gone now, not when their cancelled tasks get round to it

    def _restore_now(self) -> None:
        self._cut = False

    def _run(self, ready: threading.Event, failure: list[BaseException]) -> None:
        try:
            asyncio.run(self._serve(ready))
        except BaseException as exc:  # reported to start(); the thread has nowhere else to say it
            failure.append(exc)
        finally:
            ready.set()

    async def _serve(self, ready: threading.Event) -> None:
        self._loop = asyncio.get_running_loop()
        self._stopping = asyncio.Event()
        self._server = await asyncio.start_server(
            self._relay, self.listen_host, self._port, limit=CHUNK_BYTES
        )
        self._port = self._server.sockets[0].getsockname()[1]
        ready.set()
        try:
            await self._stopping.wait()
        finally:
            self._server.close()
            for link in list(self._links):
                link.abort()
            await self._server.wait_closed()

    def _delay_s(self) -> float:
        latency_ms, jitter_ms = self._delay_ms
        jitter = self._random.uniform(-jitter_ms, jitter_ms) if jitter_ms else 0.0
        return max(0.0, latency_ms + jitter) / 1000.0

    async def _relay(
        self, client_reader: asyncio.StreamReader, client: asyncio.StreamWriter
    ) -> None:
        """Serve one accepted connection until either side closes or the link is cut."""
        if self._cut or len(self._links) >= self.max_connections:
            client.transport.abort()
            return
        link = _Link(client=client, task=asyncio.current_task())
        self._links.add(link)
        try:
            await self._connect_and_relay(link, client_reader)
            # Both directions ended (or one failed): flush what is buffered, then close.
            writers = [w for w in (link.client, link.target) if w is not None]
            for writer in writers:
                writer.close()
            await asyncio.wait_for(
                asyncio.gather(*(w.wait_closed() for w in writers), return_exceptions=True),
                CONTROL_TIMEOUT_S,
            )
        except asyncio.CancelledError:
            # cut() or stop() cancelled us on purpose; any other cancellation propagates.
            if not link.closed:
                raise
        except TimeoutError:
            pass  # a peer that stopped reading: the abort below drops its unsent bytes
        finally:
            link.abort()
            self._links.discard(link)

    async def _connect_and_relay(self, link: _Link, client_reader: asyncio.StreamReader) -> None:
        """Connect to the target and relay both directions until both have ended."""
        try:
            target_reader, link.target = await asyncio.wait_for(
                asyncio.open_connection(self.target_host, self.target_port, limit=CHUNK_BYTES),
                CONNECT_TIMEOUT_S,
            )
        except (OSError, TimeoutError):
            return  # target down: the client sees its connection close, as with a real server
        if link.closed:  # cut while connecting
            return
        try:
            async with asyncio.TaskGroup() as relay:
                relay.create_task(self._pipe(client_reader, link.target, upstream=True))
                relay.create_task(self._pipe(target_reader, link.client, upstream=False))
        except* OSError:
            pass  # a reset peer or a broken pipe ends this link and only this link

    async def _pipe(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, upstream: bool
    ) -> None:
        """Relay one direction through a delay line, then pass the end-of-stream on."""
        line = _DelayLine(self.max_buffered_bytes)
        loop = asyncio.get_running_loop()

        async def receive() -> None:
            last_due_s = 0.0
            while True:
                chunk = await reader.read(CHUNK_BYTES)
                # Never earlier than the previous chunk: jitter must not reorder a stream.
                last_due_s = max(loop.time() + self._delay_s(), last_due_s)
                await line.put(last_due_s, chunk)
                if not chunk:
                    return

        async def deliver() -> None:
            while True:
                due_s, chunk = await line.get()
                wait_s = due_s - loop.time()
                if wait_s > 0:
                    await asyncio.sleep(wait_s)
                if not chunk:
                    if writer.can_write_eof():
                        writer.write_eof()
                    return
                # Counted before the write so a reader that has the bytes sees them counted.
                if upstream:
                    self._bytes_up += len(chunk)
                else:
                    self._bytes_down += len(chunk)
                writer.write(chunk)
                await writer.drain()

        async with asyncio.TaskGroup() as direction:
            direction.create_task(receive())
            direction.create_task(deliver())


# --- command line ---------------------------------------------------------------------


def _host_port(text: str) -> tuple[str, int]:
    """("127.0.0.1", 8000) from "127.0.0.1:8000" (or "[::1]:8000"); argparse type."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or int(port) > 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host.strip("[]"), int(port)


def _handle_command(proxy: NetemProxy, line: str) -> bool:
    """Apply one stdin command; False when the user asked to quit."""
    words = line.split()
    if not words:
        return True
    command, arguments = words[0].lower(), words[1:]
    try:
        if command == "cut":
            proxy.cut()
        elif command == "restore":
            proxy.restore()
        elif command == "latency" and 1 <= len(arguments) <= 2:
            proxy.set_latency(*(float(a) for a in arguments))
        elif command in ("quit", "exit"):
            return False
        elif command != "stats":
            print("commands: cut | restore | latency MS [JITTER_MS] | stats | quit", flush=True)
            return True
    except ValueError as exc:
        print(f"error: {exc}", flush=True)
        return True
    print(
        f"cut={proxy.is_cut} latency={proxy.latency_ms:g}ms jitter={proxy.jitter_ms:g}ms "
        f"connections={proxy.active_connections} up={proxy.bytes_up}B down={proxy.bytes_down}B",
        flush=True,
    )
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m client_sim.netem",
        description="Loopback TCP proxy adding latency/jitter, with outages. Commands on "
        "stdin: cut, restore, latency MS [JITTER_MS], stats, quit. Ctrl-C stops it.",
    )
    parser.add_argument("--target", type=_host_port, required=True, help="HOST:PORT to forward to")
    parser.add_argument(
        "--listen", type=_host_port, default=("127.0.0.1", 0), help="HOST:PORT (default: any port)"
    )
    parser.add_argument("--latency-ms", type=float, default=0.0, help="one-way delay per direction")
    parser.add_argument("--jitter-ms", type=float, default=0.0, help="uniform ± on the delay")
    parser.add_argument("--seed", type=int, default=0, help="seed of the jitter")
    parser.add_argument("--max-connections", type=int, default=DEFAULT_MAX_CONNECTIONS)
    args = parser.parse_args(argv)
    try:
        proxy = NetemProxy(
            *args.target,
            *args.listen,
            latency_ms=args.latency_ms,
            jitter_ms=args.jitter_ms,
            seed=args.seed,
            max_connections=args.max_connections,
        )
    except ValueError as exc:
        parser.error(str(exc))
    proxy.start()
    target_host, target_port = args.target
    print(
        f"netem listening on {proxy.url('tcp')} -> {target_host}:{target_port} "
        f"(latency {proxy.latency_ms:g} ms ± {proxy.jitter_ms:g} ms)",
        flush=True,
    )
    try:
        for line in sys.stdin:
            if not _handle_command(proxy, line):
                return 0
        threading.Event().wait()  # stdin closed (e.g. run in the background): serve until Ctrl-C
    except KeyboardInterrupt:
        pass
    finally:
        proxy.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
