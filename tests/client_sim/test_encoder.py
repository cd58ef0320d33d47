"""Device-side encoding: depth downsampling, depth units and the protocol-v1 frame message."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.codecs import (
    DEPTH_CODECS,
    decode_jpeg,
    decode_uint16_image,
    pose_from_bytes,
    validate_rigid_pose,
)
from client_sim.encoder import (
    DEFAULT_DEPTH_SCALE_M,
    FrameEncoder,
    depth_to_uint16,
    downsample_depth,
)

FEW = settings(max_examples=25, deadline=None)
INTRINSICS = (525.0, 525.0, 319.5, 239.5)


def step_depth(height_px: int = 480, width_px: int = 640, edge_col: int = 333) -> np.ndarray:
    """A wall at 1 m left of `edge_col` and one at 3 m right of it."""
    depth_m = np.full((height_px, width_px), 3.0, np.float32)
    depth_m[:, :edge_col] = 1.0
    return depth_m


def camera_pose() -> np.ndarray:
    angle = 0.3
    pose = np.eye(4)
    pose[:3, :3] = [
        [np.cos(angle), 0, np.sin(angle)],
        [0, 1, 0],
        [-np.sin(angle), 0, np.cos(angle)],
    ]
    pose[:3, 3] = [0.5, -1.2, 2.0]
    return pose


# --- downsample_depth -----------------------------------------------------------------------


def test_ratio_5_turns_640x480_into_128x96() -> None:
    for method in ("nearest", "min"):
        assert downsample_depth(step_depth(), 5, method).shape == (96, 128)


@FEW
@given(
    height_px=st.integers(1, 60),
    width_px=st.integers(1, 60),
    ratio=st.integers(1, 8),
    method=st.sampled_from(["nearest", "min"]),
    depth_m=st.floats(0.1, 10.0),
)
def test_constant_depth_stays_constant_at_floor_size(
    height_px: int, width_px: int, ratio: int, method: str, depth_m: float
) -> None:
    if ratio > min(height_px, width_px):
        return
    depth = np.full((height_px, width_px), depth_m, np.float32)
    small = downsample_depth(depth, ratio, method)
    assert small.shape == (height_px // ratio, width_px // ratio)
    assert np.all(small == np.float32(depth_m))


def test_ratio_1_returns_the_input_unchanged() -> None:
    depth_m = step_depth(8, 8, 3)
    assert downsample_depth(depth_m, 1) is depth_m


def test_nearest_takes_the_centre_pixel_of_each_block() -> None:
    ratio = 5
    depth_m = np.arange(20 * 30, dtype=np.float32).reshape(20, 30)
    small = downsample_depth(depth_m, ratio, "nearest")
    for v_d in range(small.shape[0]):
        for u_d in range(small.shape[1]):
            # the documented mapping: depth (u_d, v_d) <-> RGB (u_d*r + r//2, v_d*r + r//2)
            assert small[v_d, u_d] == depth_m[v_d * ratio + ratio // 2, u_d * ratio + ratio // 2]


def test_nearest_with_an_even_ratio_uses_the_same_mapping() -> None:
    depth_m = np.arange(8 * 8, dtype=np.float32).reshape(8, 8)
    np.testing.assert_array_equal(downsample_depth(depth_m, 4), [[18, 22], [50, 54]])


@pytest.mark.parametrize("method", ["nearest", "min"])
@pytest.mark.parametrize("edge_col", [330, 331, 332, 333, 334])
def test_a_step_edge_stays_a_step(method: str, edge_col: int) -> None:
    small = downsample_depth(step_depth(edge_col=edge_col), 5, method)
    # never an average of the two walls: every pixel is one of the two true depths
    assert set(np.unique(small).tolist()) == {1.0, 3.0}


def test_min_keeps_the_nearest_surface_of_a_block() -> None:
    depth_m = np.full((4, 4), 2.0, np.float32)
    depth_m[3, 3] = 0.75  # exact in float32
    np.testing.assert_array_equal(downsample_depth(depth_m, 2, "min"), [[2.0, 2.0], [2.0, 0.75]])


def test_min_pooling_ignores_zeros_and_non_finite_depth() -> None:
    depth_m = np.array(
        [
            [0.0, 2.5, np.nan, np.inf],
            [0.0, 0.0, -1.0, 4.0],
        ],
        dtype=np.float32,
    )
    np.testing.assert_array_equal(downsample_depth(depth_m, 2, "min"), [[2.5, 4.0]])


def test_min_of_a_block_without_valid_depth_is_zero() -> None:
    depth_m = np.array([[0.0, np.nan], [-2.0, 0.0]], dtype=np.float32)
    np.testing.assert_array_equal(downsample_depth(depth_m, 2, "min"), [[0.0]])


@pytest.mark.parametrize("ratio", [0, -2, 2.5, True, 700])
def test_bad_ratio_is_a_value_error(ratio: object) -> None:
    with pytest.raises(ValueError, match="ratio"):
        downsample_depth(step_depth(), ratio)  # type: ignore[arg-type]


def test_unknown_method_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="method"):
        downsample_depth(step_depth(), 2, "mean")


# --- depth_to_uint16 ------------------------------------------------------------------------


def test_depth_becomes_millimetres_by_default() -> None:
    depth_m = np.array([[0.0, 1.2345, 2.0, 65.535]])
    np.testing.assert_array_equal(depth_to_uint16(depth_m), [[0, 1234, 2000, 65535]])


def test_invalid_depth_becomes_zero() -> None:
    depth_m = np.array([[np.nan, np.inf, -np.inf, -1.0, 0.0]])
    np.testing.assert_array_equal(depth_to_uint16(depth_m), np.zeros((1, 5)))


def test_depth_beyond_the_uint16_range_is_clipped() -> None:
    np.testing.assert_array_equal(depth_to_uint16(np.array([[100.0]])), [[65535]])
    np.testing.assert_array_equal(depth_to_uint16(np.array([[100.0]]), 0.01), [[10000]])


def test_non_positive_depth_scale_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="scale"):
        depth_to_uint16(np.ones((2, 2)), 0.0)


# --- FrameEncoder ---------------------------------------------------------------------------


def smooth_rgb(height_px: int = 480, width_px: int = 640) -> np.ndarray:
    ys, xs = np.mgrid[0:height_px, 0:width_px]
    return np.stack([xs % 256, ys % 256, (xs + ys) % 256], axis=-1).astype(np.uint8)


def random_depth_m(height_px: int = 480, width_px: int = 640, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    depth_m = rng.uniform(0.3, 8.0, (height_px, width_px)).astype(np.float32)
    depth_m[rng.random((height_px, width_px)) < 0.05] = 0.0  # holes
    return depth_m


@pytest.mark.parametrize("codec", DEPTH_CODECS)
def test_encoded_frame_decodes_back_to_the_downsampled_depth_and_pose(codec: str) -> None:
    depth_m = random_depth_m()
    encoded = FrameEncoder(depth_downsampling_ratio=5, depth_codec=codec).encode(
        7, 1.25, smooth_rgb(), depth_m, camera_pose(), INTRINSICS
    )
    message = msgpack.unpackb(msgpack.packb(encoded.message), raw=False)
    depth = message["depth"]
    assert (depth["codec"], depth["w"], depth["h"]) == (codec, 128, 96)
    assert depth["scale"] == DEFAULT_DEPTH_SCALE_M
    units = decode_uint16_image(depth["data"], depth["codec"], depth["w"], depth["h"])
    expected_m = downsample_depth(depth_m, 5, "nearest")
    np.testing.assert_allclose(units * depth["scale"], expected_m, atol=depth["scale"] / 2 + 1e-6)
    pose = validate_rigid_pose(pose_from_bytes(message["pose"]))
    np.testing.assert_allclose(pose, camera_pose(), atol=1e-6)


def test_frame_message_has_the_protocol_v1_fields() -> None:
    message = (
        FrameEncoder().encode(3, 0.5, smooth_rgb(), random_depth_m(), np.eye(4), INTRINSICS).message
    )
    assert message["type"] == "frame"
    assert message["seq"] == 3 and message["t"] == 0.5
    assert message["intrinsics"] == list(INTRINSICS)
    assert message["rgb"]["codec"] == "jpeg"
    assert decode_jpeg(message["rgb"]["data"]).shape == (480, 640, 3)
    assert len(message["pose"]) == 64
    assert "detections" not in message


def test_full_resolution_depth_is_never_sent() -> None:
    encoded = FrameEncoder(depth_codec="raw").encode(
        0, 0.0, smooth_rgb(), random_depth_m(), np.eye(4), INTRINSICS
    )
    assert encoded.bytes_by_kind["depth"] == 128 * 96 * 2
    assert encoded.bytes_by_kind["total"] < 640 * 480 * 2


def test_min_method_reaches_the_wire() -> None:
    depth_m = step_depth()
    message = (
        FrameEncoder(depth_method="min", depth_codec="raw")
        .encode(0, 0.0, smooth_rgb(), depth_m, np.eye(4), INTRINSICS)
        .message
    )
    units = decode_uint16_image(message["depth"]["data"], "raw", 128, 96)
    expected = depth_to_uint16(downsample_depth(depth_m, 5, "min"), DEFAULT_DEPTH_SCALE_M)
    np.testing.assert_array_equal(units, expected)


def test_detections_travel_at_rgb_size_with_their_instances() -> None:
    instance_ids = np.zeros((480, 640), np.int32)
    instance_ids[100:200, 300:400] = 4
    instances = [{"id": np.int64(4), "label": "chair", "score": np.float32(0.875)}]
    encoded = FrameEncoder().encode(
        1, 0.1, smooth_rgb(), random_depth_m(), np.eye(4), INTRINSICS, instance_ids, instances
    )
    detections = msgpack.unpackb(msgpack.packb(encoded.message))["detections"]
    assert (detections["codec"], detections["w"], detections["h"]) == ("zstd", 640, 480)
    assert detections["instances"] == [{"id": 4, "label": "chair", "score": 0.875}]
    decoded = decode_uint16_image(detections["data"], "zstd", 640, 480, field="detections")
    np.testing.assert_array_equal(decoded, instance_ids)
    assert encoded.bytes_by_kind["detections"] == len(detections["data"])


def test_bytes_by_kind_payloads_add_up_to_just_under_the_packed_total() -> None:
    instance_ids = np.zeros((480, 640), np.uint16)
    instance_ids[:50, :50] = 1
    encoded = FrameEncoder().encode(
        1,
        0.1,
        smooth_rgb(),
        random_depth_m(),
        camera_pose(),
        INTRINSICS,
        instance_ids,
        [{"id": 1, "label": "lamp", "score": 0.5}],
    )
    sizes = encoded.bytes_by_kind
    assert sizes["pose"] == 64
    assert sizes["rgb"] == len(encoded.message["rgb"]["data"])
    assert sizes["depth"] == len(encoded.message["depth"]["data"])
    # the 50 x 50 px detection is small enough to carry a full-resolution depth patch
    assert sizes["depth_patches"] == len(encoded.message["depth_patches"]["data"]) > 0
    payload = (
        sizes["rgb"] + sizes["depth"] + sizes["detections"] + sizes["depth_patches"] + sizes["pose"]
    )
    assert sizes["total"] == len(msgpack.packb(encoded.message))
    # framing (keys, headers, intrinsics) is small next to the payloads
    assert payload < sizes["total"] < payload + 512


def test_depth_not_at_rgb_size_is_refused() -> None:
    with pytest.raises(ValueError, match="RGB size"):
        FrameEncoder().encode(0, 0.0, smooth_rgb(), random_depth_m(96, 128), np.eye(4), INTRINSICS)


def test_non_rigid_pose_is_refused_at_the_device() -> None:
    with pytest.raises(ValueError, match="pose"):
        FrameEncoder().encode(
            0, 0.0, smooth_rgb(), random_depth_m(), np.diag([2.0, 1, 1, 1]), INTRINSICS
        )


def test_instances_without_an_instance_image_are_refused() -> None:
    with pytest.raises(ValueError, match="instance_ids"):
        FrameEncoder().encode(
            0, 0.0, smooth_rgb(), random_depth_m(), np.eye(4), INTRINSICS, None, []
        )


@pytest.mark.parametrize(
    "kwargs",
    [
        {"depth_codec": "lz4"},
        {"detections_codec": "jpeg"},
        {"depth_method": "mean"},
        {"depth_downsampling_ratio": 0},
        {"depth_scale_m": -0.001},
    ],
)
def test_bad_encoder_settings_are_value_errors(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        FrameEncoder(**kwargs)
