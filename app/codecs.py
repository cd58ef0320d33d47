"""Codecs of wire protocol v1: each encoder sits next to its decoder; pure functions, no I/O.

Decoders face untrusted bytes from the network. Every failure they can meet (garbage,
truncation, decompression bombs, wrong sizes, wrong dtypes) is reported as a `CodecError`
that names the offending field, never as a library exception, so that the server can answer
a bad frame with an error message and keep the connection open. Nothing here unpickles.

Byte order on the wire is always little-endian, arrays are row-major (C order).
"""

from __future__ import annotations

import contextlib
import io
import threading
import warnings
from collections.abc import Iterator
from typing import Any

import numpy as np
import zstandard
from PIL import Image

from app.errors import InputError

DEPTH_CODECS: tuple[str, ...] = ("zstd", "png", "raw")
"""Codecs of uint16 images (depth, detection instance ids)."""

MAX_IMAGE_SIDE_PX = 8192
"""Largest width or height any image decoder accepts (decompression-bomb guard); the
protocol's limit on image sides (`app.protocol.limits` re-exports it)."""

# Default levels of uint16 images, the device's (chosen with `python -m bench.device`); any
# level decodes the same way.
ZSTD_LEVEL = 12
"""zstd level of uint16 images; 12 shrinks instance images by a third against level 3 for
~1 ms per 640x480 frame (levels from 15 on cost several times more)."""
MAX_ZSTD_LEVEL = 22
"""Highest zstd level (the lowest is 1)."""
PNG_LEVEL = 4
"""zlib level of PNG uint16 images: on ÷5 depth in 1 cm units, 2% bigger than pillow's 6 at
less than half its CPU time (1.0 vs 2.5 ms per frame)."""

_FLOAT16_MAX = float(np.finfo(np.float16).max)


class CodecError(InputError):
    """Bytes or arrays that do not decode/encode; `field` names the wire field that is wrong."""


def _require_bytes(data: Any, field: str) -> bytes:
    """`data` as bytes, or a CodecError if the field holds something else (e.g. a str)."""
    if isinstance(data, bytes):
        return data
    if isinstance(data, bytearray | memoryview):
        return bytes(data)
    raise CodecError(field, f"expected binary data, got {type(data).__name__}")


def _require_positive_int(value: Any, field: str, name: str, upper: int) -> int:
    """`value` as an int in [1, upper]; bools and floats are refused (msgpack keeps types)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise CodecError(field, f"{name} must be an integer, got {type(value).__name__}")
    if not 1 <= int(value) <= upper:
        raise CodecError(field, f"{name} = {int(value)} is out of range 1..{upper}")
    return int(value)


# --- RGB: JPEG -----------------------------------------------------------------------------


def encode_jpeg(rgb: np.ndarray, quality: int = 85) -> bytes:
    """JPEG bytes of `rgb`, uint8 [H, W, 3]; `quality` 1..95 (pillow's scale)."""
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise CodecError("rgb", f"expected uint8 [H, W, 3], got {rgb.dtype} {list(rgb.shape)}")
    if not 1 <= quality <= 100:
        raise CodecError("rgb", f"JPEG quality {quality} is out of range 1..100")
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(buffer, format="JPEG", quality=quality)
    return buffer.getvalue()


def decode_jpeg(data: bytes, field: str = "rgb") -> np.ndarray:
    """uint8 [H, W, 3] of JPEG `data`.

    The image size is read from the header and checked against `MAX_IMAGE_SIDE_PX` before
    any pixel is decoded, so a tiny file that claims a huge image costs nothing.
    """
    with _opened_jpeg(data, field) as image:
        image.load()
        return np.asarray(image.convert("RGB"), dtype=np.uint8)


def validate_jpeg(data: bytes, field: str = "rgb") -> tuple[int, int]:
    """(width, height) of JPEG `data`, after reading its whole compressed stream.

    For consumers that need the image to be valid but not its pixels: libjpeg decodes the
    stream at 1/8 scale (the same entropy decoding, so truncated or corrupt data fails
    exactly as in `decode_jpeg`) at about a tenth of the cost of a full decode.
    """
    with _opened_jpeg(data, field) as image:
        width, height = image.size
        image.draft("RGB", (max(width // 8, 1), max(height // 8, 1)))
        image.load()
        return width, height


def jpeg_size(data: bytes, field: str = "rgb") -> tuple[int, int]:
    """(width, height) JPEG `data` declares in its header, without decoding any pixel."""
    with _opened_jpeg(data, field) as image:
        return image.size


@contextlib.contextmanager
def _opened_jpeg(data: bytes, field: str) -> Iterator[Image.Image]:
    """The opened (not yet decoded) JPEG, size-checked; pillow's errors become CodecError."""
    data = _require_bytes(data, field)
    try:
        # The size check below is ours; pillow's own bomb warning would only add noise.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            image = Image.open(io.BytesIO(data), formats=["JPEG"])
            width, height = image.size
            if width > MAX_IMAGE_SIDE_PX or height > MAX_IMAGE_SIDE_PX:
                raise CodecError(
                    field, f"JPEG of {width}x{height} exceeds {MAX_IMAGE_SIDE_PX}px per side"
                )
            yield image
    except CodecError:
        raise
    except Image.DecompressionBombError as exc:  # pillow's own guard fires first on absurd sizes
        raise CodecError(field, f"JPEG exceeds {MAX_IMAGE_SIDE_PX}px per side ({exc})") from exc
    except Exception as exc:  # pillow raises many types on corrupt input; all mean "bad data"
        raise CodecError(field, f"not a decodable JPEG ({type(exc).__name__}: {exc})") from exc


# --- uint16 images: depth and instance ids --------------------------------------------------


def encode_uint16_image(img: np.ndarray, codec: str, level: int | None = None) -> bytes:
    """Bytes of `img`, uint16 [h, w], in `codec` (one of `DEPTH_CODECS`).

    zstd: zstd of the little-endian row-major bytes; png: 16-bit greyscale PNG;
    raw: the little-endian row-major bytes. level: the codec's compression level (zstd
    1..`MAX_ZSTD_LEVEL`, default `ZSTD_LEVEL`; png 0..9, default `PNG_LEVEL`); any level
    decodes the same way.
    """
    img = np.asarray(img)
    if img.dtype != np.uint16 or img.ndim != 2 or img.size == 0:
        raise CodecError("image", f"expected uint16 [h, w], got {img.dtype} {list(img.shape)}")
    if codec not in DEPTH_CODECS:
        raise CodecError("codec", f"unknown codec {codec!r}, expected one of {DEPTH_CODECS}")
    little_endian = np.ascontiguousarray(img, dtype="<u2")
    if codec == "raw":
        return little_endian.tobytes()
    if codec == "zstd":
        return _zstd_compressor(ZSTD_LEVEL if level is None else level).compress(
            little_endian.tobytes()
        )
    buffer = io.BytesIO()
    # Pillow maps a native uint16 array to mode "I;16", which PNG stores as 16-bit greyscale.
    Image.fromarray(np.ascontiguousarray(img, dtype=np.uint16)).save(
        buffer, format="PNG", compress_level=PNG_LEVEL if level is None else level
    )
    return buffer.getvalue()


_compressors = threading.local()


def _zstd_compressor(level: int) -> zstandard.ZstdCompressor:
    """This thread's zstd compressor at `level`: building one costs more than compressing a
    small image at high levels, and one must not be used by two threads at once."""
    cache = _compressors.__dict__.setdefault("by_level", {})
    if level not in cache:
        cache[level] = zstandard.ZstdCompressor(level=level)
    return cache[level]


def decode_uint16_image(
    data: bytes,
    codec: str,
    w: int,
    h: int,
    field: str = "depth",
    max_pixels: int = 16_777_216,
) -> np.ndarray:
    """uint16 [h, w] from `data` in `codec`; the declared size must match what decodes.

    At most w*h*2 (+1) bytes are ever decompressed, so a zstd bomb cannot exhaust memory.
    PNGs must be 8- or 16-bit greyscale of exactly w x h.
    """
    data = _require_bytes(data, field)
    if not isinstance(codec, str) or codec not in DEPTH_CODECS:
        raise CodecError(field, f"unknown codec {codec!r}, expected one of {DEPTH_CODECS}")
    w = _require_positive_int(w, field, "w", MAX_IMAGE_SIDE_PX)
    h = _require_positive_int(h, field, "h", MAX_IMAGE_SIDE_PX)
    if w * h > max_pixels:
        raise CodecError(field, f"{w}x{h} = {w * h} pixels exceeds the limit of {max_pixels}")
    expected_bytes = w * h * 2
    described = f"expected {expected_bytes} for {w}x{h} uint16"

    if codec == "png":
        return _decode_uint16_png(data, w, h, field)
    if codec == "raw":
        raw = data
        if len(raw) != expected_bytes:
            raise CodecError(field, f"raw data is {len(raw)} bytes, {described}")
    else:
        raw = _bounded_zstd_decompress(data, expected_bytes, field, described)
    return np.frombuffer(raw, dtype="<u2").reshape(h, w).astype(np.uint16)


def _bounded_zstd_decompress(data: bytes, expected_bytes: int, field: str, described: str) -> bytes:
    """Exactly `expected_bytes` decompressed from `data`, reading at most one byte more."""
    try:
        declared = zstandard.frame_content_size(data)
    except zstandard.ZstdError as exc:
        raise CodecError(field, f"not zstd data ({exc})") from exc
    # -1: size not in the header (streamed frame); the bounded read below still applies.
    if declared >= 0 and declared != expected_bytes:
        raise CodecError(field, f"zstd data declares {declared} bytes, {described}")
    chunks: list[bytes] = []
    total = 0
    try:
        reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data))
        while total <= expected_bytes:
            chunk = reader.read(expected_bytes + 1 - total)
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
    except zstandard.ZstdError as exc:
        raise CodecError(field, f"corrupt zstd data ({exc})") from exc
    if total > expected_bytes:
        raise CodecError(
            field, f"zstd data decodes to more than {expected_bytes} bytes, {described}"
        )
    if total != expected_bytes:
        raise CodecError(field, f"zstd data decodes to {total} bytes, {described}")
    return b"".join(chunks)


def _decode_uint16_png(data: bytes, w: int, h: int, field: str) -> np.ndarray:
    """uint16 [h, w] of an 8- or 16-bit greyscale PNG whose header says exactly w x h."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            image = Image.open(io.BytesIO(data), formats=["PNG"])
            if image.size != (w, h):
                width, height = image.size
                raise CodecError(field, f"PNG is {width}x{height}, expected {w}x{h}")
            # "I" is how older pillow versions report 16-bit greyscale PNGs.
            if image.mode not in ("I;16", "I;16B", "I", "L"):
                raise CodecError(field, f"PNG mode {image.mode!r} is not 8- or 16-bit greyscale")
            image.load()
            pixels = np.asarray(image)
    except CodecError:
        raise
    except Image.DecompressionBombError as exc:  # only reachable if the size check changes
        raise CodecError(field, f"PNG is too large ({exc})") from exc
    except Exception as exc:  # pillow raises many types on corrupt input; all mean "bad data"
        raise CodecError(field, f"not a decodable PNG ({type(exc).__name__}: {exc})") from exc
    if pixels.shape != (h, w):
        raise CodecError(field, f"PNG decodes to shape {list(pixels.shape)}, expected [{h}, {w}]")
    if pixels.dtype.kind == "i" and (pixels.min() < 0 or pixels.max() > 0xFFFF):
        raise CodecError(field, "PNG values do not fit in uint16")
    return pixels.astype(np.uint16)


# --- poses ----------------------------------------------------------------------------------


def pose_to_bytes(pose: np.ndarray) -> bytes:
    """64 bytes: the 4x4 camera-to-world `pose` as 16 float32, little-endian, row-major."""
    pose = np.asarray(pose)
    if pose.shape != (4, 4):
        raise CodecError("pose", f"expected shape [4, 4], got {list(pose.shape)}")
    return np.ascontiguousarray(pose, dtype="<f4").tobytes()


def pose_from_bytes(data: bytes, field: str = "pose") -> np.ndarray:
    """float64 [4, 4] from 64 bytes; rigidity is checked separately (`validate_rigid_pose`)."""
    data = _require_bytes(data, field)
    if len(data) != 64:
        raise CodecError(field, f"expected 64 bytes (16 float32), got {len(data)}")
    return np.frombuffer(data, dtype="<f4").reshape(4, 4).astype(np.float64)


def validate_rigid_pose(pose: np.ndarray, field: str = "pose", tol: float = 1e-3) -> np.ndarray:
    """`pose` as float64 [4, 4] if it is a rigid transform (rotation + translation).

    Checks: finite, last row [0, 0, 0, 1], R^T R = I and det(R) = +1, each within `tol`.
    """
    try:
        pose = np.asarray(pose, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CodecError(field, f"not a numeric array ({exc})") from exc
    if pose.shape != (4, 4):
        raise CodecError(field, f"expected shape [4, 4], got {list(pose.shape)}")
    if not np.all(np.isfinite(pose)):
        raise CodecError(field, "not finite (NaN or inf)")
    if np.max(np.abs(pose[3] - np.array([0.0, 0.0, 0.0, 1.0]))) > tol:
        raise CodecError(field, f"last row is {pose[3].tolist()}, expected [0, 0, 0, 1]")
    rotation = pose[:3, :3]
    orthonormality_error = float(np.max(np.abs(rotation.T @ rotation - np.eye(3))))
    if orthonormality_error > tol:
        raise CodecError(
            field,
            f"rotation is not orthonormal (max |R^T R - I| = {orthonormality_error:.3g} > {tol:g})",
        )
    determinant = float(np.linalg.det(rotation))
    if abs(determinant - 1.0) > tol:
        raise CodecError(
            field, f"rotation is a reflection (det(R) = {determinant:.3f}, expected +1)"
        )
    return pose


# --- float16 payloads of downstream deltas --------------------------------------------------


def _to_float16_checked(values: np.ndarray, field: str) -> np.ndarray:
    """`values` as little-endian float16, refusing NaN/inf and values float16 cannot hold."""
    values = np.asarray(values)
    if values.dtype.kind not in "fiu":
        raise CodecError(field, f"expected numbers, got dtype {values.dtype}")
    as_float = values.astype(np.float64)
    if not np.all(np.isfinite(as_float)):
        raise CodecError(field, "not finite (NaN or inf)")
    if as_float.size and np.max(np.abs(as_float)) > _FLOAT16_MAX:
        raise CodecError(field, f"values beyond +-{_FLOAT16_MAX:g} do not fit in float16")
    return np.ascontiguousarray(as_float, dtype="<f2")


def _from_float16_checked(data: bytes, field: str) -> np.ndarray:
    """Native float16 values of little-endian `data`; NaN/inf refused."""
    values = np.frombuffer(data, dtype="<f2").astype(np.float16)
    if not np.all(np.isfinite(values)):
        raise CodecError(field, "contains NaN or inf")
    return values


def float16_points_to_bytes(points: np.ndarray) -> bytes:
    """6*N bytes: `points` [N, 3] (metres) as little-endian float16, row-major."""
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise CodecError("points", f"expected shape [N, 3], got {list(points.shape)}")
    return _to_float16_checked(points, "points").tobytes()


def float16_points_from_bytes(data: bytes, field: str) -> np.ndarray:
    """float16 [N, 3] from 6*N bytes; kept at wire precision (convert for math)."""
    data = _require_bytes(data, field)
    if len(data) % 6:
        raise CodecError(field, f"{len(data)} bytes is not a multiple of 6 (3 float16 per point)")
    return _from_float16_checked(data, field).reshape(-1, 3)


def float16_vector_to_bytes(vector: np.ndarray) -> bytes:
    """2*d bytes: `vector` [d] (an embedding) as little-endian float16."""
    vector = np.asarray(vector)
    if vector.ndim != 1:
        raise CodecError("embedding", f"expected shape [d], got {list(vector.shape)}")
    return _to_float16_checked(vector, "embedding").tobytes()


def float16_vector_from_bytes(data: bytes, dim: int, field: str) -> np.ndarray:
    """float16 [dim] from 2*dim bytes; kept at wire precision (convert for math)."""
    data = _require_bytes(data, field)
    if isinstance(dim, bool) or not isinstance(dim, int) or dim < 1:
        raise CodecError(field, f"embedding dimension must be a positive integer, got {dim!r}")
    if len(data) != 2 * dim:
        raise CodecError(field, f"{len(data)} bytes, expected {2 * dim} for {dim} float16")
    return _from_float16_checked(data, field)
