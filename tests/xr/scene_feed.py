"""A slow walk through a small synthetic room, rendered per frame in WebXR's conventions for the
fake runtime (fake_webxr.js), and the truth a test checks the runtime or a page against.

The world (world/) is Z-up; WebXR is Y-up. The runtime's tracking frame -- the
native origin of 'local-floor' until a reset -- is the world turned by the one fixed rotation
`relation_scene.TO_Y_UP` ((x, y, z) -> (x, z, -y)): same origin (on the floor, y = 0 there),
metres, right-handed. 'local' is that frame moved to the first viewer position.

Frames reach the browser over a same-origin route (`SceneFeed.route`): the runtime fetches
`<route_prefix>frame/<i>` and the feed answers from Python, rendering on demand (or ahead, in
a thread, after `prerender`). Per frame: poses as {position, orientation} in the tracking
frame, images as PNG, depth as 16-bit units of DEPTH_UNIT_M, deflated. Route fetches cost
~20 ms each plus ~0.12 s per MB on this machine; PNG and 16-bit depth keep a frame at
~40-250 KB, against 1.3 MB raw for the phone and 1.9 MB for the Quest.
"""

from __future__ import annotations

import io
import json
import struct
import threading
import zlib
from dataclasses import dataclass, field
from urllib.parse import urlsplit

import numpy as np
import open3d as o3d
import open3d.core as o3c
from PIL import Image
from relation_scene import TO_Y_UP
from xr_device import (
    CV_FROM_XR_AXES,
    NORM_DEPTH_BUFFER_FROM_NORM_VIEW,
    Phone,
    Pinhole,
    Pose,
    Quest3,
    RuntimeOptions,
)

from world import Renderer, Scene, make_scene, walk_trajectory

TRACKING_FROM_WORLD = np.eye(4)
TRACKING_FROM_WORLD[:3, :3] = TO_Y_UP
WORLD_FROM_TRACKING = TRACKING_FROM_WORLD.T.copy()

DEPTH_UNIT_M = 0.0002
"""Depth on the wire: uint16 in 0.2 mm (up to 13.1 m; 0 = no surface)."""
TEXTURE_NOISE = 0.0
"""No surface grain: it is incompressible (a PNG of 60 KB becomes 400 KB, seven times the
route's cost); the floor's planks and the shading still give every image structure."""
MAGIC = b"FXR1"


def small_room(seed: int = 0) -> Scene:
    """The living room with its floor-standing furniture and wall items only (no small things
    on surfaces, no ceiling fan): a sofa, a coffee table, an armchair, a tv stand, a
    bookshelf, lamps, plants, paintings."""
    full = make_scene("living_room", seed)
    keep = [
        o
        for o in full.objects
        if o.is_background or (o.support_id == 0 and o.category not in ("ceiling fan",))
    ]
    return Scene(full.name, full.seed, keep, full.rooms, full.doorways)


@dataclass
class SceneFrame:
    """One scene frame in the tracking frame (WebXR axes; poses are object-to-tracking)."""

    index: int
    t_s: float
    """Time on the walk's own clock (index / scene fps)."""
    viewer: np.ndarray
    """float64 [4, 4] the viewer (phone: the camera; Quest: the head)."""
    views: list[np.ndarray]
    """Pose of each XRView, in the order the runtime lists them."""
    camera: np.ndarray
    """Pose of the colour camera (phone: the view; Quest: the getUserMedia camera)."""
    camera_rgb: np.ndarray
    """uint8 [H, W, 3], row 0 the top of the image."""
    depth_sensors: list[np.ndarray]
    """Pose of each depth view (phone: the view's own)."""
    depth_m: list[np.ndarray]
    """float32 [Hd, Wd] z-depth in metres per depth view, in the buffer's layout (phone: the
    sensor's orientation; Quest: the depth view's, row 0 its top)."""
    eye_rgb: list[np.ndarray] = field(default_factory=list)
    """Quest: the passthrough each eye sees, for the display."""


class SceneTruth:
    """The room's surfaces in the tracking frame, for checks against what the browser saw."""

    def __init__(self, scene: Scene):
        self._raycaster = o3d.t.geometry.RaycastingScene()
        for obj in scene.objects:
            vertices = np.asarray(obj.mesh.vertices, np.float64) @ TO_Y_UP.T
            self._raycaster.add_triangles(
                o3c.Tensor(vertices.astype(np.float32)),
                o3c.Tensor(np.asarray(obj.mesh.triangles).astype(np.uint32)),
            )

    def distance(self, points) -> np.ndarray:
        """float64 [N] distance in metres of points [N, 3] (tracking frame) to the nearest
        surface."""
        pts = o3c.Tensor(np.asarray(points, np.float32).reshape(-1, 3))
        return self._raycaster.compute_distance(pts).numpy().astype(np.float64)

    def z_depth(self, pose: np.ndarray, pinhole: Pinhole, nv) -> np.ndarray:
        """float64 [N] z-depth in metres of the surface seen through normalized view
        coordinates [N, 2] of a view at `pose` (inf where nothing is hit)."""
        directions = pinhole.rays(nv) @ np.asarray(pose)[:3, :3].T
        rays = np.empty((len(directions), 6), np.float32)
        rays[:, :3] = np.asarray(pose)[:3, 3]
        rays[:, 3:] = directions
        return self._raycaster.cast_rays(o3c.Tensor(rays))["t_hit"].numpy().astype(np.float64)

    def surface_points(self, pose: np.ndarray, pinhole: Pinhole, nv) -> np.ndarray:
        """float64 [N, 3] tracking-frame points seen through normalized view coordinates."""
        z = self.z_depth(pose, pinhole, nv)
        local = pinhole.rays(nv) * z[:, None]
        return local @ np.asarray(pose)[:3, :3].T + np.asarray(pose)[:3, 3]


def project(pose: np.ndarray, pinhole: Pinhole, points) -> np.ndarray:
    """float64 [N, 2] pixel coordinates (u, v) of tracking-frame points in a view at `pose`."""
    pts = np.atleast_2d(np.asarray(points, np.float64))
    local = (pts - pose[:3, 3]) @ pose[:3, :3]
    z = -local[:, 2]
    return np.stack(
        [pinhole.cx + pinhole.fx * local[:, 0] / z, pinhole.cy - pinhole.fy * local[:, 1] / z], 1
    )


class SceneFeed:
    """The walk for one device: frames rendered on demand (cached), encoded for the runtime,
    served over a Playwright route, with the room's truth."""

    def __init__(
        self,
        device: Phone | Quest3,
        n_frames: int = 48,
        seed: int = 0,
        options: RuntimeOptions | None = None,
        scene_fps: float = 10.0,
    ):
        self.device = device
        self.options = options or RuntimeOptions()
        self.scene = small_room(seed)
        self.scene_fps = scene_fps
        self.truth = SceneTruth(self.scene)
        self._renderer = Renderer(self.scene)
        self.viewers = [
            TRACKING_FROM_WORLD @ p @ CV_FROM_XR_AXES
            for p in walk_trajectory(self.scene, n_frames, seed)
        ]
        self._frames: dict[int, SceneFrame] = {}
        self._encoded: dict[int, bytes] = {}
        self._lock = threading.RLock()
        self._thread: threading.Thread | None = None

    def __len__(self) -> int:
        return len(self.viewers)

    # --- frames ------------------------------------------------------------------------------

    def frame(self, index: int) -> SceneFrame:
        """Scene frame `index`, rendered once."""
        with self._lock:
            if index not in self._frames:
                self._frames[index] = self._render(index)
            return self._frames[index]

    def _render(self, index: int) -> SceneFrame:
        viewer = self.viewers[index]
        t_s = index / self.scene_fps
        if isinstance(self.device, Phone):
            phone = self.device
            rgb = self._image(viewer, phone.camera)
            aligned = self._depth(viewer, phone.depth_view)
            depth = _to_buffer_layout(aligned, phone.depth_orientation, phone.depth_size)
            return SceneFrame(index, t_s, viewer, [viewer], viewer, rgb, [viewer], [depth])
        quest = self.device
        eyes = [viewer @ offset for offset in quest.eye_from_viewer()]
        sensors = [eye @ offset for eye, offset in zip(eyes, quest.depth_from_eyes(), strict=True)]
        camera = viewer @ quest.color_from_viewer.matrix()
        shown = quest.eye_pinholes() if self.options.display else []  # only the display needs them
        small = [
            p.scaled(
                max(1, round(p.width * quest.passthrough_scale)),
                max(1, round(p.height * quest.passthrough_scale)),
            )
            for p in shown
        ]
        return SceneFrame(
            index,
            t_s,
            viewer,
            eyes,
            camera,
            self._image(camera, quest.color),
            sensors,
            [self._depth(s, p) for s, p in zip(sensors, quest.depth_pinholes(), strict=True)],
            [self._image(e, p) for e, p in zip(eyes, small, strict=False)],
        )

    def _render_view(self, pose: np.ndarray, pinhole: Pinhole):
        world_pose = WORLD_FROM_TRACKING @ pose @ CV_FROM_XR_AXES
        return self._renderer.render(world_pose, pinhole.camera(), texture_noise=TEXTURE_NOISE)

    def _image(self, pose: np.ndarray, pinhole: Pinhole) -> np.ndarray:
        return self._render_view(pose, pinhole).rgb

    def _depth(self, pose: np.ndarray, pinhole: Pinhole) -> np.ndarray:
        return self._render_view(pose, pinhole).depth_m

    def prerender(self) -> SceneFeed:
        """Render and encode every frame in a background thread (ray casting releases the
        GIL), so the route answers while the browser starts."""
        if self._thread is None:
            self._thread = threading.Thread(
                target=lambda: [self.encoded(i) for i in range(len(self))], daemon=True
            )
            self._thread.start()
        return self

    # --- the wire ----------------------------------------------------------------------------

    def encoded(self, index: int) -> bytes:
        """Scene frame `index` as the runtime reads it: b"FXR1", u32 header length, the JSON
        header, padding to 4 bytes, then the blobs the header lists (offsets from there)."""
        with self._lock:
            if index not in self._encoded:
                self._encoded[index] = self._encode(self.frame(index))
            return self._encoded[index]

    def _encode(self, frame: SceneFrame) -> bytes:
        blobs: list[tuple[str, dict, bytes]] = [
            ("camera", _shape(frame.camera_rgb), _png(frame.camera_rgb))
        ]
        blobs += [(f"eye{k}", _shape(rgb), _png(rgb)) for k, rgb in enumerate(frame.eye_rgb)]
        for k, depth in enumerate(frame.depth_m):
            units = np.clip(np.round(depth / DEPTH_UNIT_M), 0, 65535).astype("<u2")
            info = {**_shape(depth), "unit_m": DEPTH_UNIT_M}
            blobs.append((f"depth{k}", info, zlib.compress(units.tobytes(), 1)))
        table, offset = {}, 0
        for name, info, data in blobs:
            table[name] = {**info, "offset": offset, "length": len(data)}
            offset += len(data)
        header = json.dumps(
            {
                "index": frame.index,
                "t_s": frame.t_s,
                "viewer": Pose.of(frame.viewer).to_js(),
                "views": [Pose.of(v).to_js() for v in frame.views],
                "camera": Pose.of(frame.camera).to_js(),
                "depthSensors": [Pose.of(s).to_js() for s in frame.depth_sensors],
                "blobs": table,
            }
        ).encode()
        pad = b" " * (-(8 + len(header)) % 4)
        body = MAGIC + struct.pack("<I", len(header) + len(pad)) + header + pad
        return body + b"".join(data for _, _, data in blobs)

    def js_config(self) -> dict:
        """window.__fakeXRConfig for this walk (documented at the top of fake_webxr.js)."""
        first = self.viewers[0][:3, 3]
        return {
            **self.device.to_js(),
            **self.options.to_js(),
            "frameCount": len(self),
            "sceneFps": self.scene_fps,
            "localOrigin": Pose(tuple(float(v) for v in first)).to_js(),
        }

    def route(self, page) -> None:
        """Answer the runtime's frame fetches on `page`, whatever its origin. Playwright runs
        the handler on this thread while it waits in a call (wait_for_function, evaluate):
        a test that sleeps in Python starves the runtime."""
        prefix = self.options.route_prefix

        def handle(route) -> None:
            path = urlsplit(route.request.url).path
            name = path[path.index(prefix) + len(prefix) :]
            if name.startswith("frame/") and name[6:].isdigit() and int(name[6:]) < len(self):
                route.fulfill(
                    body=self.encoded(int(name[6:])),
                    content_type="application/octet-stream",
                    headers={"cache-control": "no-store"},
                )
            else:
                route.fulfill(status=404, body=f"no such fake XR resource: {name}")

        page.route(f"**{prefix}**", handle)


def _to_buffer_layout(aligned: np.ndarray, orientation: str, size: tuple[int, int]) -> np.ndarray:
    """float32 [Hd, Wd]: a view-aligned depth image rearranged so that texel (row, column) holds
    what normDepthBufferFromNormView maps there (texel centres map onto pixel centres)."""
    width, height = size
    inverse = np.linalg.inv(NORM_DEPTH_BUFFER_FROM_NORM_VIEW[orientation])
    cols, rows = np.meshgrid(np.arange(width), np.arange(height))
    nd = np.stack(
        [
            (cols + 0.5) / width,
            (rows + 0.5) / height,
            np.zeros_like(cols, float),
            np.ones_like(cols, float),
        ],
        -1,
    )
    nv = nd.reshape(-1, 4) @ inverse.T
    h, w = aligned.shape
    i = np.clip(np.floor(nv[:, 0] * w).astype(int), 0, w - 1)
    j = np.clip(np.floor(nv[:, 1] * h).astype(int), 0, h - 1)
    return aligned[j, i].reshape(height, width).astype(np.float32)


def _shape(image: np.ndarray) -> dict:
    return {"width": int(image.shape[1]), "height": int(image.shape[0])}


def _png(rgb: np.ndarray) -> bytes:
    out = io.BytesIO()
    Image.fromarray(rgb).save(out, format="PNG", compress_level=1)
    return out.getvalue()
