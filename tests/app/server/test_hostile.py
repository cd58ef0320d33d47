"""No client stalls the server, against a real server process (docs/faults.md, "No client can
stall the server").

Each hostile message is sent while another thread polls /healthz: the worst answer time
stays under 1 s, the server's RSS (/proc/PID/status) grows by less than 256 MB (512 MB for
eight at once), each message gets a clear error, and the server stays up. The budgets'
refusals come back within 1.5 s. Bounds are the faults target's (docs/evaluation.md
"Targets"); the figures are printed (-s)."""

from __future__ import annotations

import asyncio
import struct
import threading
import time
from pathlib import Path

import httpx
import msgpack
import numpy as np
import pytest
import websockets
from analytic_world import Rect
from devices import frame_message

from app import codecs
from app.protocol import Uint16Image, pack_frame
from app.server.runner import ServerProcess

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

MESSAGE_BYTES = 8 << 20  # the server's default max_message_bytes
WORST_HEALTHZ_S = 1.0
REFUSED_WITHIN_S = 1.5
MB = 1 << 20
CHAIR = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)


def empty_arrays_bomb(size: int = MESSAGE_BYTES) -> bytes:
    """One msgpack array of ~8.4 M empty arrays: 8 MiB that unpack naively to ~600 MB."""
    n = size - 5
    return b"\xdd" + struct.pack(">I", n) + b"\x90" * n


def bomb_in_a_valid_frame() -> bytes:
    """A valid frame with the same bomb under a key the protocol does not know."""
    frame = msgpack.packb(frame_message([CHAIR], 0))
    n = MESSAGE_BYTES - len(frame) - 64
    # A map of one more pair: the frame's pairs, then "padding": [[]] * n.
    assert frame[0] & 0xF0 == 0x80, "the frame packs as a fixmap"
    pairs = frame[0] & 0x0F
    return (
        bytes([0x80 | (pairs + 1)])
        + frame[1:]
        + msgpack.packb("padding")
        + (b"\xdd" + struct.pack(">I", n) + b"\x90" * n)
    )


def big_frame(side_px: int = 4096) -> bytes:
    """A 4096x4096 frame with full-size depth (small on the wire: uniform images)."""
    rgb = codecs.encode_jpeg(np.full((side_px, side_px, 3), 128, np.uint8))
    depth = np.full((side_px, side_px), 2000, np.uint16)
    return msgpack.packb(
        pack_frame(
            seq=1,
            t=0.0,
            pose=codecs.pose_to_bytes(np.eye(4)),
            intrinsics=[side_px, side_px, side_px / 2, side_px / 2],
            rgb_jpeg=rgb,
            depth=Uint16Image("zstd", side_px, side_px, codecs.encode_uint16_image(depth, "zstd")),
            depth_scale_m=0.001,
        )
    )


def comb_frame(n_instances: int, w: int = 640, h: int = 480) -> bytes:
    """n instances of distinct labels, each a comb of pixels spread over the whole frame (so
    its box passes min_mapping_bbox_area), at 1 m."""
    ids = (np.arange(w * h) % n_instances + 1).astype(np.uint16).reshape(h, w)
    return msgpack.packb(
        pack_frame(
            seq=2,
            t=0.0,
            pose=codecs.pose_to_bytes(np.eye(4)),
            intrinsics=[500.0, 500.0, w / 2, h / 2],
            rgb_jpeg=codecs.encode_jpeg(np.full((h, w, 3), 128, np.uint8)),
            depth=Uint16Image(
                "zstd", w, h, codecs.encode_uint16_image(np.full((h, w), 1000, np.uint16), "zstd")
            ),
            depth_scale_m=0.001,
            detections=Uint16Image("zstd", w, h, codecs.encode_uint16_image(ids, "zstd")),
            instances=[
                {"id": i + 1, "label": f"thing number {i}", "score": 0.9}
                for i in range(n_instances)
            ],
        )
    )


def rss_bytes(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmRSS")


class Watch:
    """Polls /healthz (worst answer time) and the server's RSS (peak) from another thread."""

    def __init__(self, server: ServerProcess):
        self.server = server
        self.worst_s = 0.0
        self.failures: list[str] = []
        self.base_rss = self.peak_rss = rss_bytes(server.proc.pid)
        self.polls = 0
        self._polled = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        with httpx.Client(timeout=10) as http:
            while not self._stop.is_set():
                t0 = time.perf_counter()
                try:
                    status = http.get(f"{self.server.url}/healthz").status_code
                    if status != 200:
                        self.failures.append(f"/healthz {status}")
                except httpx.HTTPError as exc:
                    self.failures.append(repr(exc))
                self.worst_s = max(self.worst_s, time.perf_counter() - t0)
                self.peak_rss = max(self.peak_rss, rss_bytes(self.server.proc.pid))
                with self._polled:
                    self.polls += 1
                    self._polled.notify_all()
                self._stop.wait(0.02)  # a polling period

    def _wait_polls(self, n: int) -> None:
        with self._polled:
            assert self._polled.wait_for(lambda: self.polls >= n, timeout=30), "no /healthz answer"

    def __enter__(self) -> Watch:
        self._thread.start()
        self._wait_polls(1)
        return self

    def __exit__(self, *exc_info) -> None:
        self._wait_polls(self.polls + 2)  # a whole poll after the last message was answered
        self._stop.set()
        self._thread.join(timeout=30)

    @property
    def growth_mb(self) -> float:
        return (self.peak_rss - self.base_rss) / MB


async def send_for_reply(url: str, data: bytes, timeout_s: float = 30.0) -> tuple[dict, float]:
    """Send one message; (its reply, seconds from send to reply)."""
    async with websockets.connect(url, max_size=None) as ws:
        t0 = time.perf_counter()
        await ws.send(data)
        reply = msgpack.unpackb(await asyncio.wait_for(ws.recv(), timeout_s))
        return reply, time.perf_counter() - t0


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with ServerProcess(tmp_path_factory.mktemp("hostile")) as proc:
        yield proc


@pytest.fixture(scope="module")
def stream_url(server):
    sid = httpx.post(f"{server.url}/v1/sessions", json={}, timeout=10).json()["session_id"]
    return f"{server.ws_url}/v1/sessions/{sid}/stream"


def assert_unharmed(server: ServerProcess, watch: Watch, max_growth_mb: float, what: str) -> None:
    print(f"\n{what}: worst /healthz {watch.worst_s * 1e3:.0f} ms, RSS +{watch.growth_mb:.0f} MB")
    assert not watch.failures, watch.failures[:3]
    assert watch.worst_s < WORST_HEALTHZ_S
    assert watch.growth_mb < max_growth_mb
    assert server.proc.poll() is None
    assert httpx.get(f"{server.url}/healthz", timeout=5).status_code == 200


@pytest.mark.parametrize(
    "bomb", [empty_arrays_bomb, bomb_in_a_valid_frame], ids=["alone", "under-an-unknown-key"]
)
def test_an_unpacking_bomb_is_refused_without_stalling_anyone(server, stream_url, bomb):
    data = bomb()
    assert len(data) <= MESSAGE_BYTES
    with Watch(server) as watch:
        reply, _ = asyncio.run(send_for_reply(stream_url, data))
    assert (reply["type"], reply["code"]) == ("error", "bad_message")
    assert "limit" in reply["message"]
    assert_unharmed(server, watch, 256, f"bomb {bomb.__name__}")


def test_eight_bombs_at_once_stall_nobody(server, stream_url):
    data = empty_arrays_bomb()

    async def eight() -> list[dict]:
        return [
            r
            for r, _ in await asyncio.gather(*(send_for_reply(stream_url, data) for _ in range(8)))
        ]

    with Watch(server) as watch:
        replies = asyncio.run(eight())
    assert [(r["type"], r["code"]) for r in replies] == [("error", "bad_message")] * 8
    assert_unharmed(server, watch, 512, "eight bombs")


@pytest.mark.parametrize(
    ("frame", "limit"),
    [
        (big_frame, "--max-frame-pixels"),
        (lambda: comb_frame(1024), "--max-instances-per-frame"),
    ],
    ids=["4096x4096", "1024-instances"],
)
def test_a_frame_over_the_budget_is_refused_quickly_naming_the_flag(
    server, stream_url, frame, limit
):
    data = frame()
    with Watch(server) as watch:
        reply, took_s = asyncio.run(send_for_reply(stream_url, data))
    print(f"\nrefused in {took_s * 1e3:.0f} ms: {reply['message']}")
    assert (reply["type"], reply["code"], reply["seq"]) == (
        "error",
        "over_limit",
        msgpack.unpackb(data)["seq"],
    )
    assert limit in reply["message"]
    assert took_s < REFUSED_WITHIN_S
    assert_unharmed(server, watch, 256, limit)
