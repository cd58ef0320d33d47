"""An independent client, written from docs/protocol.md alone, streams through one gateway,
follows the map through another, and survives a kill -9 of the session's map shard with
nothing acknowledged lost (docs/architecture.md, "Many devices: gateways and map shards").

Only the test function touches the cluster's machinery (the gateways' addresses, the owner
shard, the kill); everything that crosses the wire is built and read here, from the
documented contract, without importing the project's own protocol code.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import signal
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

import httpx
import msgpack
import numpy as np
import pytest
import websockets
from PIL import Image
from websockets.asyncio.client import ClientConnection

pytestmark = [pytest.mark.cluster, pytest.mark.slow, pytest.mark.timeout(300)]

REPLY_TIMEOUT_S = 60.0
"""Longest one reply may take: a failover (lease, claim, reload) takes a few seconds."""


class OutsideClient:
    """A SemanticXR client written from docs/protocol.md alone (wire protocol v1).

    REST bodies are JSON; socket messages are msgpack maps with raw bytes for binary fields.
    Frames carry a camera-to-world pose as 16 float32 little-endian (row-major), intrinsics
    of the RGB image, the RGB image as JPEG, depth as uint16 little-endian with its scale
    (metres per unit) and detections as a uint16 instance-id image (0 = none) with a label
    and score per id. The stream answers every frame with exactly one `ack` or `error`; the
    updates socket sends `delta`s which, applied in order, hold the server's confirmed map.
    The session's token goes in `Authorization: Bearer` on REST and on the socket handshakes.
    """

    def __init__(self, url: str) -> None:
        self.url = url.rstrip("/")
        self.ws_url = "ws" + self.url.removeprefix("http")
        self.tokens: dict[str, str] = {}

    def _auth(self, sid: str) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.tokens[sid]}"}

    async def _get(self, path: str, sid: str, **params) -> object:
        async with httpx.AsyncClient(timeout=REPLY_TIMEOUT_S) as http:
            answer = await http.get(f"{self.url}{path}", params=params, headers=self._auth(sid))
        assert answer.status_code == 200, f"GET {path}: {answer.status_code} {answer.text}"
        return answer.json()

    async def create_session(self, name: str, knobs: dict) -> str:
        """POST /v1/sessions; remembers the session's token (returned only once)."""
        async with httpx.AsyncClient(timeout=REPLY_TIMEOUT_S) as http:
            answer = await http.post(f"{self.url}/v1/sessions", json={"name": name, "knobs": knobs})
        assert answer.status_code == 201, answer.text
        body = answer.json()
        assert body["protocol"] == 1, body
        self.tokens[body["session_id"]] = body["token"]
        return body["session_id"]

    def share(self, other: OutsideClient) -> None:
        """Lets `other` (say, at another gateway) use this client's session tokens."""
        other.tokens.update(self.tokens)

    async def objects(self, sid: str) -> dict[int, str]:
        """The confirmed map, id -> label."""
        listed = await self._get(f"/v1/sessions/{sid}/objects", sid, points="false")
        return {o["id"]: o["label"] for o in listed}

    async def stats(self, sid: str) -> dict:
        return await self._get(f"/v1/sessions/{sid}", sid)

    async def query(self, sid: str, text: str, k: int = 5) -> list[dict]:
        """The hits of a text query, best first."""
        answer = await self._get(f"/v1/sessions/{sid}/query", sid, text=text, k=k, points="false")
        return answer["results"]

    @staticmethod
    def frame(
        seq: int,
        t: float,
        pose: np.ndarray,
        intrinsics: tuple[float, float, float, float],
        rgb: np.ndarray,
        depth_m: np.ndarray,
        instance_ids: np.ndarray,
        labels: dict[int, str],
        depth_scale: float = 0.001,
    ) -> bytes:
        """One `frame` message: rgb uint8 [h, w, 3], depth_m float [h, w] (0 = no depth),
        instance_ids uint16 [h, w] (0 = none), labels for the ids present."""
        h, w = depth_m.shape
        depth_units = np.round(depth_m / depth_scale).astype("<u2")
        jpeg = io.BytesIO()
        Image.fromarray(rgb).save(jpeg, format="JPEG", quality=90)
        present = sorted(int(i) for i in np.unique(instance_ids) if i != 0)
        return msgpack.packb(
            {
                "type": "frame",
                "seq": seq,
                "t": t,
                "pose": np.asarray(pose, dtype="<f4").tobytes(order="C"),
                "intrinsics": [float(v) for v in intrinsics],
                "rgb": {"codec": "jpeg", "data": jpeg.getvalue()},
                "depth": {
                    "codec": "raw",
                    "w": w,
                    "h": h,
                    "scale": depth_scale,
                    "data": depth_units.tobytes(order="C"),
                },
                "detections": {
                    "codec": "raw",
                    "w": w,
                    "h": h,
                    "data": instance_ids.astype("<u2").tobytes(order="C"),
                    "instances": [{"id": i, "label": labels[i], "score": 0.9} for i in present],
                },
            }
        )

    @contextlib.asynccontextmanager
    async def stream(self, sid: str) -> AsyncIterator[Stream]:
        """The stream socket; on leaving, it is closed and any reply left over is kept in
        `Stream.extra` (a frame answered twice)."""
        async with websockets.connect(
            f"{self.ws_url}/v1/sessions/{sid}/stream",
            additional_headers=self._auth(sid),
            max_size=16 << 20,
        ) as ws:
            stream = Stream(ws)
            reader = asyncio.create_task(stream.read())
            try:
                yield stream
            finally:
                await ws.close()
                await asyncio.wait_for(reader, REPLY_TIMEOUT_S)

    @contextlib.asynccontextmanager
    async def follow(self, sid: str, since: int = 0) -> AsyncIterator[HeldMap]:
        """The updates socket from `since`, applied to a HeldMap as deltas arrive."""
        held = HeldMap()
        async with websockets.connect(
            f"{self.ws_url}/v1/sessions/{sid}/updates?since={since}",
            additional_headers=self._auth(sid),
            max_size=16 << 20,
        ) as ws:
            reader = asyncio.create_task(held.read(ws))
            try:
                yield held
            finally:
                reader.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await reader


@dataclass
class Stream:
    """One stream socket: frames out, every message that came back, in order."""

    ws: ClientConnection
    replies: asyncio.Queue = field(default_factory=asyncio.Queue)
    closed: str | None = None
    extra: list[dict] = field(default_factory=list)
    waiting: int = 0

    async def read(self) -> None:
        try:
            async for raw in self.ws:
                reply = msgpack.unpackb(raw)
                if self.waiting:
                    self.waiting -= 1
                    await self.replies.put(reply)
                else:
                    self.extra.append(reply)
        except websockets.ConnectionClosed:
            pass
        self.closed = f"closed {self.ws.close_code} {self.ws.close_reason!r}"
        await self.replies.put(None)

    async def send(self, frame: bytes) -> None:
        """Sends a frame without waiting for its reply."""
        self.waiting += 1
        await self.ws.send(frame)

    async def reply(self) -> dict:
        """The next reply, within REPLY_TIMEOUT_S."""
        reply = await asyncio.wait_for(self.replies.get(), REPLY_TIMEOUT_S)
        assert reply is not None, f"the stream socket ended waiting for a reply: {self.closed}"
        return reply

    async def send_and_wait(self, frame: bytes) -> dict:
        await self.send(frame)
        return await self.reply()


@dataclass
class HeldMap:
    """What an update subscriber holds: id -> label, and the last seq it applied."""

    labels: dict[int, str] = field(default_factory=dict)
    seq: int = -1
    closed: str | None = None
    changed: asyncio.Condition = field(default_factory=asyncio.Condition)

    async def read(self, ws: ClientConnection) -> None:
        ended = None
        try:
            async for raw in ws:
                delta = msgpack.unpackb(raw)
                if delta.get("type") != "delta":
                    ended = f"sent {delta!r}, not a delta"
                    break
                if delta["full"]:
                    self.labels.clear()
                for up in delta["upserts"]:
                    self.labels[up["id"]] = up["label"]
                for oid in delta["removed"]:
                    self.labels.pop(oid, None)
                async with self.changed:
                    self.seq = delta["seq"]
                    self.changed.notify_all()
        except websockets.ConnectionClosed:
            pass
        async with self.changed:
            self.closed = ended or f"closed {ws.close_code} {ws.close_reason!r}"
            self.changed.notify_all()

    async def reach(self, seq: int) -> None:
        """Waits until the subscriber applied `seq` (AssertionError if its socket ended)."""
        async with self.changed:
            await self.changed.wait_for(lambda: self.seq >= seq or self.closed is not None)
        assert self.seq >= seq, (
            f"the updates socket ended ({self.closed}) at seq {self.seq} < {seq}"
        )


# The client's own world: a wall 3 m ahead, labelled boxes in front of it (OpenCV axes:
# x right, y down, z forward; the world is the first camera's frame).

W, H = 320, 240
INTRINSICS = (260.0, 260.0, (W - 1) / 2, (H - 1) / 2)
WALL_Z_M = 3.0


@dataclass(frozen=True)
class Box:
    instance: int
    label: str
    centre: tuple[float, float, float]
    size: tuple[float, float, float]
    rgb: tuple[int, int, int]


MUG = Box(1, "mug", (-0.35, 0.15, 1.3), (0.10, 0.12, 0.10), (200, 40, 40))
LAPTOP = Box(2, "laptop", (0.25, 0.10, 1.8), (0.34, 0.24, 0.05), (60, 60, 70))
CHAIR = Box(3, "chair", (-0.80, 0.05, 2.4), (0.45, 0.80, 0.45), (130, 80, 40))
BACKPACK = Box(4, "backpack", (0.80, -0.10, 2.0), (0.30, 0.45, 0.20), (40, 70, 200))
SCENE = [MUG, LAPTOP, CHAIR]


def camera_pose(i: int) -> np.ndarray:
    """Camera-to-world 4x4 of frame i: a slow step right while turning slightly."""
    yaw = 0.005 * i
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]]
    pose[:3, 3] = [0.02 * i, 0.0, 0.0]
    return pose


def render(boxes: list[Box], pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ray-casts the scene: rgb uint8 [H, W, 3], depth in metres [H, W] (camera z), and the
    instance id of the nearest box per pixel (uint16 [H, W], 0 = wall)."""
    fx, fy, cx, cy = INTRINSICS
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    rays_cam = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u, dtype=float)], -1)
    rays = rays_cam @ pose[:3, :3].T  # world directions; t along them is the camera z
    origin = pose[:3, 3]
    depth = (WALL_Z_M - origin[2]) / rays[..., 2]
    ids = np.zeros((H, W), np.uint16)
    rgb = np.empty((H, W, 3), np.uint8)
    rgb[:] = (200, 200, 190)
    with np.errstate(divide="ignore", invalid="ignore"):
        for box in boxes:
            lo = np.subtract(box.centre, np.divide(box.size, 2))
            hi = np.add(box.centre, np.divide(box.size, 2))
            t1, t2 = (lo - origin) / rays, (hi - origin) / rays
            near = np.nanmax(np.minimum(t1, t2), -1)
            far = np.nanmin(np.maximum(t1, t2), -1)
            hit = (far >= near) & (near > 0) & (near < depth)
            depth[hit], ids[hit], rgb[hit] = near[hit], box.instance, box.rgb
    return rgb, depth, ids


def scene_frame(i: int, boxes: list[Box]) -> bytes:
    """Frame i of the walk (10 frames a second), showing `boxes`."""
    rgb, depth, ids = render(boxes, camera_pose(i))
    labels = {b.instance: b.label for b in boxes}
    return OutsideClient.frame(i, 0.1 * i, camera_pose(i), INTRINSICS, rgb, depth, ids, labels)


def test_an_outside_client_streams_through_two_gateways_and_survives_a_shard_kill(cluster):
    cluster.wait_for_shards()
    a = OutsideClient(cluster.gateways[0].url)
    b = OutsideClient(cluster.gateways[1].url)
    knobs = {
        "keyframe_interval": 1,
        "min_observations": 2,
        "min_mapping_bbox_area": 100,
        "local_map_update_frequency": 1,
    }

    async def scenario() -> dict:
        sid = await a.create_session("outside client", knobs)
        a.share(b)
        async with a.stream(sid) as stream, b.follow(sid, since=0) as held:
            replies = [await stream.send_and_wait(scene_frame(i, SCENE)) for i in range(4)]
            before = await b.objects(sid)
            owner, epoch = await asyncio.to_thread(cluster.owner, sid)
            # a keyframe in flight when its shard is killed
            await stream.send(scene_frame(4, [*SCENE, BACKPACK]))
            await asyncio.to_thread(cluster.signal, owner, signal.SIGKILL)
            replies.append(await stream.reply())
            for i in range(5, 8):
                replies.append(await stream.send_and_wait(scene_frame(i, [*SCENE, BACKPACK])))
            after = await b.objects(sid)
            update_seq = (await b.stats(sid))["update_seq"]
            await asyncio.wait_for(held.reach(update_seq), REPLY_TIMEOUT_S)
            hits = await b.query(sid, "laptop")
        return {
            "moved": (await asyncio.to_thread(cluster.owner, sid))[1] > epoch,
            "replies": replies,
            "extra": stream.extra,
            "before": before,
            "after": after,
            "held": held.labels,
            "hits": hits,
        }

    seen = asyncio.run(scenario())
    replies, before, after = seen["replies"], seen["before"], seen["after"]
    assert seen["moved"], "the session never left the killed shard"
    assert [(r["type"], r["seq"]) for r in replies] == [("ack", i) for i in range(8)], replies
    assert seen["extra"] == [], "a frame was answered more than once"
    assert sorted(before.values()) == ["chair", "laptop", "mug"]
    assert before.items() <= after.items()  # nothing acknowledged is lost
    assert sorted(after.values()) == ["backpack", "chair", "laptop", "mug"]
    assert seen["held"] == after
    laptop = next(oid for oid, label in after.items() if label == "laptop")
    assert seen["hits"][0]["id"] == laptop, seen["hits"]
    cluster.wait_for_shards()
