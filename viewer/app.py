"""The viser viewer of one session: follows its map updates, shows objects and query hits.

Threads: viser runs its own server thread and calls GUI callbacks from its thread pool; the
viewer runs one background thread with an asyncio loop that follows the updates WebSocket
and polls the session's stats. `SceneModel` is not thread-safe, so every use of it holds
`ViewerApp._lock`.

The updates socket is kept up by the API client's `UpdatesSubscriber` (app/client/), as the
device's is: exponential backoff (0.2 s doubling to 5 s), resume from the last applied seq
after a disconnect, resync from a full snapshot after a malformed message. While it is down
the GUI says so in red.

The device's camera pose and path come from the optional "device_pose" field of updates
(an extension of v1: the newest mapped keyframe's camera-to-world pose): a frustum at the
newest pose and a line through the poses seen so far.
"""

from __future__ import annotations

import asyncio
import contextlib
import html
import logging
import ssl
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import viser
import viser.transforms as vtf

from app.answering.relevance import CONFIDENT
from app.client import ApiError, Disconnect, SessionApi, UpdatesSubscriber
from app.codecs import pose_from_bytes, validate_rigid_pose
from app.errors import InputError
from app.protocol import SessionStats, unpack_update
from viewer.palette import Rgb
from viewer.scene import (
    ANCHORS_GROUP,
    HITS_GROUP,
    RELATION_LINES_NODE,
    DeltaError,
    RelationHighlight,
    SceneModel,
)
from viewer.shapes import PANEL_PX, FloorGrid, floor_grid, frame_view
from viewer.words import relation_words

MAX_PATH_POINTS = 5000
"""Device path vertices kept (one per update that moved more than 1 cm)."""

log = logging.getLogger(__name__)

UpDirection = Literal["+x", "+y", "+z", "-x", "-y", "-z"]

REST_TIMEOUT_S = 10.0
"""Timeout of a query or a stats request."""
STATS_PERIOD_S = 2.0
"""How often the stats panel is refreshed from GET /v1/sessions/{sid}."""
POINT_SIZE_M = 0.012
"""Point size in world units: small, so 5,000 clouds stay light to draw and readable."""
BOX_THICKNESS_PX = 1.5
"""Line width of the batched boxes, in screen pixels (constant at every distance)."""
HIT_BOX_THICKNESS_PX = 4.0
"""Line width of the highlighted hits' boxes."""
MOVE_LINE_THICKNESS_PX = 3.0
"""Line width of the lines from a moved object's old place to its new one."""
CONFIDENT_DEGREE = 0.5
"""A hit stands in its relation from this degree on; under it the list says "not on the desk"
(static/app.js says the same)."""
RELATION_LINE_THICKNESS_PX = 4.0
"""Line width of the lines from a relational answer's target to its anchors."""
FLOOR_NODE = "/floor"
"""The floor grid: faint lines under the map, at its lowest box face along up."""
FLOOR_CELL_RGB, FLOOR_SECTION_RGB = (228, 228, 228), (200, 200, 200)
"""Faint: the floor is a reference, not content (0.5 m cells, 1 m sections)."""
ASSUMED_CANVAS_PX = (1400, 860)
"""The canvas size the starting view of new clients is framed for (a laptop's browser)."""
LIVE_RGB, DOWN_RGB, WAITING_RGB = "#1a7f37", "#cf222e", "#6e7781"
"""Status colours: live (green), disconnected (red), not connected yet (grey)."""


class ViewerError(RuntimeError):
    """A REST call of the viewer failed (server unreachable, 4xx/5xx)."""


class ViserSceneSink:
    """`SceneSink` on a viser scene: one viser node per name, handles kept for updates."""

    def __init__(self, scene: viser.SceneApi, point_size_m: float = POINT_SIZE_M):
        self.scene = scene
        self.point_size_m = point_size_m
        self._handles: dict[str, viser.SceneNodeHandle] = {}

    def add_point_cloud(self, name: str, points: np.ndarray, color: Rgb) -> None:
        self._handles[name] = self.scene.add_point_cloud(
            name,
            points,
            colors=color,  # one colour, sent as 3 bytes rather than 3 per point
            point_size=self.point_size_m,
            point_shape="circle",
            precision="float16",  # the wire precision: no conversion, half the bytes
        )

    def set_point_color(self, name: str, color: Rgb) -> None:
        handle = self._handles.get(name)
        if isinstance(handle, viser.PointCloudHandle):
            handle.colors = np.asarray(color, np.uint8)

    def add_label(self, name: str, text: str, position: tuple[float, float, float]) -> None:
        hit = name.startswith(HITS_GROUP)
        self._handles[name] = self.scene.add_label(
            name,
            text,
            position=position,
            font_screen_scale=1.0 if hit else 0.7,
            # an anchor's label hangs below its centre, so that it does not cover the label
            # of the target above it ("mug — on the desk" over "desk")
            anchor="top-center" if name.startswith(ANCHORS_GROUP) else "bottom-center",
        )

    def set_boxes(self, name: str, segments: np.ndarray, colors: np.ndarray) -> None:
        self._handles[name] = self.scene.add_line_segments(
            name,
            segments,
            colors,
            # the hits' and the relational answer's boxes (under /hits) stand out
            thickness=HIT_BOX_THICKNESS_PX if name.startswith(HITS_GROUP) else BOX_THICKNESS_PX,
            thickness_units="screen",
        )

    def set_lines(self, name: str, segments: np.ndarray, colors: np.ndarray) -> None:
        relation = name == RELATION_LINES_NODE
        thickness = RELATION_LINE_THICKNESS_PX if relation else MOVE_LINE_THICKNESS_PX
        self._handles[name] = self.scene.add_line_segments(
            name, segments, colors, thickness=thickness, thickness_units="screen"
        )

    def set_visible(self, name: str, visible: bool) -> None:
        handle = self._handles.get(name)
        if handle is None:  # a group: an invisible frame that parents its children
            handle = self._handles[name] = self.scene.add_frame(name, show_axes=False)
        handle.visible = visible

    def remove(self, name: str) -> None:
        handle = self._handles.pop(name, None)
        if handle is not None:
            handle.remove()


@dataclass
class ViewerStatus:
    """What the viewer knows about its link to the server (read by the GUI and by tests)."""

    connected: bool = False
    """True while the updates socket is up."""
    ever_connected: bool = False
    reconnects: int = 0
    """Successful re-connections after a loss."""
    last_since: int | None = None
    """`since` of the newest updates connection (None: it asked for a full snapshot)."""
    deltas_applied: int = 0
    full_snapshots: int = 0
    resyncs: int = 0
    """Full-snapshot resyncs after a malformed update."""
    last_error: str | None = None
    """The most recent problem, for a human."""
    stats: SessionStats | None = None
    """The last GET /v1/sessions/{sid} answer (None until the first one)."""
    stats_ok: bool = False
    """Whether the last stats poll succeeded."""


@dataclass
class _Gui:
    status: viser.GuiHtmlHandle
    query_form: viser.GuiFormHandle
    query_text: viser.GuiTextHandle
    top_k: viser.GuiNumberHandle
    search: viser.GuiButtonHandle
    clear: viser.GuiButtonHandle
    results: viser.GuiMarkdownHandle
    show_boxes: viser.GuiCheckboxHandle
    show_labels: viser.GuiCheckboxHandle
    color_by_class: viser.GuiCheckboxHandle
    stats: viser.GuiMarkdownHandle


def _megabytes(n_bytes: Any) -> str:
    return f"{n_bytes / 1e6:.2f} MB" if isinstance(n_bytes, int | float) else "-"


def _milliseconds(value: Any) -> str:
    return f"{value:.0f} ms" if isinstance(value, int | float) else "-"


def _strength(hit: dict) -> float:
    """How brightly a hit is drawn, in [0, 1]: its relevance, times its relation's degree in
    a relational answer (the mug on the shelf is no answer to "the mug on the desk")."""
    relation = hit.get("relation")
    return hit["relevance"] * (relation["degree"] if relation else 1.0)


def _hit_line(hit: dict, held: set[int], answer: bool) -> str:
    """One hit of the GUI's list, markdown: "mug — on the desk (0.93) — relevance `0.91`,
    score `0.612` (#10)", the relation's degree in brackets ("mug — not on the desk (0.00)"
    under CONFIDENT_DEGREE). The relation is said of what was asked about (a confident hit,
    or `answer`: the best hit of a matching answer), not of the desk in "the mug on the desk"
    nor of a weak hit. Names are escaped (user data)."""
    said = html.escape(hit["label"])
    relation = hit.get("relation")
    about = answer or hit["relevance"] >= CONFIDENT
    if relation and about and all(a["id"] != hit["id"] for a in relation["anchors"]):
        anchors = relation["anchors"]
        words = relation_words(relation["kind"], [a["label"] for a in anchors])
        negation = "" if relation["degree"] >= CONFIDENT_DEGREE else "not "
        said += f" — {negation}{html.escape(words)} ({relation['degree']:.2f})"
        if any(a["id"] not in held for a in anchors):
            said += " (anchor not received yet)"
    missing = "" if hit["id"] in held else " (not received yet)"
    return (
        f"{said} — relevance `{hit['relevance']:.2f}`, score `{hit['score']:.3f}` "
        f"(#{hit['id']}){missing}"
    )


def _up_vector(direction: UpDirection) -> np.ndarray:
    axis = {"x": 0, "y": 1, "z": 2}[direction[1]]
    up = np.zeros(3)
    up[axis] = 1.0 if direction[0] == "+" else -1.0
    return up


class ViewerApp:
    """A viser server showing one session's confirmed map, live.

    server_url: http(s)://host:port of the SemanticXR server. token: the session token (or
    the API key), sent as `Authorization: Bearer`. port / host: where the viewer listens
    (port 0: any free port; see `port` after construction). up_direction: the up axis of the
    device's world frame (the synthetic world is +z up). ssl_context: whom an https://
    server must prove to be (`app.client.trusting`; default: the system's CAs).

    `start()` begins following updates; `stop()` ends everything. Usable as a context manager.
    """

    def __init__(
        self,
        server_url: str,
        session_id: str,
        token: str | None = None,
        port: int = 8080,
        host: str = "127.0.0.1",
        *,
        up_direction: UpDirection = "+z",
        stats_period_s: float = STATS_PERIOD_S,
        verbose: bool = False,
        ssl_context: ssl.SSLContext | None = None,
    ):
        self.api = SessionApi(
            server_url, session_id, token, timeout_s=REST_TIMEOUT_S, ssl_context=ssl_context
        )
        self.server_url = server_url
        self.session_id = session_id
        self.token = token
        self.ssl_context = ssl_context
        self.host = host
        self.stats_period_s = stats_period_s
        self.status = ViewerStatus()
        self.last_match: bool | None = None
        """Whether the last query had a confident match (None before the first query)."""
        self.up = _up_vector(up_direction)
        self.server = viser.ViserServer(host=host, port=port, verbose=verbose)
        self.server.scene.set_up_direction(up_direction)
        self._lock = threading.RLock()
        self.model = SceneModel(ViserSceneSink(self.server.scene))
        self._device_path: list[np.ndarray] = []
        self._camera_framed = False  # frame the map once, when it first has objects
        self._floor: FloorGrid | None = None  # the floor grid in the scene now
        self.gui = self._build_gui()
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._main_task: asyncio.Task | None = None
        self._loop_ready = threading.Event()

    # --- lifecycle --------------------------------------------------------------------------

    @property
    def port(self) -> int:
        return self.server.get_port()

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "") else self.host
        return f"http://{host}:{self.port}"

    @property
    def applied_seq(self) -> int:
        """Seq of the last delta the viewer applied."""
        # No lock: an int read is atomic, and the event loop must not wait for a big apply.
        return self.model.seq

    def start(self) -> ViewerApp:
        """Start following the session's updates and polling its stats (background thread)."""
        if self._thread is not None:
            raise RuntimeError("the viewer is already started")
        self._thread = threading.Thread(target=self._run, name="viewer-updates", daemon=True)
        self._thread.start()
        self._loop_ready.wait(10)
        return self

    def stop(self) -> None:
        """Stop following updates and shut the viser server down."""
        if self._loop is not None and self._main_task is not None:
            self._loop.call_soon_threadsafe(self._main_task.cancel)
        if self._thread is not None:
            self._thread.join(timeout=15)
        self.server.stop()

    def __enter__(self) -> ViewerApp:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._main())
            loop.run_until_complete(loop.shutdown_default_executor())  # an apply in flight
        finally:
            # As asyncio.run does: finish what is left (a socket's keepalive) before closing.
            leftovers = asyncio.all_tasks(loop)
            for task in leftovers:
                task.cancel()
            if leftovers:
                loop.run_until_complete(asyncio.wait(leftovers))
            loop.close()

    async def _main(self) -> None:
        self._main_task = asyncio.current_task()
        self._loop_ready.set()
        with contextlib.suppress(asyncio.CancelledError):
            await asyncio.gather(self._follow_updates(), self._poll_stats())

    # --- updates ----------------------------------------------------------------------------

    async def _follow_updates(self) -> None:
        """Apply the session's deltas until cancelled; resume from the applied seq after a
        disconnect, resync from a full snapshot after a malformed message."""
        subscriber = UpdatesSubscriber(
            self.server_url,
            self.session_id,
            self.token,
            apply=self._apply_update,
            applied_seq=lambda: self.applied_seq,
            # Off the loop: a big snapshot takes a while to hand to viser, and the socket's
            # keepalive pings must still be answered meanwhile.
            apply_in_thread=True,
            on_connected=self._updates_connected,
            on_disconnected=self._updates_disconnected,
            ssl_context=self.ssl_context,
        )
        await subscriber.run()

    def _updates_connected(self, since: int | None, reconnect: bool) -> None:
        self.status.last_since = since
        self._set_connected(True)

    def _updates_disconnected(self, event: Disconnect) -> None:
        self.status.resyncs += event.bad_update is not None
        self._set_connected(False, event.reason, quiet=event.repeated)

    def _apply_update(self, raw: bytes | str) -> str | None:
        """Apply one updates-socket message; what was wrong with it, or None if applied."""
        message = unpack_update(raw)
        if isinstance(message, str):
            return message
        with self._lock:
            try:
                summary = self.model.apply_delta(message)
            except DeltaError as exc:
                return str(exc)
            self.status.deltas_applied += 1
            self.status.full_snapshots += summary.full
            if isinstance(message.get("device_pose"), bytes):
                self._show_device(message["device_pose"])
            if summary.changed:
                self._show_floor()
            if not self._camera_framed and self.model.objects:
                self._camera_framed = True
                self._frame_camera()
        self._show_status()
        return None

    def _set_connected(self, connected: bool, reason: str = "", quiet: bool = False) -> None:
        status = self.status
        if connected:
            status.reconnects += status.ever_connected and not status.connected
            status.connected = status.ever_connected = True
        else:
            status.connected = False
            status.last_error = reason
            if not quiet:
                log.warning("updates socket down (%s); reconnecting", reason)
        self._show_status()

    # --- stats ------------------------------------------------------------------------------

    async def _poll_stats(self) -> None:
        async with self.api:
            while True:
                try:
                    self.status.stats = await self.api.fetch()
                    self.status.stats_ok = True
                except ApiError:
                    self.status.stats_ok = False
                self._show_stats()
                await asyncio.sleep(self.stats_period_s)  # a polling period

    # --- queries ----------------------------------------------------------------------------

    def run_query(self, text: str, k: int = 5) -> list[dict]:
        """GET /v1/sessions/{sid}/query, highlight the hits and list them in the GUI; the
        results, best first. A relational answer ("the mug on the desk") also shows its
        target and anchors (`SceneModel.highlight`), and each hit its relation in words.

        Raises ViewerError when the server cannot answer (the highlight is left as it was).
        """
        try:  # no points: hits are drawn from the model
            answer = self.api.query_result_blocking(text, k)
        except ApiError as exc:
            raise ViewerError(f"query failed: {exc}") from exc
        results, self.last_match = answer["results"], answer["match"]
        relation = RelationHighlight.of_hit(results[0], self.last_match) if results else None
        with self._lock:  # as bright as it answers: a weak hit is barely lifted from the rest
            self.model.highlight(((r["id"], _strength(r)) for r in results), relation)
            held = set(self.model.objects)
        verdict = "" if self.last_match else " — **no confident match**"
        lines = [f"**{len(results)} hits** for *{html.escape(text)}*{verdict}:", ""]
        lines += [
            f"{rank}. {_hit_line(r, held, rank == 1 and self.last_match)}"
            for rank, r in enumerate(results, 1)
        ]
        self.gui.results.content = "\n".join(lines)
        return results

    def clear_query(self) -> None:
        """Drop the highlight: every object drawn plainly again."""
        with self._lock:
            self.model.clear_highlight()
        self.gui.results.content = ""

    # --- GUI --------------------------------------------------------------------------------

    def _build_gui(self) -> _Gui:
        gui = self.server.gui
        # No share button or logo: the viewer runs on private networks, often offline.
        gui.configure_theme(control_width="large", show_logo=False, show_share_button=False)
        with gui.add_folder("Connection"):
            status = gui.add_html(self._status_html())
        # A form, so that Enter in "Find" submits it (the browser's implicit form submission).
        with gui.add_form("Query") as query_form:
            query_text = gui.add_text("Find", "", hint="e.g. 'where can I sit'")
            top_k = gui.add_number("Top k", 5, min=1, max=100, step=1)
            search = gui.add_button("Search", icon=viser.Icon.SEARCH)
            clear = gui.add_button("Clear", icon=viser.Icon.X, color="gray")
            results = gui.add_markdown("")
        with gui.add_folder("Display"):
            show_boxes = gui.add_checkbox("Boxes", True)
            show_labels = gui.add_checkbox("Labels", True)
            color_by_class = gui.add_checkbox("Colour by class", False)
        with gui.add_folder("Session"):
            stats = gui.add_markdown("waiting for the first stats…")
        handles = _Gui(
            status=status,
            query_form=query_form,
            query_text=query_text,
            top_k=top_k,
            search=search,
            clear=clear,
            results=results,
            show_boxes=show_boxes,
            show_labels=show_labels,
            color_by_class=color_by_class,
            stats=stats,
        )

        @search.on_click
        def _(_event: viser.GuiEvent) -> None:
            self._search_clicked()

        @query_form.on_submit
        def _(_event: viser.GuiEvent) -> None:
            self._search_clicked()  # Enter in "Find" does what the button does

        @clear.on_click
        def _(_event: viser.GuiEvent) -> None:
            self.clear_query()

        def toggled(apply: Callable[[bool], None], checkbox: viser.GuiCheckboxHandle) -> None:
            @checkbox.on_update
            def _(_event: viser.GuiEvent) -> None:
                with self._lock:
                    apply(checkbox.value)

        toggled(self.model.set_show_boxes, show_boxes)
        toggled(self.model.set_show_labels, show_labels)
        toggled(self.model.set_color_by_class, color_by_class)
        return handles

    def _search_clicked(self) -> None:
        text = self.gui.query_text.value.strip()
        if not text:
            self.clear_query()
            return
        self.gui.search.disabled = True
        try:
            self.run_query(text, int(self.gui.top_k.value))
        except ViewerError as exc:
            self.gui.results.content = f"**{html.escape(str(exc))}**"
        finally:
            self.gui.search.disabled = False

    def _status_html(self) -> str:
        status = self.status
        # No lock (atomic reads): this runs on the event loop, which must not wait for an apply.
        seq, n_objects = self.model.seq, len(self.model.objects)
        if status.connected:
            color, headline = LIVE_RGB, "● live"
            detail = f"seq {seq} · {n_objects} objects"
        elif status.ever_connected or status.last_error:
            color, headline = DOWN_RGB, "● disconnected — reconnecting…"
            detail = html.escape(status.last_error or "")
        else:
            color, headline, detail = WAITING_RGB, "● connecting…", ""
        return (
            f'<div style="padding:0 0.5em"><div style="color:{color};font-weight:600">'
            f'{headline}</div><div style="font-size:0.8em;color:#57606a">{detail}</div></div>'
        )

    def _show_status(self) -> None:
        self.gui.status.content = self._status_html()

    def _show_stats(self) -> None:
        stats = self.status.stats
        if stats is None:
            self.gui.stats.content = "stats unavailable (server unreachable)"
            return
        latency = stats.mapping_latency_ms
        held, applied = len(self.model.objects), self.model.seq  # atomic reads, as above
        stale = "" if self.status.stats_ok else "\n\n*stale: the server is unreachable*"
        apart = (
            f" ({stats.frames_whole} whole, {stats.sightings} sightings)"
            if stats.frames_whole is not None and stats.sightings is not None
            else ""
        )
        self.gui.stats.content = (
            "| | |\n|---|---|\n"
            f"| objects | {stats.objects} (viewer {held}) |\n"
            f"| frames walked | {stats.frames}{apart} |\n"
            f"| keyframes | {stats.keyframes} |\n"
            f"| mapping p50 / p95 | {_milliseconds(latency.p50)} / "
            f"{_milliseconds(latency.p95)} |\n"
            f"| bytes in | {_megabytes(stats.bytes_in.get('total'))} |\n"
            f"| bytes out | {_megabytes(stats.bytes_out.get('total'))} |\n"
            f"| update seq | {stats.update_seq} (applied {applied}) |" + stale
        )

    # --- the device ---------------------------------------------------------------------------

    def _show_device(self, pose_bytes: bytes) -> None:
        """Frustum at the device's newest pose, and its path so far (held: self._lock)."""
        try:
            pose = validate_rigid_pose(pose_from_bytes(pose_bytes, "device_pose"), "device_pose")
        except InputError:
            return  # an optional field: a bad one is ignored, the map is not affected
        position = pose[:3, 3]
        if not self._device_path or np.linalg.norm(self._device_path[-1] - position) > 0.01:
            self._device_path.append(position)
            del self._device_path[:-MAX_PATH_POINTS]
        scene = self.server.scene
        scene.add_camera_frustum(
            "/device/frustum",
            fov=np.deg2rad(60.0),
            aspect=4 / 3,
            scale=0.25,
            color=(255, 120, 0),
            wxyz=vtf.SO3.from_matrix(pose[:3, :3]).wxyz,
            position=position,
        )
        if len(self._device_path) >= 2:
            path = np.asarray(self._device_path, np.float32)
            segments = np.stack([path[:-1], path[1:]], axis=1)
            scene.add_line_segments("/device/path", segments, (255, 160, 60), thickness=0.02)

    # --- camera ---------------------------------------------------------------------------

    def _frame_camera(self) -> None:
        """Frame the whole map, from above and aside, in the part of the canvas the GUI panel
        leaves free (caller holds the lock): the starting view of new clients and of "Reset
        View", and the view of clients already open (framed for their own canvas)."""
        bounds = self.model.bounds()
        if bounds is None:
            return
        initial = self.server.initial_camera
        width, height = ASSUMED_CANVAS_PX
        view = frame_view(bounds, self.up, initial.fov, width / height, PANEL_PX / width)
        initial.position, initial.look_at = view.position, view.look_at
        for client in self.server.get_clients().values():
            camera = client.camera
            with contextlib.suppress(AssertionError):  # its camera is not known yet
                width, height = camera.image_width, camera.image_height
                mine = frame_view(bounds, self.up, camera.fov, width / height, PANEL_PX / width)
                # position first: viser moves look_at along with the position, then we re-aim.
                camera.position = mine.position
                camera.look_at = mine.look_at

    def _show_floor(self) -> None:
        """Draw the floor grid under the map, again when its extent changed (holds the lock)."""
        floor = floor_grid(self.model.bounds(), self.up)
        if floor == self._floor:
            return
        self._floor = floor
        if floor is None:
            self.server.scene.remove_by_name(FLOOR_NODE)
            return
        self.server.scene.add_grid(
            FLOOR_NODE,
            width=floor.width,
            height=floor.height,
            plane=floor.plane,  # type: ignore[arg-type]
            cell_size=0.5,
            section_size=1.0,
            cell_color=FLOOR_CELL_RGB,
            section_color=FLOOR_SECTION_RGB,
            shadow_opacity=0.0,
            position=floor.position,
        )
