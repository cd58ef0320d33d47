"""Map shards without Ray: two real servers on loopback with shard names over one PostgreSQL
store. A shard claims what it serves (owner, epoch), beats with its address, answers a
session another live shard holds with 503 naming that shard, lets its sessions go when it
stops, and drops a session claimed away from it without writing to it again. On any server,
a keyframe resent under the same stream id is answered from the store, not mapped twice.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import httpx
import msgpack
import pytest
import websockets
from analytic_world import Rect
from devices import frame_message, send_and_collect, stream_in_step

from app.cluster.gateway import create_gateway_app
from app.server.runner import ServerThread
from app.server.sessions import Session
from app.server.settings import ServerSettings
from app.store import Store, open_store

pytestmark = pytest.mark.timeout(120)

SCENE = [
    Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0),
    Rect(2, "refrigerator", 0.1, -0.8, 0.9, 0.8, 2.5),
]
LAMP = Rect(3, "lamp", -1.2, -0.9, -0.8, -0.4, 2.2)
KNOBS = {
    "keyframe_interval": 1,
    "min_observations": 2,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
}
LEASE_S = 2.0
"""The shards' lease (the least allowed is over 1.5 s: they renew every second)."""
WAIT_S = 10.0
"""Longest a condition polled here may take to hold."""
STREAM_HEADER = "x-semanticxr-stream"


def poll(condition: Callable[[], object], what: str, timeout_s: float = WAIT_S) -> object:
    """condition()'s first truthy value; AssertionError naming `what` past `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while not (value := condition()):
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout_s:g} s: {what}")
        time.sleep(0.01)  # a polling period, not synchronisation
    return value


def frames(first: int, n: int, scene: list[Rect] = SCENE) -> list[dict]:
    return [frame_message(scene, i, cam_xy=(0.02 * i, 0.0)) for i in range(first, first + n)]


def create(url: str, name: str = "home") -> str:
    answer = httpx.post(f"{url}/v1/sessions", json={"name": name, "knobs": KNOBS})
    assert answer.status_code == 201, answer.text
    return answer.json()["session_id"]


def objects(url: str, sid: str) -> list[dict]:
    answer = httpx.get(f"{url}/v1/sessions/{sid}/objects", params={"points": True})
    assert answer.status_code == 200, answer.text
    return answer.json()


def session_stats(url: str, sid: str) -> dict:
    answer = httpx.get(f"{url}/v1/sessions/{sid}")
    assert answer.status_code == 200, answer.text
    return answer.json()


def stored_map(store: Store, sid: str) -> tuple[int, int, list[tuple[int, int]]]:
    """What a keyframe's commit changes in the store: (update seq, keyframes, each present
    object's (id, version))."""
    return (
        store.load_delta_log(sid).seq,
        store.load_session(sid).keyframes,
        [(o.id, o.version) for o in store.load_objects(sid)],
    )


def stream_url(server: ServerThread, sid: str) -> str:
    return f"{server.ws_url}/v1/sessions/{sid}/stream"


# ---------------------------------------------------------------------- two shards, one store
@pytest.fixture
def store(fresh_pg_url: str) -> Iterator[Store]:
    with open_store(fresh_pg_url) as store:
        yield store


@pytest.fixture
def shards(fresh_pg_url, encoder, tmp_path) -> Iterator[dict[str, ServerThread]]:
    """Map shards shard-a and shard-b, each a real server on a loopback port, over one store."""
    started: dict[str, ServerThread] = {}
    try:
        for name in ("shard-a", "shard-b"):
            settings = ServerSettings(
                host="127.0.0.1",
                port=0,
                data_dir=str(tmp_path / name),
                store=fresh_pg_url,
                shard_name=name,
                shard_lease_s=LEASE_S,
            )
            started[name] = ServerThread(settings, encoder).start()
        yield started
    finally:
        for server in started.values():
            server.stop()


def test_a_session_made_on_a_shard_is_its_own_and_the_other_answers_503_naming_it(shards, store):
    a, b = shards["shard-a"], shards["shard-b"]
    sid = create(a.url)
    claimed = store.load_session(sid)
    assert (claimed.owner, claimed.epoch) == ("shard-a", 1)

    answer = httpx.get(f"{b.url}/v1/sessions/{sid}")
    assert answer.status_code == 503, answer.text
    assert answer.headers["Retry-After"] == "1"
    assert answer.headers["X-SemanticXR-Owner"] == "shard-a"
    after = store.load_session(sid)
    assert (after.owner, after.epoch) == ("shard-a", 1)  # B's try changed nothing
    assert session_stats(a.url, sid)["session_id"] == sid


def test_both_shards_beat_with_the_addresses_gateways_reach_them_at(shards, store):
    expected = {name: server.settings.shard_address for name, server in shards.items()}
    assert expected == {name: server.url for name, server in shards.items()}

    def listed() -> dict[str, str]:
        return {s.name: s.url for s in store.live_shards(LEASE_S)}

    poll(lambda: listed() == expected, f"both shards listed live as {expected}")
    beats = {s.name: s.heartbeat_at for s in store.live_shards(LEASE_S)}
    poll(
        lambda: all(s.heartbeat_at > beats[s.name] for s in store.live_shards(LEASE_S)),
        "both shards beating again (every second)",
    )


def test_a_shard_stopped_gracefully_lets_its_sessions_go_to_the_other_at_once(shards, store):
    a, b = shards["shard-a"], shards["shard-b"]
    sid = create(a.url)
    replies = asyncio.run(stream_in_step(stream_url(a, sid), frames(0, 3)))
    assert [r["type"] for r in replies] == ["ack"] * 3
    held_by_a = objects(a.url, sid)
    seq_on_a = session_stats(a.url, sid)["update_seq"]
    epoch_of_a = store.load_session(sid).epoch
    assert held_by_a and seq_on_a >= 2

    a.stop()
    assert [s.name for s in store.live_shards(LEASE_S)] == ["shard-b"]  # forgotten
    released = store.load_session(sid)
    assert (released.owner, released.lease_until, released.epoch) == (None, None, epoch_of_a)

    assert session_stats(b.url, sid)["update_seq"] == seq_on_a  # at once: no lease to wait out
    taken = store.load_session(sid)
    assert (taken.owner, taken.epoch) == ("shard-b", epoch_of_a + 1)
    assert objects(b.url, sid) == held_by_a


class HeldRenewal:
    """A shard's housekeeping thread stalled in its next lease renewal that lists session
    `sid`, until `release` is set: the shard hung (or lost the store) as far as its claims
    go, while it still serves its sockets. That thread also makes the counters-only saves, so
    nothing but the keyframe under test writes the session meanwhile (whichever write meets
    another shard's claim first drops the session)."""

    def __init__(self, server: ServerThread, sid: str, monkeypatch: pytest.MonkeyPatch):
        self.sid = sid
        self.holding = threading.Event()
        """The renewal listed the session and waits."""
        self.release = threading.Event()
        self.over = threading.Event()
        """A later renewal began: the held one (and the drops it made) finished."""
        store = server.app.state.manager.store
        self._renew = store.renew_leases
        monkeypatch.setattr(store, "renew_leases", self.renew)

    def renew(self, owner, epochs, lease_s, now=None):
        if self.sid in epochs and not self.release.is_set():
            self.holding.set()
            self.release.wait(WAIT_S)
        elif self.holding.is_set():
            self.over.set()
        return self._renew(owner, epochs, lease_s, now)


@pytest.fixture
def hold_renewal(shards, monkeypatch) -> Iterator[Callable[[str, str], HeldRenewal]]:
    """hold_renewal(shard, sid): that shard's next renewal listing `sid` waits (released at
    the end of the test at the latest, so the shard can stop)."""
    held: list[HeldRenewal] = []

    def hold(shard: str, sid: str) -> HeldRenewal:
        held.append(HeldRenewal(shards[shard], sid, monkeypatch))
        return held[-1]

    yield hold
    for renewal in held:
        renewal.release.set()


def claim_away(store: Store, sid: str, to: str) -> int:
    """Claim `sid` for shard `to` in the store as once its owner's lease has run out (its
    renewal held); the new epoch."""
    lease_until = store.load_session(sid).lease_until
    return store.claim_session(sid, to, LEASE_S, now=max(lease_until + 0.5, time.time()))


@dataclass
class Fenced:
    sid: str
    before: tuple
    """The store's map (`stored_map`) before the keyframe sent after the claim."""
    reply: dict
    """Shard A's reply to that keyframe."""
    closed: websockets.ConnectionClosed | None
    """How A's socket ended within `close_within_s` of that reply (None: it stayed open)."""
    renewal: HeldRenewal
    session: Session
    """A's copy of the session."""


def fence_shard_a(shards, store, hold_renewal, close_within_s: float) -> Fenced:
    """Stream three keyframes to shard A, hold its renewal, claim the session for shard B,
    then send A a fourth keyframe (one that would add a lamp)."""
    a = shards["shard-a"]
    sid = create(a.url)

    async def scenario() -> Fenced:
        async with websockets.connect(stream_url(a, sid), max_size=None) as ws:
            for frame in frames(0, 3):
                assert (await send_and_collect(ws, [frame]))[0]["type"] == "ack"
            session = a.app.state.manager.sessions[sid]
            renewal = hold_renewal("shard-a", sid)
            assert await asyncio.to_thread(renewal.holding.wait, WAIT_S), "A renewed nothing"
            before = stored_map(store, sid)
            assert claim_away(store, sid, "shard-b") == 2
            reply = (await send_and_collect(ws, frames(3, 1, [*SCENE, LAMP])))[0]
            try:
                extra = await asyncio.wait_for(ws.recv(), close_within_s)
            except websockets.ConnectionClosed as closed:
                return Fenced(sid, before, reply, closed, renewal, session)
            except TimeoutError:
                return Fenced(sid, before, reply, None, renewal, session)
            raise AssertionError(f"a message after the refusal: {msgpack.unpackb(extra)}")

    return asyncio.run(scenario())


def taken_over_count(server: ServerThread) -> list[str]:
    return [
        line
        for line in httpx.get(f"{server.url}/metrics").text.splitlines()
        if line.startswith("semanticxr_sessions_taken_over_total ")
    ]


def test_a_shard_that_lost_its_claim_refuses_the_keyframe_unmapped_and_writes_nothing(
    shards, store, hold_renewal
):
    """Another shard claimed the session while shard A held it (A hung past its lease, as
    the store sees it): A's next commit is fenced, so the keyframe is refused, unmapped."""
    fenced = fence_shard_a(shards, store, hold_renewal, close_within_s=0.1)
    reply = fenced.reply
    assert (reply["type"], reply["seq"], reply["code"]) == ("error", 3, "session_moved"), reply
    assert stored_map(store, fenced.sid) == fenced.before, "shard A wrote to a session it lost"
    moved = store.load_session(fenced.sid)
    assert (moved.owner, moved.epoch) == ("shard-b", 2)
    assert fenced.session.moved
    assert taken_over_count(shards["shard-a"]) == ["semanticxr_sessions_taken_over_total 1.0"]


def test_a_shard_that_lost_its_claim_closes_the_socket_1012_after_session_moved(
    shards, store, hold_renewal
):
    """The socket closes once the refusal has gone out, without waiting for another frame:
    a gateway moves it then (and a device reconnects)."""
    fenced = fence_shard_a(shards, store, hold_renewal, close_within_s=3.0)
    assert fenced.reply["code"] == "session_moved", fenced.reply
    assert fenced.closed is not None, "shard A's socket stayed open 3 s after session_moved"
    assert fenced.closed.rcvd is not None and fenced.closed.rcvd.code == 1012


def test_a_session_taken_over_is_counted_once_when_its_renewal_meets_the_claim_too(
    shards, store, hold_renewal
):
    """Shard A's housekeeping lists the session to renew its lease; meanwhile a keyframe's
    commit meets the other shard's claim and drops the session; then the renewal finds the
    claim gone too. One session was taken over: the counter says 1."""
    fenced = fence_shard_a(shards, store, hold_renewal, close_within_s=0.1)
    assert fenced.reply["code"] == "session_moved", fenced.reply
    fenced.renewal.release.set()
    assert fenced.renewal.over.wait(WAIT_S), "shard A renewed no more"
    assert taken_over_count(shards["shard-a"]) == ["semanticxr_sessions_taken_over_total 1.0"]


def test_a_device_streaming_in_step_through_a_gateway_gets_a_reply_to_a_fenced_keyframe(
    shards, store, hold_renewal, fresh_pg_url, tmp_path
):
    """The old owner still beats, so only its refusal can tell the gateway to move the socket:
    the device, waiting for the reply before its next frame, gets it from the new owner."""
    gateway_settings = ServerSettings(
        host="127.0.0.1",
        port=0,
        data_dir=str(tmp_path / "gateway"),
        store=fresh_pg_url,
        shard_lease_s=LEASE_S,
    )
    gateway = ServerThread(gateway_settings, app_factory=create_gateway_app).start()
    try:
        sid = create(gateway.url)
        owner = store.load_session(sid).owner
        other = next(name for name in shards if name != owner)

        async def scenario() -> list[dict]:
            url = f"{gateway.ws_url}/v1/sessions/{sid}/stream"
            async with websockets.connect(url, max_size=None) as ws:
                replies = [(await send_and_collect(ws, [f]))[0] for f in frames(0, 3)]
                session = shards[owner].app.state.manager.sessions[sid]
                renewal = hold_renewal(owner, sid)
                assert await asyncio.to_thread(renewal.holding.wait, WAIT_S)
                claim_away(store, sid, other)
                await ws.send(msgpack.packb(frames(3, 1)[0]))
                await asyncio.to_thread(poll, lambda: session.moved, "the owner refusing it")
                renewal.release.set()  # the old owner beats on: only its socket can say
                try:
                    replies += [msgpack.unpackb(await asyncio.wait_for(ws.recv(), 8.0))]
                except TimeoutError:
                    raise AssertionError("no reply to keyframe 3 within 8 s") from None
                return replies

        replies = asyncio.run(scenario())
        assert [(r["type"], r["seq"]) for r in replies] == [("ack", i) for i in range(4)]
    finally:
        gateway.stop()


# ---------------------------------------------------------------------- stream ids (standalone)
async def resend(url: str, stream: str, message: dict) -> dict:
    headers = {STREAM_HEADER: stream}
    async with websockets.connect(url, additional_headers=headers, max_size=None) as ws:
        return (await send_and_collect(ws, [message]))[0]


def test_a_keyframe_resent_under_its_stream_id_is_answered_from_the_store_not_mapped(
    live_server,
):
    server = live_server()
    sid = create(server.url)
    url = f"{server.ws_url}/v1/sessions/{sid}/stream"
    sent = frames(0, 3)
    first = asyncio.run(stream_in_step(url, sent, headers={STREAM_HEADER: "device-1"}))
    assert [r["type"] for r in first] == ["ack"] * 3
    before = session_stats(server.url, sid)

    again = asyncio.run(resend(url, "device-1", sent[2]))  # a new socket, the same stream
    assert again["type"] == "ack" and again["keyframe"], again
    assert (again["seq"], again["update_seq"], again["objects"]) == (
        2,
        first[2]["update_seq"],
        first[2]["objects"],
    )
    after = session_stats(server.url, sid)
    assert (after["keyframes"], after["update_seq"]) == (before["keyframes"], before["update_seq"])


def test_the_same_seq_under_another_stream_id_is_mapped(live_server):
    server = live_server()
    sid = create(server.url)
    url = f"{server.ws_url}/v1/sessions/{sid}/stream"
    sent = frames(0, 3)
    asyncio.run(stream_in_step(url, sent, headers={STREAM_HEADER: "device-1"}))
    before = session_stats(server.url, sid)["keyframes"]

    other = asyncio.run(resend(url, "device-2", sent[2]))
    assert other["type"] == "ack" and other["keyframe"], other
    assert session_stats(server.url, sid)["keyframes"] == before + 1


@pytest.mark.parametrize(
    "stream", [pytest.param("x" * 65, id="65 characters"), pytest.param("a/b", id="a slash")]
)
def test_a_bad_stream_id_is_refused_at_the_handshake(live_server, stream):
    server = live_server()
    sid = create(server.url)

    async def run() -> websockets.InvalidStatus:
        with pytest.raises(websockets.InvalidStatus) as refused:
            async with websockets.connect(
                f"{server.ws_url}/v1/sessions/{sid}/stream",
                additional_headers={STREAM_HEADER: stream},
            ):
                pass
        return refused.value

    refused = asyncio.run(run())
    assert refused.response.status_code == 403
    assert session_stats(server.url, sid)["frames"] == 0


def test_a_stream_id_of_64_allowed_characters_is_taken(live_server):
    server = live_server()
    sid = create(server.url)
    stream = ("aZ09-_" * 11)[:64]
    reply = asyncio.run(
        resend(f"{server.ws_url}/v1/sessions/{sid}/stream", stream, frames(0, 1)[0])
    )
    assert reply["type"] == "ack", reply


def test_deleting_a_session_closes_its_idle_stream_socket_1001(live_server):
    server = live_server()
    sid = create(server.url)

    async def scenario() -> websockets.ConnectionClosed | None:
        async with websockets.connect(f"{server.ws_url}/v1/sessions/{sid}/stream") as ws:
            assert (await send_and_collect(ws, frames(0, 1)))[0]["type"] == "ack"
            async with httpx.AsyncClient() as http:
                deleted = await http.delete(f"{server.url}/v1/sessions/{sid}")
            assert deleted.status_code == 204, deleted.text
            try:
                await asyncio.wait_for(ws.recv(), 3.0)
            except websockets.ConnectionClosed as closed:
                return closed
            except TimeoutError:
                return None
            raise AssertionError("a message after the deletion instead of a close")

    closed = asyncio.run(scenario())
    assert closed is not None, "the socket stayed open 3 s after its session was deleted"
    assert closed.rcvd is not None and closed.rcvd.code == 1001
