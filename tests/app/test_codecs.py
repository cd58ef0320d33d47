"""Wire codecs: every encoder/decoder pair round-trips, every corrupt input is a CodecError."""

from __future__ import annotations

import io

import numpy as np
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from PIL import Image

from app.codecs import (
    DEPTH_CODECS,
    CodecError,
    decode_jpeg,
    decode_uint16_image,
    encode_jpeg,
    encode_uint16_image,
    float16_points_from_bytes,
    float16_points_to_bytes,
    float16_vector_from_bytes,
    float16_vector_to_bytes,
    pose_from_bytes,
    pose_to_bytes,
    validate_jpeg,
    validate_rigid_pose,
)

FEW = settings(max_examples=25, deadline=None)


def rotation_from_quaternion(q: np.ndarray) -> np.ndarray:
    """3x3 rotation of a (not necessarily unit) quaternion w, x, y, z."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def rigid_pose(q: np.ndarray, translation_m: np.ndarray) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = rotation_from_quaternion(q)
    pose[:3, 3] = translation_m
    return pose


def png_bytes(img: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(img).save(buffer, format="PNG")
    return buffer.getvalue()


quaternions = hnp.arrays(np.float64, 4, elements=st.floats(-1, 1)).filter(
    lambda q: np.linalg.norm(q) > 0.1
)
translations = hnp.arrays(np.float64, 3, elements=st.floats(-100, 100))
uint16_images = hnp.arrays(
    np.uint16,
    hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=40),
    elements=st.integers(0, 65535),
)


# --- CodecError -----------------------------------------------------------------------------


def test_codec_error_is_a_value_error_that_names_its_field() -> None:
    error = CodecError("depth", "too short")
    assert isinstance(error, ValueError)
    assert error.field == "depth"
    assert str(error) == "depth: too short"


# --- JPEG -----------------------------------------------------------------------------------


def test_jpeg_round_trip_keeps_size_and_is_close() -> None:
    rng = np.random.default_rng(0)
    # A smooth image: JPEG is near-lossless on gradients, so the tolerance can be tight.
    ys, xs = np.mgrid[0:48, 0:64]
    rgb = np.stack([xs * 4, ys * 5, (xs + ys) * 2], axis=-1).astype(np.uint8)
    rgb_noisy = np.clip(rgb + rng.integers(-2, 3, rgb.shape), 0, 255).astype(np.uint8)
    decoded = decode_jpeg(encode_jpeg(rgb_noisy, quality=95))
    assert decoded.dtype == np.uint8
    assert decoded.shape == (48, 64, 3)
    assert np.mean(np.abs(decoded.astype(int) - rgb_noisy.astype(int))) < 3


@FEW
@given(width=st.integers(1, 40), height=st.integers(1, 40), seed=st.integers(0, 2**16))
def test_jpeg_round_trip_keeps_any_image_size(width: int, height: int, seed: int) -> None:
    rgb = np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)
    assert decode_jpeg(encode_jpeg(rgb)).shape == (height, width, 3)


@pytest.mark.parametrize("decode", [decode_jpeg, validate_jpeg])
def test_corrupt_jpeg_is_a_codec_error_naming_the_field(decode) -> None:
    jpeg = encode_jpeg(np.zeros((32, 32, 3), np.uint8))
    for corrupt in (b"", b"\xff\xd8garbage", jpeg[: len(jpeg) // 2], b"\x00" * 100):
        with pytest.raises(CodecError, match="^rgb: ") as info:
            decode(corrupt)
        assert info.value.field == "rgb"


@FEW
@given(seed=st.integers(0, 2**32 - 1), at=st.floats(0.05, 0.95), length=st.integers(1, 200))
def test_validating_a_jpeg_refuses_exactly_what_decoding_refuses(seed, at, length) -> None:
    rng = np.random.default_rng(seed)
    jpeg = bytearray(encode_jpeg(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)))
    start = int(at * len(jpeg))
    jpeg[start : start + length] = (
        rng.integers(0, 256, len(jpeg[start : start + length])).astype(np.uint8).tobytes()
    )

    def outcome(decode):
        try:
            decode(bytes(jpeg))
        except CodecError:
            return "refused"
        return "accepted"

    assert outcome(validate_jpeg) == outcome(decode_jpeg)


@FEW
@given(width=st.integers(1, 200), height=st.integers(1, 200))
def test_validating_a_jpeg_gives_its_size_without_keeping_pixels(width: int, height: int) -> None:
    rgb = np.random.default_rng(width * height).integers(0, 256, (height, width, 3), np.uint8)
    assert validate_jpeg(encode_jpeg(rgb)) == (width, height)


@FEW
@given(data=st.binary(max_size=300))
def test_random_bytes_are_never_a_jpeg_crash(data: bytes) -> None:
    with pytest.raises(CodecError, match="^frame.rgb: "):
        decode_jpeg(data, field="frame.rgb")


def test_png_sent_as_jpeg_is_refused() -> None:
    with pytest.raises(CodecError, match="rgb"):
        decode_jpeg(png_bytes(np.zeros((4, 4), np.uint8)))


@pytest.mark.parametrize("side_px", [8193, 9000, 60000])
def test_jpeg_claiming_a_huge_image_is_refused_before_decoding(side_px: int) -> None:
    jpeg = bytearray(encode_jpeg(np.zeros((8, 8, 3), np.uint8)))
    # Patch the SOF0 frame header's height/width (big-endian uint16s); the pixel data stays
    # 8x8, so only a decoder that checks the header first refuses it cheaply.
    sof = jpeg.index(b"\xff\xc0")
    jpeg[sof + 5 : sof + 9] = side_px.to_bytes(2, "big") * 2
    with pytest.raises(CodecError, match="rgb: .*exceeds 8192px per side"):
        decode_jpeg(bytes(jpeg))


def test_jpeg_decoder_refuses_non_bytes() -> None:
    with pytest.raises(CodecError, match="rgb: expected binary data, got str"):
        decode_jpeg("not bytes")  # type: ignore[arg-type]


# --- uint16 images --------------------------------------------------------------------------


@FEW
@given(img=uint16_images, codec=st.sampled_from(DEPTH_CODECS))
def test_uint16_image_round_trips_exactly_in_every_codec(img: np.ndarray, codec: str) -> None:
    h, w = img.shape
    decoded = decode_uint16_image(encode_uint16_image(img, codec), codec, w, h)
    assert decoded.dtype == np.uint16
    np.testing.assert_array_equal(decoded, img)
    decoded[0, 0] = 1  # writable, not a view of the message bytes


def test_raw_and_zstd_carry_little_endian_row_major_bytes() -> None:
    img = np.array([[1, 2, 3], [256, 65535, 0]], dtype=np.uint16)
    expected = b"\x01\x00\x02\x00\x03\x00\x00\x01\xff\xff\x00\x00"
    assert encode_uint16_image(img, "raw") == expected
    assert zstandard.ZstdDecompressor().decompress(encode_uint16_image(img, "zstd")) == expected


def test_png_codec_writes_a_16_bit_greyscale_png() -> None:
    img = np.array([[0, 1000], [40000, 65535]], dtype=np.uint16)
    decoded = Image.open(io.BytesIO(encode_uint16_image(img, "png")))
    assert decoded.format == "PNG"
    assert decoded.mode.startswith("I")
    np.testing.assert_array_equal(np.asarray(decoded), img)


def test_8_bit_greyscale_png_is_accepted_as_uint16() -> None:
    img = np.array([[0, 7, 255]], dtype=np.uint8)
    np.testing.assert_array_equal(decode_uint16_image(png_bytes(img), "png", 3, 1), img)


def test_unknown_codec_is_refused() -> None:
    with pytest.raises(CodecError, match="depth: unknown codec 'lz4'"):
        decode_uint16_image(b"\x00\x00", "lz4", 1, 1)


@pytest.mark.parametrize("w, h", [(0, 4), (4, -1), (4.0, 4), (True, 4), (9000, 1)])
def test_bad_declared_dimensions_are_refused(w: object, h: object) -> None:
    with pytest.raises(CodecError, match="depth: "):
        decode_uint16_image(b"\x00" * 32, "raw", w, h)  # type: ignore[arg-type]


def test_declared_size_over_the_pixel_limit_is_refused() -> None:
    with pytest.raises(CodecError, match="depth: .*exceeds the limit"):
        decode_uint16_image(b"", "zstd", 5000, 5000)


def test_zstd_data_of_the_wrong_size_names_field_and_sizes() -> None:
    data = zstandard.ZstdCompressor().compress(b"\x00" * 1000)
    with pytest.raises(CodecError) as info:
        decode_uint16_image(data, "zstd", 128, 96)
    assert str(info.value).startswith("depth: ")
    assert "1000 bytes" in str(info.value)
    assert "expected 24576 for 128x96 uint16" in str(info.value)


def test_zstd_data_without_declared_size_is_still_checked() -> None:
    # A streamed frame does not declare its size; the bounded read must catch the mismatch.
    compressor = zstandard.ZstdCompressor(write_content_size=False)
    data = compressor.compress(b"\x00" * 1000)
    with pytest.raises(CodecError, match="depth: zstd data decodes to 1000 bytes"):
        decode_uint16_image(data, "zstd", 128, 96)


def test_zstd_bomb_is_refused_without_decompressing_it() -> None:
    bomb = zstandard.ZstdCompressor(write_content_size=False).compress(b"\x00" * 64_000_000)
    assert len(bomb) < 10_000
    with pytest.raises(CodecError, match="depth: zstd data decodes to more than 24576 bytes"):
        decode_uint16_image(bomb, "zstd", 128, 96)


def test_truncated_zstd_is_a_codec_error() -> None:
    img = np.random.default_rng(1).integers(0, 65535, (96, 128), dtype=np.uint16)
    data = encode_uint16_image(img, "zstd")
    for truncated in (data[: len(data) // 2], data[:-1], data[:6], b""):
        with pytest.raises(CodecError, match="^depth: "):
            decode_uint16_image(truncated, "zstd", 128, 96)


@FEW
@given(data=st.binary(max_size=200), codec=st.sampled_from(DEPTH_CODECS))
def test_random_bytes_are_never_a_uint16_crash(data: bytes, codec: str) -> None:
    with pytest.raises(CodecError, match="^detections: "):
        decode_uint16_image(data, codec, 64, 48, field="detections")


def test_raw_data_of_the_wrong_length_is_refused() -> None:
    with pytest.raises(CodecError, match="depth: raw data is 10 bytes, expected 24 for 4x3"):
        decode_uint16_image(b"\x00" * 10, "raw", 4, 3)


def test_png_of_the_wrong_dimensions_is_refused() -> None:
    data = encode_uint16_image(np.zeros((10, 20), np.uint16), "png")
    with pytest.raises(CodecError, match="depth: PNG is 20x10, expected 20x11"):
        decode_uint16_image(data, "png", 20, 11)


def test_colour_png_is_refused_as_depth() -> None:
    with pytest.raises(CodecError, match="depth: PNG mode 'RGB'"):
        decode_uint16_image(png_bytes(np.zeros((2, 2, 3), np.uint8)), "png", 2, 2)


def test_truncated_png_is_a_codec_error() -> None:
    img = np.random.default_rng(2).integers(0, 65535, (30, 40), dtype=np.uint16)
    data = encode_uint16_image(img, "png")
    with pytest.raises(CodecError, match="^depth: "):
        decode_uint16_image(data[: len(data) // 2], "png", 40, 30)


# --- poses ----------------------------------------------------------------------------------


@FEW
@given(q=quaternions, translation_m=translations)
def test_pose_round_trips_through_64_bytes(q: np.ndarray, translation_m: np.ndarray) -> None:
    pose = rigid_pose(q, translation_m)
    data = pose_to_bytes(pose)
    assert len(data) == 64
    decoded = pose_from_bytes(data)
    assert decoded.dtype == np.float64
    np.testing.assert_allclose(decoded, pose.astype(np.float32), rtol=0, atol=0)
    # float32 precision keeps any real rotation rigid at the validator's tolerance.
    validate_rigid_pose(decoded)


def test_pose_bytes_are_row_major_little_endian_float32() -> None:
    pose = np.eye(4)
    pose[0, 3] = 2.0
    values = np.frombuffer(pose_to_bytes(pose), dtype="<f4")
    assert values[3] == 2.0  # row 0, column 3


@pytest.mark.parametrize("length", [0, 63, 65, 128])
def test_pose_of_the_wrong_length_is_refused(length: int) -> None:
    with pytest.raises(CodecError, match=f"pose: expected 64 bytes .*got {length}"):
        pose_from_bytes(b"\x00" * length)


def test_nan_pose_is_refused_as_not_finite() -> None:
    pose = np.eye(4)
    pose[1, 3] = np.nan
    with pytest.raises(CodecError, match=r"pose: not finite \(NaN or inf\)"):
        validate_rigid_pose(pose_from_bytes(pose_to_bytes(pose)))


def test_non_orthonormal_pose_is_refused() -> None:
    pose = np.eye(4)
    pose[0, 0] = 1.1  # a scale, not a rotation
    with pytest.raises(CodecError, match="pose: rotation is not orthonormal"):
        validate_rigid_pose(pose)


def test_reflection_pose_is_refused() -> None:
    pose = np.diag([1.0, 1.0, -1.0, 1.0])  # orthonormal but det = -1
    with pytest.raises(CodecError, match="pose: rotation is a reflection"):
        validate_rigid_pose(pose)


def test_pose_with_a_bad_last_row_is_refused() -> None:
    pose = np.eye(4)
    pose[3, 0] = 0.5
    with pytest.raises(CodecError, match="frame.pose: last row"):
        validate_rigid_pose(pose, field="frame.pose")


def test_pose_of_the_wrong_shape_is_refused() -> None:
    with pytest.raises(CodecError, match="pose: expected shape"):
        validate_rigid_pose(np.eye(3))


# --- float16 payloads -----------------------------------------------------------------------

finite_float16 = st.floats(-60000, 60000, width=16, allow_nan=False, allow_infinity=False)


@FEW
@given(
    points=hnp.arrays(
        np.float16, st.tuples(st.integers(0, 50), st.just(3)), elements=finite_float16
    )
)
def test_float16_points_round_trip_exactly(points: np.ndarray) -> None:
    data = float16_points_to_bytes(points)
    assert len(data) == 6 * len(points)
    np.testing.assert_array_equal(float16_points_from_bytes(data, "points"), points)


def test_float32_points_round_trip_to_float16_precision() -> None:
    points_m = np.random.default_rng(3).uniform(-10, 10, (100, 3)).astype(np.float32)
    decoded = float16_points_from_bytes(float16_points_to_bytes(points_m), "points")
    np.testing.assert_allclose(decoded.astype(np.float32), points_m, atol=10 * 2**-10)


def test_float16_points_of_a_bad_length_are_refused() -> None:
    with pytest.raises(CodecError, match="upserts.points: 7 bytes is not a multiple of 6"):
        float16_points_from_bytes(b"\x00" * 7, "upserts.points")


def test_float16_points_carrying_nan_are_refused() -> None:
    data = np.array([[0, 0, np.nan]], dtype="<f2").tobytes()
    with pytest.raises(CodecError, match="points: contains NaN or inf"):
        float16_points_from_bytes(data, "points")


def test_points_beyond_float16_range_are_refused_at_encoding() -> None:
    with pytest.raises(CodecError, match="points: values beyond"):
        float16_points_to_bytes(np.array([[1e6, 0, 0]]))


@FEW
@given(vector=hnp.arrays(np.float16, st.integers(1, 64), elements=finite_float16))
def test_float16_vector_round_trips_exactly(vector: np.ndarray) -> None:
    data = float16_vector_to_bytes(vector)
    decoded = float16_vector_from_bytes(data, len(vector), "embedding")
    np.testing.assert_array_equal(decoded, vector)


def test_float16_vector_of_the_wrong_dimension_is_refused() -> None:
    data = float16_vector_to_bytes(np.ones(384, np.float32))
    with pytest.raises(CodecError, match="upserts.embedding: 768 bytes, expected 1024"):
        float16_vector_from_bytes(data, 512, "upserts.embedding")


@pytest.mark.parametrize(("codec", "level"), [("zstd", 1), ("zstd", 12), ("png", 0), ("png", 9)])
def test_any_compression_level_decodes_to_the_same_image(codec: str, level: int) -> None:
    img = np.random.default_rng(level).integers(0, 5000, (24, 32)).astype(np.uint16)
    data = encode_uint16_image(img, codec, level)
    np.testing.assert_array_equal(decode_uint16_image(data, codec, 32, 24), img)


def test_threads_compressing_at_once_each_get_the_bytes_of_their_own_image() -> None:
    from concurrent.futures import ThreadPoolExecutor

    images = [np.full((64, 64), i, np.uint16) + np.arange(64, dtype=np.uint16) for i in range(32)]
    with ThreadPoolExecutor(4) as pool:
        encoded = list(pool.map(lambda img: encode_uint16_image(img, "zstd", 12), images))
    for img, data in zip(images, encoded, strict=True):
        np.testing.assert_array_equal(decode_uint16_image(data, "zstd", 64, 64), img)
