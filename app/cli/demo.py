"""`semanticxr demo`: the whole system on the embedded default, in one command.

Starts the server (in process), an emulated device that streams a synthetic apartment
through a loopback network emulator, the viser viewer when it can, asks a few queries (the
server answers while the link is good), cuts the network and shows the device's local map
still answering, restores it and checks the device caught up with no update lost, then
prints where to look and keeps serving until Ctrl-C (or exits with --exit).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import sys
import tempfile
import time
from typing import Any

from app.cli.common import scene_name
from app.flags import positive_int

DEFAULT_QUERIES = (
    "something to sit on",
    "where can I wash the dishes?",
    "the fridge",
    "where can I make coffee?",
)


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    demo = subparsers.add_parser(
        "demo",
        help="run server + emulated device + viewer on a synthetic apartment, with a network drop",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    demo.add_argument(
        "--scene", default="apartment", type=scene_name, help="synthetic scene (default apartment)"
    )
    demo.add_argument(
        "--frames",
        type=positive_int,
        default=300,
        help="frames of the walk to stream (default: %(default)s)",
    )
    demo.add_argument(
        "--port",
        type=int,
        default=8000,
        help="server port, 0 for any free port (default: %(default)s)",
    )
    demo.add_argument(
        "--viewer-port", type=int, default=8080, help="viser viewer port (default: %(default)s)"
    )
    demo.add_argument("--no-viewer", action="store_true", help="do not start the 3D viewer")
    demo.add_argument("--data-dir", help="server data folder (default: a temporary folder)")
    demo.add_argument(
        "--query",
        action="append",
        help="query to ask (repeatable; default: the demo's own queries)",
    )
    demo.add_argument("--exit", action="store_true", help="exit after the scripted run")
    demo.set_defaults(func=run)
    return demo


class _Console:
    """The demo's output: a live progress line on a terminal (redrawn in place, cleared before
    any other line), one progress line per update when stdout is a file or a pipe (a log
    gets readable lines, never one long line of carriage returns)."""

    def __init__(self) -> None:
        self.live = False  # a progress line is on screen, unterminated

    @property
    def tty(self) -> bool:
        isatty = getattr(sys.stdout, "isatty", None)
        return bool(isatty and isatty())

    def say(self, message: str) -> None:
        self._clear()
        print(message, flush=True)

    def progress(self, line: str) -> None:
        if self.tty:
            sys.stdout.write(f"\r\x1b[K{line}")
            sys.stdout.flush()
            self.live = True
        else:
            print(line, flush=True)

    def _clear(self) -> None:
        if self.live:
            sys.stdout.write("\r\x1b[K")
            self.live = False


_console = _Console()
PROGRESS_TTY_S = 0.5
"""How often the live line is redrawn on a terminal."""
PROGRESS_LOG_S = 2.0
"""How often a progress line is written when stdout is not a terminal."""


def _say(message: str) -> None:
    _console.say(message)


async def _report_progress(device, total: int, t0: float) -> None:
    """Until cancelled: the walk's progress, every PROGRESS_TTY_S on a terminal and every
    PROGRESS_LOG_S otherwise (so the demo never goes quiet while it streams)."""
    while True:
        s = device.stats
        elapsed_s = max(time.perf_counter() - t0, 1e-3)
        sent = s.bytes_up_by_kind["total"]
        rtt = f"{device.rtt_ms:.0f} ms" if device.rtt_ms is not None else "?"
        _console.progress(
            f"  frames {s.frames_sent}/{total}  up {8 * sent / elapsed_s / 1e6:.1f} Mbps at "
            f"{s.frames_sent / elapsed_s:.1f} fps ({sent / max(s.frames_sent, 1) / 1e3:.0f}"
            f" kB/frame)  objects held {len(device.local_map)}  RTT {rtt}"
        )
        await asyncio.sleep(PROGRESS_TTY_S if _console.tty else PROGRESS_LOG_S)


async def _stream_with_progress(device, source, *, start: int, limit: int, t0: float) -> None:
    """Stream source frames start .. limit - 1 of the walk, reporting progress meanwhile."""
    reporter = asyncio.create_task(_report_progress(device, len(source), t0))
    try:
        await device.stream(source, fps=None, start=start, limit=limit)
    finally:
        reporter.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reporter
    _say(f"  frames {device.stats.frames_sent}/{len(source)} sent")


def _show(answer) -> None:
    top = ", ".join(f"{r['label']} ({r['relevance']:.2f})" for r in answer.results[:3]) or "nothing"
    if answer.results and not answer.match:
        top = f"no confident match (nearest: {top})"
    _say(
        f"  [{answer.mode}] {answer.text!r}: {top}   {answer.latency_ms:.1f} ms  ({answer.reason})"
    )


async def _scripted(args: argparse.Namespace, server_url: str, encoder) -> dict:
    from app.client import SessionApi, create_session
    from app.config import Knobs
    from client_sim.netem import NetemProxy
    from client_sim.querying import QueryRouter
    from client_sim.sources.synthetic import SyntheticSource
    from client_sim.streaming import DeviceClient

    port = int(server_url.rsplit(":", 1)[1])
    proxy = NetemProxy("127.0.0.1", port)
    proxy.start()
    device_url = proxy.url()
    sid, token, _ = await create_session(server_url, name="demo")
    api = SessionApi(server_url, sid, token)
    _say(f"session {sid} created; the device reaches the server through {device_url}")

    viewer = None
    if not args.no_viewer:
        try:
            from viewer.app import ViewerApp

            viewer = ViewerApp(server_url, sid, token, port=args.viewer_port)
            viewer.start()
            _say(f"3D viewer on {viewer.url}")
        except Exception as exc:  # the demo goes on without a viewer
            _say(f"(no 3D viewer: {exc})")

    _say(
        f"ready: dashboard {server_url}/"
        + (f"   3D viewer {viewer.url}" if viewer is not None else "")
        + "   (the map grows there as the device walks)"
    )
    device = DeviceClient(
        device_url, sid, token, knobs=Knobs(), on_log=lambda m: _say(f"  device: {m}")
    )
    follower = asyncio.create_task(device.follow_updates())
    source = SyntheticSource(args.scene, n_frames=args.frames)
    _say(f"streaming {args.frames} frames of a synthetic {args.scene} (640x480, depth ÷5)...")
    t0 = time.perf_counter()
    first_part = max(1, int(args.frames * 0.8))
    await _stream_with_progress(device, source, start=0, limit=first_part, t0=t0)
    server_seq = (await api.fetch())["update_seq"]
    await device.wait_synced(server_seq, timeout_s=15)
    _say(
        f"mapped: the device holds {len(device.local_map)} objects, "
        f"{device.local_map.memory_bytes() / 1e6:.2f} MB"
    )

    queries = args.query or list(DEFAULT_QUERIES)
    router = QueryRouter(
        device_url,
        sid,
        token,
        device.local_map,
        encoder,
        threshold_ms=Knobs().net_latency_switch_threshold_ms,
        rtt_ms=lambda: device.rtt_ms,
    )
    _say("queries with a good network (server query, SQ):")
    for text in queries:
        _show(await router.query(text))

    _say("network drop! (the emulator cuts the link)")
    proxy.cut()
    for text in queries:
        _show(await router.query(text))

    _say(
        f"network back; the device resumes its updates from its last one and continues its walk"
        f" at frame {first_part}"
    )
    proxy.restore()
    await _stream_with_progress(device, source, start=first_part, limit=args.frames, t0=t0)
    session = await api.fetch()
    server_seq = session["update_seq"]
    _say(f"waiting for the device to apply the server's updates up to {server_seq}...")
    synced = await device.wait_synced(server_seq, timeout_s=20)
    objects = await api.objects()
    server_map = {o["id"]: o["version"] for o in objects}
    local = {oid: version for oid, (version, _label) in device.local_map.snapshot().items()}
    same = synced and local == server_map
    resumed = [s for s in device.subscriptions if s]
    _say(
        f"caught up: {'yes' if same else 'NO'} — {len(local)} objects locally, "
        f"{len(server_map)} on the server; resumed with since={resumed[-1] if resumed else None}"
    )
    walked = session["frames"] == args.frames
    _say(
        f"walk continued: {'yes' if walked else 'NO'} — the server counted {session['frames']}"
        f" frames of the {args.frames}-frame walk"
    )
    _say("queries again (SQ):")
    for text in queries[:2]:
        _show(await router.query(text))

    await router.aclose()
    await api.aclose()
    await device.stop()
    follower.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await follower  # lets the updates socket close cleanly before the loop ends
    proxy.stop()
    return {"session_id": sid, "token": token, "viewer": viewer, "in_sync": same and walked}


def run(args: argparse.Namespace) -> int:
    from app.cli.ports import check_ports

    ports = [("127.0.0.1", args.port, "--port")]
    if not args.no_viewer:
        ports.append(("127.0.0.1", args.viewer_port, "--viewer-port (or --no-viewer)"))
    if not check_ports("demo", *ports):
        return 2
    if not _console.tty:  # the model loader's bar would be one long \r line in a log
        os.environ.setdefault("HF_HUB_DISABLE_PROGRESS_BARS", "1")
    from app.semantics import get_text_encoder
    from app.server.runner import ServerThread
    from app.server.settings import ServerSettings

    encoder = get_text_encoder()
    with contextlib.ExitStack() as stack:
        data_dir = args.data_dir or stack.enter_context(tempfile.TemporaryDirectory())
        settings = ServerSettings(host="127.0.0.1", port=args.port, data_dir=data_dir)
        server = ServerThread(settings, encoder).start()
        stack.callback(server.stop)
        _say(f"SemanticXR server on {server.url} (data in {data_dir})")
        outcome = asyncio.run(_scripted(args, server.url, encoder))
        _say("")
        _say(f"dashboard: {server.url}/   API docs: {server.url}/docs")
        if outcome["viewer"] is not None:
            _say(f"3D viewer: {outcome['viewer'].url}")
        _say(
            f"curl '{server.url}/v1/sessions/{outcome['session_id']}/query?text=keys&k=3&points=false'"
        )
        if not args.exit:
            _say("serving until Ctrl-C")
            with contextlib.suppress(KeyboardInterrupt):
                while True:
                    time.sleep(3600)
        if outcome["viewer"] is not None:
            with contextlib.suppress(Exception):
                outcome["viewer"].stop()
    return 0 if outcome["in_sync"] else 1
