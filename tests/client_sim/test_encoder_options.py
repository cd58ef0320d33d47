"""Upstream-size options of the device encoder: depth step, JPEG Huffman tables, zstd level.

Each option changes only bytes on the wire, within protocol v1: the server decodes every
setting with the same `parse_frame`.
"""

from __future__ import annotations

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.codecs import DEPTH_CODECS, decode_jpeg
from app.protocol import parse_frame
from client_sim.encoder import FrameEncoder, downsample_depth

FEW = settings(max_examples=20, deadline=None)
INTRINSICS = (70.0, 70.0, 39.5, 29.5)
W, H = 80, 60


def noisy_depth_m(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    depth_m = rng.uniform(0.3, 8.0, (H, W)).astype(np.float32)
    depth_m[rng.random((H, W)) < 0.05] = 0.0  # holes
    return depth_m


def textured_rgb(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:H, 0:W]
    base = np.stack([xs * 3, ys * 4, (xs + ys) * 2], axis=-1)
    return np.clip(base + rng.normal(0, 12, base.shape), 0, 255).astype(np.uint8)


def instance_image() -> np.ndarray:
    ids = np.zeros((H, W), np.uint16)
    ids[10:30, 20:50] = 3
    ids[35:55, 5:40] = 9
    return ids


def over_the_wire(encoder: FrameEncoder, depth_m: np.ndarray, with_detections: bool = False):
    kwargs = {}
    if with_detections:
        kwargs = {
            "instance_ids": instance_image(),
            "instances": [
                {"id": 3, "label": "mug", "score": 0.7},
                {"id": 9, "label": "book", "score": 0.6},
            ],
        }
    encoded = encoder.encode(0, 0.0, textured_rgb(), depth_m, np.eye(4), INTRINSICS, **kwargs)
    message = msgpack.unpackb(msgpack.packb(encoded.message, use_bin_type=True), raw=False)
    return encoded, parse_frame(message)


@FEW
@given(
    step_mm=st.sampled_from([1.0, 2.0, 2.5, 4.0, 5.0, 10.0]),
    codec=st.sampled_from(DEPTH_CODECS),
    ratio=st.integers(1, 5),
    seed=st.integers(0, 2**16),
)
def test_depth_comes_back_within_half_a_step_through_the_server_decoder(
    step_mm: float, codec: str, ratio: int, seed: int
) -> None:
    depth_m = noisy_depth_m(seed)
    encoder = FrameEncoder(ratio, depth_codec=codec, depth_scale_m=step_mm / 1000)
    encoded, frame = over_the_wire(encoder, depth_m)
    assert encoded.message["depth"]["scale"] == step_mm / 1000
    expected_m = downsample_depth(depth_m, ratio)
    np.testing.assert_allclose(frame.depth_m, expected_m, atol=step_mm / 2000 + 1e-5)
    np.testing.assert_array_equal(frame.depth_m == 0, expected_m == 0)  # holes stay holes


def test_a_coarser_depth_step_sends_fewer_bytes_of_noisy_depth() -> None:
    depth_m = noisy_depth_m()
    sizes = [
        FrameEncoder(1, depth_codec="png", depth_scale_m=step_m)
        .encode(0, 0.0, textured_rgb(), depth_m, np.eye(4), INTRINSICS)
        .bytes_by_kind["depth"]
        for step_m in (0.001, 0.005, 0.01)
    ]
    assert sizes[0] > sizes[1] > sizes[2]


def test_optimised_huffman_tables_are_lossless_and_smaller() -> None:
    depth_m = noisy_depth_m()
    plain, plain_frame = over_the_wire(FrameEncoder(jpeg_quality=60, jpeg_optimize=False), depth_m)
    optimised, optimised_frame = over_the_wire(
        FrameEncoder(jpeg_quality=60, jpeg_optimize=True), depth_m
    )
    np.testing.assert_array_equal(optimised_frame.rgb, plain_frame.rgb)
    assert optimised.bytes_by_kind["rgb"] < plain.bytes_by_kind["rgb"]


def test_lower_jpeg_quality_sends_a_smaller_image_of_the_same_size() -> None:
    depth_m = noisy_depth_m()
    high, _ = over_the_wire(FrameEncoder(jpeg_quality=90), depth_m)
    low, low_frame = over_the_wire(FrameEncoder(jpeg_quality=40), depth_m)
    assert low.bytes_by_kind["rgb"] < high.bytes_by_kind["rgb"]
    assert decode_jpeg(low.message["rgb"]["data"]).shape == (H, W, 3)
    assert low_frame.rgb_size == (W, H)


@pytest.mark.parametrize("level", [1, 12, 22])
def test_any_zstd_level_decodes_to_the_same_depth_and_instances(level: int) -> None:
    depth_m = noisy_depth_m()
    encoder = FrameEncoder(2, depth_codec="zstd", detections_codec="zstd", zstd_level=level)
    _, frame = over_the_wire(encoder, depth_m, with_detections=True)
    reference = FrameEncoder(2, depth_codec="raw", detections_codec="raw")
    _, reference_frame = over_the_wire(reference, depth_m, with_detections=True)
    np.testing.assert_array_equal(frame.depth_m, reference_frame.depth_m)
    np.testing.assert_array_equal(frame.instance_ids, instance_image())


@pytest.mark.parametrize(
    ("kwargs", "named"),
    [
        ({"jpeg_quality": 0}, "jpeg_quality"),
        ({"jpeg_quality": 101}, "jpeg_quality"),
        ({"jpeg_quality": 50.5}, "jpeg_quality"),
        ({"jpeg_quality": True}, "jpeg_quality"),
        ({"zstd_level": 0}, "zstd_level"),
        ({"zstd_level": 23}, "zstd_level"),
        ({"depth_scale_m": 0.0}, "depth_scale_m"),
        ({"depth_scale_m": 2.0}, "depth_scale_m"),  # the protocol allows (0, 1] m per unit
        ({"depth_scale_m": float("nan")}, "depth_scale_m"),
        ({"depth_scale_m": "0.005"}, "depth_scale_m"),
    ],
)
def test_bad_upstream_options_are_value_errors_naming_the_option(kwargs: dict, named: str) -> None:
    with pytest.raises(ValueError, match=named):
        FrameEncoder(**kwargs)


# --- the device command's flags -------------------------------------------------------------


def device_args(*flags: str):
    from app.cli import build_parser

    return build_parser().parse_args(
        ["device", "--server", "http://127.0.0.1:9", "--create", *flags]
    )


def test_device_flags_default_to_the_encoder_defaults() -> None:
    from app.cli.device import encoder_options_from_args

    options = encoder_options_from_args(device_args())
    encoder, default = FrameEncoder(**options), FrameEncoder()
    for name in ("jpeg_quality", "jpeg_optimize", "depth_codec", "detections_codec", "zstd_level"):
        assert getattr(encoder, name) == getattr(default, name)
    assert encoder.depth_scale_m == pytest.approx(default.depth_scale_m)


def test_device_flags_reach_the_encoder_options() -> None:
    from app.cli.device import encoder_options_from_args

    options = encoder_options_from_args(
        device_args(
            "--jpeg-quality", "70", "--no-jpeg-optimize", "--depth-codec", "zstd",
            "--depth-step-mm", "2", "--detections-codec", "png", "--zstd-level", "3",
        )
    )  # fmt: skip
    assert options == {
        "jpeg_quality": 70,
        "jpeg_optimize": False,
        "depth_codec": "zstd",
        "depth_scale_m": 0.002,
        "detections_codec": "png",
        "zstd_level": 3,
    }


def test_a_bad_encoding_flag_stops_the_device_command_before_connecting(capsys) -> None:
    from app.cli.device import run

    assert run(device_args("--jpeg-quality", "0")) == 2
    assert "jpeg_quality" in capsys.readouterr().err
