"""The devices the fake WebXR runtime (tests/xr/fake_webxr.js) emulates, in numbers, and the few
conventions the runtime, the scene feed and a test must agree on. Pure: no I/O, no browser.

- `Phone`: Chrome on Android (ARCore). One view (eye "none") that is the camera; `camera-access`
  gives its colour image; CPU depth at a lower resolution in the sensor's orientation, indexed
  through a non-identity `normDepthBufferFromNormView`.
- `Quest3`: two eyes; GPU depth as a texture array, one layer per eye, from each depth
  sensor's own pose and field of view, holding window-space depth rather than metres; colour
  only from getUserMedia (a passthrough camera at a calibrated pose in the viewer's space).
- `RuntimeOptions`: how the runtime paces and shows the walk.

Conventions (each cited from its spec in fake_webxr.js):
- Reference spaces: metres, +X right, +Y up, -Z forward, right-handed. A pose is a 4x4
  object-to-space matrix; a view or camera looks down its own -Z with +Y up.
- Intrinsics (`Pinhole`) are OpenCV's, as world.render uses them: pixel (u, v) has
  its centre at integer coordinates, u to the right, v down, row 0 the top of the image.
- Normalized view coordinates (depth-sensing spec): origin at the view's top-left corner,
  x right, y down, [0, 1] across the view; pixel (u, v) sits at ((u + 0.5) / width,
  (v + 0.5) / height) and the projection's NDC is (2 x - 1, 1 - 2 y).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from world.render import Camera

CV_FROM_XR_AXES = np.diag([1.0, -1.0, -1.0, 1.0])
"""A camera's OpenCV axes (x right, y down, z forward) from its WebXR axes (y up, -z forward);
its own inverse."""


# --- rigid transforms ------------------------------------------------------------------------


def quaternion_of(rotation: np.ndarray) -> np.ndarray:
    """float64 [4] unit quaternion (x, y, z, w), w >= 0, of a 3x3 rotation matrix."""
    m = np.asarray(rotation, np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s]
    q = np.asarray(q) / np.linalg.norm(q)
    return -q if q[3] < 0 else q


def rotation_of(quaternion) -> np.ndarray:
    """float64 [3, 3] rotation of a unit quaternion (x, y, z, w)."""
    x, y, z, w = np.asarray(quaternion, np.float64) / np.linalg.norm(quaternion)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def axis_angle(axis, degrees: float) -> tuple[float, float, float, float]:
    """Quaternion (x, y, z, w) turning `degrees` about `axis` (right-handed)."""
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    half = math.radians(degrees) / 2
    return (*(a * math.sin(half)), math.cos(half))


@dataclass(frozen=True)
class Pose:
    """A rigid transform as WebXR's XRRigidTransform holds it: `position` in metres and a unit
    quaternion `orientation` (x, y, z, w); as a matrix it rotates, then translates."""

    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    def matrix(self) -> np.ndarray:
        """float64 [4, 4]."""
        m = np.eye(4)
        m[:3, :3] = rotation_of(self.orientation)
        m[:3, 3] = self.position
        return m

    @classmethod
    def of(cls, matrix: np.ndarray) -> Pose:
        """The pose of a rigid 4x4 matrix."""
        m = np.asarray(matrix, np.float64)
        return cls(
            tuple(float(v) for v in m[:3, 3]), tuple(float(v) for v in quaternion_of(m[:3, :3]))
        )

    def mirrored_x(self) -> Pose:
        """The same offset for the other side of the head: x negated, the rotation reflected."""
        x, y, z = self.position
        qx, qy, qz, qw = self.orientation
        return Pose((-x, y, z), (qx, -qy, -qz, qw))

    def to_js(self) -> dict:
        return {"position": list(self.position), "orientation": list(self.orientation)}


def translation(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


# --- pinhole views ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Pinhole:
    """Intrinsics of a width x height image, OpenCV convention (module docstring)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_fov(
        cls,
        width: int,
        height: int,
        left_deg: float,
        right_deg: float,
        up_deg: float,
        down_deg: float,
    ) -> Pinhole:
        """The image of a frustum given by its four half-angles (an OpenXR XrFovf, positive)."""
        tl, tr, tu, td = (
            math.tan(math.radians(a)) for a in (left_deg, right_deg, up_deg, down_deg)
        )
        fx, fy = width / (tl + tr), height / (tu + td)
        return cls(width, height, fx, fy, fx * tl - 0.5, fy * tu - 0.5)

    def scaled(self, width: int, height: int) -> Pinhole:
        """The same frustum at another resolution."""
        sx, sy = width / self.width, height / self.height
        return Pinhole(
            width,
            height,
            self.fx * sx,
            self.fy * sy,
            (self.cx + 0.5) * sx - 0.5,
            (self.cy + 0.5) * sy - 0.5,
        )

    def mirrored(self) -> Pinhole:
        """The frustum reflected left to right (the other eye's)."""
        return Pinhole(self.width, self.height, self.fx, self.fy, self.width - 1 - self.cx, self.cy)

    def camera(self) -> Camera:
        return Camera(self.width, self.height, self.fx, self.fy, self.cx, self.cy)

    def normalized(self, uv) -> np.ndarray:
        """float64 [N, 2] normalized view coordinates of pixel coordinates [N, 2] (u, v)."""
        uv = np.atleast_2d(np.asarray(uv, np.float64))
        return (uv + 0.5) / (self.width, self.height)

    def pixels(self, nv) -> np.ndarray:
        """float64 [N, 2] pixel coordinates (u, v) of normalized view coordinates [N, 2]."""
        nv = np.atleast_2d(np.asarray(nv, np.float64))
        return nv * (self.width, self.height) - 0.5

    def rays(self, nv) -> np.ndarray:
        """float64 [N, 3] directions in the view's WebXR axes through normalized view
        coordinates, scaled so that -z = 1 (a hit distance along them is the z-depth)."""
        u, v = self.pixels(nv).T
        return np.stack([(u - self.cx) / self.fx, -(v - self.cy) / self.fy, -np.ones_like(u)], 1)

    def projection(self, near: float, far: float | None) -> np.ndarray:
        """float64 [4, 4] OpenGL projection of this view (far None: infinite), so that NDC
        (2 x - 1, 1 - 2 y) is normalized view coordinate (x, y) (module docstring)."""
        p = np.zeros((4, 4))
        p[0, 0] = 2 * self.fx / self.width
        p[0, 2] = 1 - 2 * (self.cx + 0.5) / self.width
        p[1, 1] = 2 * self.fy / self.height
        p[1, 2] = 2 * (self.cy + 0.5) / self.height - 1
        if far is None:
            p[2, 2], p[2, 3] = -1.0, -2 * near
        else:
            p[2, 2], p[2, 3] = -(far + near) / (far - near), -2 * far * near / (far - near)
        p[3, 2] = -1.0
        return p

    def to_js(self) -> dict:
        return {k: getattr(self, k) for k in ("width", "height", "fx", "fy", "cx", "cy")}


def window_depth(z_m: np.ndarray, near: float, far: float | None) -> np.ndarray:
    """OpenGL window-space depth in [0, 1] (glDepthRange 0..1) of z-depths in metres under a
    projection with these planes (far None: infinite); 0 stays 0 (no data)."""
    z = np.asarray(z_m, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = 1 - near / z if far is None else far * (z - near) / (z * (far - near))
    return np.where(z > 0, d, 0.0)


def metres_of_window_depth(d: np.ndarray, near: float, far: float | None) -> np.ndarray:
    """The inverse of `window_depth`: z-depth in metres; 0 stays 0."""
    d = np.asarray(d, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = near / (1 - d) if far is None else far * near / (far - d * (far - near))
    return np.where(d > 0, z, 0.0)


# --- depth buffer orientation ----------------------------------------------------------------


def _affine(rotation, offset) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = rotation
    m[:3, 3] = offset
    return m


NORM_DEPTH_BUFFER_FROM_NORM_VIEW: dict[str, np.ndarray] = {
    "identity": np.eye(4),
    # (x, y) of the view -> (y, 1 - x) of the buffer: a portrait view on a landscape sensor.
    "rot90": _affine([[0, 1, 0], [-1, 0, 0], [0, 0, 1]], (0, 1, 0)),
    "rot180": _affine(np.diag([-1, -1, 1]), (1, 1, 0)),
    "rot270": _affine([[0, -1, 0], [1, 0, 0], [0, 0, 1]], (1, 0, 0)),
    # Flips are half-turns about an in-plane axis (a rigid transform must not mirror).
    "flip-y": _affine(np.diag([1, -1, -1]), (0, 1, 0)),
    "flip-x": _affine(np.diag([-1, 1, -1]), (1, 0, 0)),
}
"""`normDepthBufferFromNormView` by name: normalized view -> normalized depth-buffer
coordinates, both with x right and y down over [0, 1]."""


def swaps_axes(orientation: str) -> bool:
    """True when the buffer's columns run along the view's rows."""
    return orientation in ("rot90", "rot270")


# --- the devices -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Phone:
    """Chrome on Android with ARCore: one view that is the camera (WebXR AR on a phone)."""

    profile: ClassVar[str] = "android"
    camera: Pinhole = Pinhole(480, 640, 520.0, 520.0, 241.3, 318.2)
    """The view and its camera image (portrait; principal point off centre on purpose)."""
    depth_size: tuple[int, int] = (160, 120)
    """(width, height) of the depth buffer as the sensor holds it."""
    depth_orientation: str = "rot90"
    """Key of NORM_DEPTH_BUFFER_FROM_NORM_VIEW; not "identity", so a page that ignores the
    transform reads the wrong texels."""
    depth_formats: tuple[str, ...] = ("luminance-alpha", "float32", "unsigned-short")
    preferred_depth_format: str = "luminance-alpha"
    """What an empty dataFormatPreference gets."""
    raw_value_to_meters_16bit: float = 0.001
    """16-bit formats hold millimetres (float32 holds metres: rawValueToMeters 1)."""
    features: tuple[str, ...] = (
        "viewer",
        "local",
        "local-floor",
        "camera-access",
        "depth-sensing",
        "dom-overlay",
    )
    framebuffer_scale: float = 1.0
    """The layer's framebuffer per view, relative to the view's pinhole."""
    stale_depth_scene_frames: int = 0
    """How many scene frames old the depth is when the page sets matchDepthView false."""

    @property
    def depth_view(self) -> Pinhole:
        """The depth buffer as seen from the view: the camera's frustum at the buffer's
        resolution, turned to the view's orientation."""
        w, h = self.depth_size
        return (
            self.camera.scaled(h, w)
            if swaps_axes(self.depth_orientation)
            else self.camera.scaled(w, h)
        )

    def to_js(self) -> dict:
        m = NORM_DEPTH_BUFFER_FROM_NORM_VIEW[self.depth_orientation]
        fb = self.camera.scaled(
            round(self.camera.width * self.framebuffer_scale),
            round(self.camera.height * self.framebuffer_scale),
        )
        return {
            "profile": self.profile,
            "features": list(self.features),
            "views": [
                {
                    "eye": "none",
                    "pinhole": self.camera.to_js(),
                    "viewport": [0, 0, fb.width, fb.height],
                }
            ],
            "framebuffer": [fb.width, fb.height],
            "cameraAccess": {"width": self.camera.width, "height": self.camera.height},
            "depth": {
                "usages": ["cpu-optimized"],
                "formats": list(self.depth_formats),
                "preferredFormat": self.preferred_depth_format,
                "width": self.depth_size[0],
                "height": self.depth_size[1],
                "normDepthBufferFromNormView": Pose.of(m).to_js(),
                "rawValueToMeters16": self.raw_value_to_meters_16bit,
                "encoding": "metres",
                "alignedWithView": True,
                "staleSceneFrames": self.stale_depth_scene_frames,
            },
            "userMedia": None,
            "interactionMode": "screen-space",
            "displayScale": 1.0,
        }


@dataclass(frozen=True)
class Quest3:
    """Meta Quest 3 in Quest Browser: two eyes, GPU depth per eye, colour via getUserMedia."""

    profile: ClassVar[str] = "quest"
    ipd_m: float = 0.063
    eye: Pinhole = Pinhole.from_fov(640, 640, 52.0, 42.0, 46.0, 52.0)
    """The left eye's render view (the right eye's is its mirror image)."""
    depth: Pinhole = Pinhole.from_fov(320, 320, 60.0, 50.0, 55.0, 60.0)
    """The left depth sensor view: wider than the eye's (the right one is its mirror image)."""
    depth_from_eye: Pose = Pose((0.004, -0.015, -0.05), axis_angle((1, 0.3, 0), -4.0))
    """The left depth view's pose in the left eye's space (the right one mirrored)."""
    depth_near_m: float = 0.1
    depth_far_m: float | None = None
    """None: an infinite far plane (OpenXR XR_META_environment_depth: farZ < nearZ)."""
    depth_bottom_row_first: bool = True
    """Texel row 0 of each layer holds the bottom of the depth view (GL's orientation)."""
    depth_formats: tuple[str, ...] = ("float32",)
    color: Pinhole = Pinhole(640, 480, 434.0, 434.0, 319.5, 239.5)
    """The passthrough camera's image as getUserMedia delivers it (placeholder numbers: a test
    of the page passes the page's own calibration)."""
    color_from_viewer: Pose = Pose((-0.032, -0.012, -0.07), axis_angle((1, 0, 0), -8.0))
    """The passthrough camera's pose in the viewer's space (WebXR axes: it looks down -Z)."""
    stale_depth_scene_frames: int = 1
    """How many scene frames old the depth is when the page sets matchDepthView false."""
    passthrough_scale: float = 0.25
    """Resolution of the per-eye passthrough the display composites, relative to the eye."""
    features: tuple[str, ...] = ("viewer", "local", "local-floor", "depth-sensing")

    def eye_pinholes(self) -> list[Pinhole]:
        return [self.eye, self.eye.mirrored()]

    def depth_pinholes(self) -> list[Pinhole]:
        return [self.depth, self.depth.mirrored()]

    def eye_from_viewer(self) -> list[np.ndarray]:
        return [translation(-self.ipd_m / 2, 0, 0), translation(self.ipd_m / 2, 0, 0)]

    def depth_from_eyes(self) -> list[np.ndarray]:
        return [self.depth_from_eye.matrix(), self.depth_from_eye.mirrored_x().matrix()]

    def to_js(self) -> dict:
        w, h = self.eye.width, self.eye.height
        return {
            "profile": self.profile,
            "features": list(self.features),
            "views": [
                {"eye": "left", "pinhole": self.eye.to_js(), "viewport": [0, 0, w, h]},
                {"eye": "right", "pinhole": self.eye.mirrored().to_js(), "viewport": [w, 0, w, h]},
            ],
            "framebuffer": [2 * w, h],
            "cameraAccess": None,
            "depth": {
                "usages": ["gpu-optimized"],
                "formats": list(self.depth_formats),
                "preferredFormat": self.depth_formats[0],
                "width": self.depth.width,
                "height": self.depth.height,
                "pinholes": [p.to_js() for p in self.depth_pinholes()],
                "normDepthBufferFromNormView": Pose().to_js(),
                "rawValueToMeters16": 1 / 65535,
                "encoding": "window",
                "near": self.depth_near_m,
                "far": self.depth_far_m,
                "bottomRowFirst": self.depth_bottom_row_first,
                "textureType": "texture-array",
                "alignedWithView": False,
                "staleSceneFrames": self.stale_depth_scene_frames,
            },
            "userMedia": {"width": self.color.width, "height": self.color.height},
            "interactionMode": "world-space",
            "displayScale": 0.5,
        }


@dataclass(frozen=True)
class RuntimeOptions:
    """How the runtime paces the walk and shows it (keys of window.__fakeXRConfig)."""

    xr_frames_per_scene_frame: int = 3
    """Each scene frame is held for this many XR animation frames."""
    on_walk_end: str = "hold"
    """"hold": keep delivering the last scene frame (fakeXR.done turns true); "end": end the
    session after the last one."""
    display: bool = True
    """Composite the passthrough and the app's layer onto a visible canvas."""
    display_every: int = 6
    """Composite every n-th XR frame: each composite makes the browser re-raster the page on
    a software GPU (at 1 the phone's XR frame rate fell from 60 to ~16 fps here)."""
    display_scale: float | None = None
    """The display's resolution relative to the layer's (None: the device's, 1 for the phone,
    0.5 for the Quest's two eyes side by side)."""
    prefetch: int = 6
    """Scene frames fetched ahead of the one shown."""
    require_user_activation: bool = True
    """requestSession('immersive-ar') needs transient user activation, as in Chrome."""
    video_fps: float = 30.0
    """Frames per second the getUserMedia track pushes (its content changes per scene frame)."""
    video_delay_scene_frames: int = 0
    """The video shows the scene frame this many frames behind the XR frame's pose."""
    route_prefix: str = "/__fakexr/"
    """Same-origin path the runtime fetches scene frames from (the feed answers it)."""
    extra: dict = field(default_factory=dict)
    """Anything else merged into the config as is."""

    def to_js(self) -> dict:
        return {
            "xrFramesPerSceneFrame": self.xr_frames_per_scene_frame,
            "onWalkEnd": self.on_walk_end,
            "display": self.display,
            "displayEvery": self.display_every,
            **({} if self.display_scale is None else {"displayScale": self.display_scale}),
            "prefetch": self.prefetch,
            "requireUserActivation": self.require_user_activation,
            "videoFps": self.video_fps,
            "videoDelaySceneFrames": self.video_delay_scene_frames,
            "routePrefix": self.route_prefix,
            **self.extra,
        }
