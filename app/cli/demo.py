"""`semanticxr demo`: the whole system on the embedded default, in one command.

Starts the server (in process), an emulated device that streams a synthetic apartment
through a loopback network emulator, the viser viewer when it can, asks a few queries (the
server answers while the link is good), cuts the network and shows the device's local map
still answering, restores it and checks the device caught up with no update lost. Then the
living map: while you were out someone moved a thing and took another away (a scripted second
visit); the device walks the same path again, and "where is the <thing>?" follows it, on the
server and in the device's local map (--no-revisit skips this). Last it prints where to look
and keeps serving until Ctrl-C (or exits with --exit).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from app.cli.common import frames_words, scene_name
from app.flags import positive_int

if TYPE_CHECKING:
    from world.changes import GroundTruthChange

DEFAULT_QUERIES = (
    "something to sit on",
    "where can I wash the dishes?",
    "the fridge",
    "where can I make coffee?",
)
FOLLOWED_WITHIN_M = 0.5
"""The moved thing's answer followed it when its top hit lies this close to where the script
put it."""
LOCAL_AGREES_WITHIN_M = 0.1
"""The local map answers the same when it holds the server's top hit this close (it keeps
fewer points per object, so its centroid differs by a few centimetres)."""
LOCAL_RANKS = 5
"""How many of the local map's best hits are searched for the server's answer."""
SYNC_TIMEOUT_S = 20.0
"""Longest wait for the device to apply the server's updates after a walk."""


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
        help="frames of the walk to stream; the second visit walks them again "
        "(default: %(default)s)",
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
    demo.add_argument(
        "--no-revisit",
        action="store_true",
        help="skip the living-map step (a thing moved, the walk again: about --frames more "
        "frames and a few seconds of scripting)",
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


async def _stream_with_progress(
    device, source, *, start: int, limit: int, total: int, t0: float
) -> None:
    """Stream source frames start .. limit - 1, reporting progress (frames sent of `total`)
    meanwhile."""
    reporter = asyncio.create_task(_report_progress(device, total, t0))
    try:
        await device.stream(source, fps=None, start=start, limit=limit)
    finally:
        reporter.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reporter
    _say(f"  frames {device.stats.frames_sent}/{total} sent")


def _show(answer) -> None:
    top = ", ".join(f"{r['label']} ({r['relevance']:.2f})" for r in answer.results[:3]) or "nothing"
    if answer.results and not answer.match:
        top = f"no confident match (nearest: {top})"
    _say(
        f"  [{answer.mode}] {answer.text!r}: {top}   {answer.latency_ms:.1f} ms  ({answer.reason})"
    )


@dataclass(frozen=True)
class _Shown:
    """The scripted changes the living-map step tells about and asks after."""

    moved: GroundTruthChange
    """The moved thing it asks "where is" about."""
    removed: GroundTruthChange | None
    """A removed thing it asks "where did I last see" about."""


def _pick_shown(scenario) -> _Shown | None:
    """The moved (and removed) thing to show: one whose label the scene holds the fewest of
    (so "where is the kettle?" means it), the smallest first; None when nothing moved."""

    def key(change) -> tuple[int, float, int]:
        same = sum(o.category == change.category for o in scenario.before.objects)
        lo_hi = scenario.before.object_by_id(change.instance_id).bbox
        volume = float((lo_hi[3:] - lo_hi[:3]).prod())
        return same, volume, change.instance_id

    moved = sorted((c for c in scenario.changes if c.kind == "moved"), key=key)
    removed = sorted((c for c in scenario.changes if c.kind == "removed"), key=key)
    if not moved:
        return None
    return _Shown(moved[0], removed[0] if removed else None)


def _where_words(scene, instance_id: int) -> tuple[str, str]:
    """Where the script put a thing, from the scene: ("the kitchen counter", "the kitchen")."""
    thing = scene.object_by_id(instance_id)
    on = scene.object_by_id(thing.support_id).category if thing.support_id else "floor"
    room = scene.rooms[thing.room].type.replace("_", " ") if thing.room >= 0 else "apartment"
    return f"the {on}", f"the {room}"


def _move_words(scenario, instance_id: int) -> str:
    """ "from the kitchen counter to the dining table, in the kitchen" (the script's truth)."""
    (old, old_room), (new, new_room) = (
        _where_words(scenario.before, instance_id),
        _where_words(scenario.after, instance_id),
    )
    if (old, old_room) == (new, new_room):
        return f"elsewhere on {new}, in {new_room}"
    if old_room == new_room:
        return f"from {old} to {new}, in {new_room}"
    return f"from {old} in {old_room} to {new} in {new_room}"


def _hit_words(hit: dict, now_t: float | None) -> str:
    """A query hit in words: "kettle #80 on the dining table (0.93), last seen 10 min ago"."""
    from app.cli.sessions import ago_words

    words = f"{hit['label']} #{hit['id']}"
    if hit.get("state") == "removed":
        words += " (removed)"
    place = hit.get("place")
    if isinstance(place, dict):
        words += f" {place['relation']} the {place['label']}"
    words += f" ({hit['relevance']:.2f})"
    if now_t is not None and hit.get("last_seen_t") is not None:
        words += f", last seen {ago_words(now_t - hit['last_seen_t'])}"
    return words


def _distance_m(a, b) -> float:
    return sum((float(x) - float(y)) ** 2 for x, y in zip(a, b, strict=True)) ** 0.5


async def _caught_up(api, device, timeout_s: float = SYNC_TIMEOUT_S) -> tuple[bool, str]:
    """Wait for the device to apply the server's newest update; (its map equals the server's,
    "N objects locally, M on the server" and the first differences).

    The server may still commit after the walk (a closed stream settles its map), so a
    difference read together with a newer server seq is waited out, not reported."""
    deadline = time.monotonic() + timeout_s
    waited_for = -1
    while True:
        server_seq = (await api.fetch()).update_seq
        if server_seq != waited_for:
            _say(f"waiting for the device to apply the server's updates up to {server_seq}...")
        remaining = max(0.0, deadline - time.monotonic())
        synced = await device.wait_synced(server_seq, timeout_s=remaining)
        server_map = {o["id"]: o["version"] for o in await api.objects()}
        local = {oid: version for oid, (version, _label) in device.local_map.snapshot().items()}
        differ = sorted(
            oid for oid in local.keys() | server_map.keys() if local.get(oid) != server_map.get(oid)
        )
        newer = (await api.fetch()).update_seq > server_seq  # committed while we compared
        if not (synced and differ and newer) or time.monotonic() >= deadline:
            break
        waited_for = server_seq
    words = f"{len(local)} objects locally, {len(server_map)} on the server"
    if not synced:
        words += f" (the device's updates stopped at {device.local_map.seq} of {server_seq})"
    if differ:
        shown = ", ".join(
            f"#{oid} version {local.get(oid, '-')} locally, {server_map.get(oid, '-')} on the server"
            for oid in differ[:3]
        )
        verb = "differs" if len(differ) == 1 else "differ"
        words += f"; {len(differ)} {verb}: {shown}" + (", ..." if len(differ) > 3 else "")
    return synced and not differ, words


async def _local_words(device, encoder, question: str, server_hit: dict) -> str:
    """Whether the device's local map (fed by deltas) answers `question` with the server's
    top hit at the same place: "yes — [LQ] kettle #10 (rank 1), 0.01 m from ...". Its
    ranking among like-labelled things may differ from the server's (equal scores, int8
    embeddings), so the server's hit is looked for among its best LOCAL_RANKS."""
    embedding = await asyncio.to_thread(encoder.encode_query, question)
    local = device.local_map.query_embedding(embedding, LOCAL_RANKS)
    mine = next((hit for hit in local if hit.id == server_hit["id"]), None)
    if mine is None:
        best = f"{local[0].label} #{local[0].id}" if local else "nothing"
        return f"NO — [LQ] {best}; #{server_hit['id']} is not among its best {LOCAL_RANKS}"
    apart_m = _distance_m(mine.centroid, server_hit["centroid"])
    agrees = apart_m <= LOCAL_AGREES_WITHIN_M
    return (
        f"{'yes' if agrees else 'NO'} — [LQ] {mine.label} #{mine.id} (rank "
        f"{local.index(mine) + 1}), {apart_m:.2f} m from the server's answer"
    )


async def _living_map_step(api, device, encoder, source, shown: _Shown, t0: float) -> bool:
    """Tell what the script changed, ask where the moved thing is, walk the same path again,
    list the changes the server concluded, and ask again (server and local map) and after the
    removed thing; whether the device caught up. Whether the answer followed the thing is
    said, not returned: how well the map follows is the eval's to measure."""
    from app.cli.sessions import change_words

    scenario = source.scenario
    moved, removed = shown.moved, shown.removed
    thing = moved.category
    away = f" and took the {removed.category} away" if removed is not None else ""
    _say(
        f"while you were out, someone moved the {thing} "
        f"({_move_words(scenario, moved.instance_id)}){away}; "
        f"{scenario.gap_s / 60:g} minutes later you walk the same path again"
    )
    question = f"where is the {thing}?"
    answer = await api.query_result(question, k=3)
    before = answer["results"][0] if answer["results"] else None
    top = _hit_words(before, answer["now_t"]) if before else "nothing"
    _say(f"  [SQ] {question!r}: {top}")

    walk1 = scenario.walk1_frames
    _say(
        f"walking the same path again: frames {walk1}..{len(source) - 1}, "
        f"the device clock {scenario.gap_s:g} s later..."
    )
    await _stream_with_progress(
        device, source, start=walk1, limit=len(source), total=len(source), t0=t0
    )
    same, counts = await _caught_up(api, device)
    _say(f"caught up: {'yes' if same else 'NO'} — {counts}")

    listing = await api.changes()
    now_t = listing.get("now_t")
    walk2_start_t = scenario.walk2_start_t
    second = [c for c in listing["changes"] if c["t"] >= walk2_start_t]
    earlier = len(listing["changes"]) - len(second)
    _say(
        f"the script made {len(scenario.changes)} changes; the map concluded {len(second)} on "
        "the second walk"
        + (f" ({earlier} more on the first)" if earlier else "")
        + " (GET .../changes):"
    )
    for change in second:
        _say(f"  #{change['id']} {change_words(change, now_t)}")

    answer = await api.query_result(question, k=3)
    after = answer["results"][0] if answer["results"] else None
    _say(f"  [SQ] {question!r}: {_hit_words(after, answer['now_t']) if after else 'nothing'}")
    if after is None:
        _say(f"the {thing}'s answer followed it: NO — the server found nothing")
    else:
        off_m = _distance_m(after["centroid"], moved.to_xyz)
        followed = off_m <= FOLLOWED_WITHIN_M
        same_id = before is not None and after["id"] == before["id"]
        _say(
            f"the {thing}'s answer followed it: {'yes' if followed else 'NO'} — "
            f"{'the same id' if same_id else 'another id'} #{after['id']}, {off_m:.2f} m from "
            f"where the script put it"
            + (
                ""
                if followed
                else f" (more than {FOLLOWED_WITHIN_M} m: the map has not followed "
                "this one; `semanticxr eval --scenario revisit` measures how often it does)"
            )
        )
        words = await _local_words(device, encoder, question, after)
        _say(f"  the device's local map answers the same: {words}")

    if removed is not None:
        question = f"where did I last see the {removed.category}?"
        answer = await api.query_result(question, k=3, include="removed")
        hits = answer["results"]
        top = _hit_words(hits[0], answer["now_t"]) if hits else "nothing"
        _say(f"  [SQ include=removed] {question!r}: {top}")
        gone = next((h for h in hits[1:] if h["state"] == "removed"), None)
        if hits and hits[0]["state"] != "removed" and gone is not None:
            _say(f"    and the removed one: {_hit_words(gone, answer['now_t'])}")
    return same


async def _scripted(args: argparse.Namespace, server_url: str, encoder) -> dict:
    from app.client import SessionApi, create_session
    from app.config import Knobs
    from client_sim.netem import NetemProxy
    from client_sim.querying import QueryRouter
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
    source, shown = _walk_source(args)
    _say(f"streaming {args.frames} frames of a synthetic {args.scene} (640x480, depth ÷5)...")
    t0 = time.perf_counter()
    first_part = max(1, int(args.frames * 0.8))
    await _stream_with_progress(device, source, start=0, limit=first_part, total=args.frames, t0=t0)
    server_seq = (await api.fetch()).update_seq
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
    await _stream_with_progress(
        device, source, start=first_part, limit=args.frames, total=args.frames, t0=t0
    )
    same, counts = await _caught_up(api, device)
    session = await api.fetch()
    resumed = [s for s in device.subscriptions if s]
    _say(
        f"caught up: {'yes' if same else 'NO'} — {counts}; "
        f"resumed with since={resumed[-1] if resumed else None}"
    )
    walked = session.frames == args.frames
    _say(
        f"walk continued: {'yes' if walked else 'NO'} — the server counted"
        f" {frames_words(session)} of the {args.frames}-frame walk"
    )
    _say("queries again (SQ):")
    for text in queries[:2]:
        _show(await router.query(text))

    revisited = None  # the device caught up after the second walk (None: no second walk)
    if shown is not None:
        revisited = await _living_map_step(api, device, encoder, source, shown, t0)

    await router.aclose()
    await api.aclose()
    await device.stop()
    follower.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await follower  # lets the updates socket close cleanly before the loop ends
    proxy.stop()
    return {
        "session_id": sid,
        "token": token,
        "viewer": viewer,
        "in_sync": same and walked and revisited is not False,
        "revisited": revisited is not None,
    }


def _walk_source(args: argparse.Namespace):
    """(the frame source, the changes to show or None): walk 1 of a scripted revisit, or
    with --no-revisit the same frames without the script (SyntheticSource at the revisit's
    frame rate renders them identically)."""
    from client_sim.sources.revisit import RevisitSource
    from client_sim.sources.synthetic import SyntheticSource
    from world.changes import REVISIT_FPS

    if args.no_revisit:
        return SyntheticSource(args.scene, n_frames=args.frames, fps=REVISIT_FPS), None
    _say(
        f"scripting a second visit to the {args.scene}: what someone changes while you are out "
        "(a few seconds)..."
    )
    start_s = time.perf_counter()
    source = RevisitSource(args.scene, walk_frames=args.frames)
    changes = source.scenario.changes
    kinds = ", ".join(
        f"{sum(c.kind == kind for c in changes)} {kind}" for kind in ("moved", "removed", "added")
    )
    _say(f"  scripted {len(changes)} changes ({kinds}) in {time.perf_counter() - start_s:.1f} s")
    shown = _pick_shown(source.scenario)
    if shown is None:
        _say(
            f"  nothing moved that a {args.frames}-frame walk sees well enough to show: the "
            "living-map step is skipped (a longer walk, e.g. the default --frames 300, shows it)"
        )
    return source, shown


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
        if outcome["revisited"]:
            _say(f"curl '{server.url}/v1/sessions/{outcome['session_id']}/changes'")
        if not args.exit:
            _say("serving until Ctrl-C")
            with contextlib.suppress(KeyboardInterrupt):
                while True:
                    time.sleep(3600)
        if outcome["viewer"] is not None:
            with contextlib.suppress(Exception):
                outcome["viewer"].stop()
    return 0 if outcome["in_sync"] else 1
