"""The server's per-frame budget: refused from declared sizes and counts, before decoding,
with a LimitError naming the setting and its flag."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from app import codecs
from app.errors import InputError
from app.protocol import FrameBudget, LimitError, parse_frame, unpack_frame_message
from app.protocol.limits import FRAME_LIMITS

W, H = 80, 60


def frame(w=W, h=H, depth_w=W, depth_h=H, instances=1, depth_data=None) -> dict:
    ids = np.zeros((h, w), np.uint16)
    ids[: min(instances, h), 0] = np.arange(1, min(instances, h) + 1)
    depth = depth_data or codecs.encode_uint16_image(
        np.full((depth_h, depth_w), 1000, np.uint16), "zstd"
    )
    return {
        "type": "frame",
        "seq": 3,
        "t": 0.0,
        "pose": codecs.pose_to_bytes(np.eye(4)),
        "intrinsics": [50.0, 50.0, w / 2, h / 2],
        "rgb": {"codec": "jpeg", "data": codecs.encode_jpeg(np.zeros((h, w, 3), np.uint8))},
        "depth": {"codec": "zstd", "w": depth_w, "h": depth_h, "scale": 0.001, "data": depth},
        "detections": {
            "codec": "zstd",
            "w": w,
            "h": h,
            "data": codecs.encode_uint16_image(ids, "zstd"),
            "instances": [{"id": i + 1, "label": "cup", "score": 1.0} for i in range(instances)],
        },
    }


def test_a_frame_within_the_budget_parses():
    parsed = parse_frame(frame(instances=4), budget=FrameBudget(W * H, 4))
    assert parsed.rgb_size == (W, H) and len(parsed.instances) == 4


def test_an_rgb_image_over_the_budget_is_refused_from_its_header_naming_the_flag():
    with pytest.raises(LimitError) as refused:
        parse_frame(frame(), budget=FrameBudget(W * H - 1))
    assert refused.value.field == "rgb" and refused.value.setting == "max_frame_pixels"
    assert "--max-frame-pixels" in str(refused.value) and f"{W * H - 1}" in str(refused.value)


def test_a_depth_image_over_the_budget_is_refused_before_its_data_is_read():
    # Garbage data: refused on the declared size alone, never decompressed.
    message = frame(w=8, h=6, depth_w=4096, depth_h=4096, depth_data=b"not zstd at all")
    with pytest.raises(LimitError) as refused:
        parse_frame(message, budget=FrameBudget(1920 * 1440))
    assert refused.value.field == "depth"


def test_too_many_instances_are_refused_before_the_instance_image_is_decoded():
    message = frame(instances=5)
    message["detections"]["data"] = b"garbage"  # never decoded
    with pytest.raises(LimitError) as refused:
        parse_frame(message, budget=FrameBudget(max_instances_per_frame=4))
    assert refused.value.setting == "max_instances_per_frame"
    assert "--max-instances-per-frame" in str(refused.value)


def test_without_a_budget_only_the_protocol_limits_apply():
    assert parse_frame(frame(instances=50)).rgb_size == (W, H)


def test_a_bomb_under_an_unknown_key_is_refused_while_unpacking():
    message = frame()
    message["extension"] = [[]] * (FRAME_LIMITS.max_array_len + 1)
    with pytest.raises(InputError) as refused:
        unpack_frame_message(msgpack.packb(message))
    assert "limit" in str(refused.value) and not isinstance(refused.value, LimitError)
    nested = frame()
    nested["extension"] = [[[]] * 1000] * 1000  # each list within limits, a million in all
    with pytest.raises(InputError, match="items"):
        unpack_frame_message(msgpack.packb(nested))


def test_an_unknown_key_within_the_limits_is_ignored():
    message = frame()
    message["extension"] = {"anything": [1, 2, 3]}
    assert parse_frame(unpack_frame_message(msgpack.packb(message))).seq == 3
