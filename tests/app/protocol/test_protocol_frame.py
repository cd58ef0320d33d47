"""Decoding v1 frame messages: what the device encodes, the server reads back exactly."""

from __future__ import annotations

import numpy as np
import pytest

from app.errors import InputError
from app.protocol import parse_frame
from client_sim.encoder import FrameEncoder

W, H = 80, 60


def encoded(ratio=5, with_detections=True) -> dict:
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 4.0, (H, W)).astype(np.float32)
    ids = np.zeros((H, W), np.uint16)
    ids[10:30, 20:50] = 3
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 0.5]
    kwargs = {"instance_ids": ids, "instances": [{"id": 3, "label": "mug", "score": 0.7}]}
    return (
        FrameEncoder(ratio)
        .encode(
            seq=7,
            t=0.25,
            rgb=rgb,
            depth_m=depth,
            pose=pose,
            intrinsics=(70.0, 70.0, 39.5, 29.5),
            **(kwargs if with_detections else {}),
        )
        .message
    )


def test_an_encoded_frame_decodes_to_the_same_geometry_and_detections():
    frame = parse_frame(encoded())
    assert frame.seq == 7 and frame.rgb_size == (W, H) and frame.depth_m.shape == (H // 5, W // 5)
    assert frame.depth_m.dtype == np.float32 and frame.depth_m.min() > 0.49
    np.testing.assert_allclose(frame.pose[:3, 3], [1.0, 2.0, 0.5])
    assert frame.instances == [{"id": 3, "label": "mug", "score": 0.7}]
    assert (frame.instance_ids == 3).sum() == 20 * 30


def test_without_rgb_pixels_everything_but_the_pixels_is_the_same():
    full, lean = parse_frame(encoded()), parse_frame(encoded(), rgb_pixels=False)
    assert full.rgb is not None and full.rgb.shape == (H, W, 3) and lean.rgb is None
    assert lean.rgb_size == full.rgb_size == (W, H)
    np.testing.assert_array_equal(lean.depth_m, full.depth_m)
    np.testing.assert_array_equal(lean.instance_ids, full.instance_ids)
    bad = encoded()
    bad["rgb"]["data"] = bad["rgb"]["data"][: len(bad["rgb"]["data"]) // 2]
    with pytest.raises(InputError, match="^rgb: "):
        parse_frame(bad, rgb_pixels=False)


def test_detections_are_optional():
    frame = parse_frame(encoded(with_detections=False))
    assert frame.instance_ids is None and frame.instances == []


def _set(path: str, value):
    def mutate(msg):
        *parents, leaf = path.split(".")
        node = msg
        for p in parents:
            node = node[p]
        if value is KeyError:
            del node[leaf]
        else:
            node[leaf] = value

    return mutate


CASES = [
    ("type", _set("type", "hello")),
    ("seq", _set("seq", KeyError)),
    ("seq", _set("seq", "7")),
    ("pose", _set("pose", b"\x00" * 10)),
    ("pose", _set("pose", np.full(16, np.nan, "<f4").tobytes())),
    ("intrinsics", _set("intrinsics", [1.0, 2.0])),
    ("intrinsics", _set("intrinsics", [-1.0, 70.0, 39.5, 29.5])),
    ("rgb.codec", _set("rgb.codec", "webp")),
    ("rgb", _set("rgb.data", b"\xff\xd8\xff garbage")),
    ("depth", _set("depth.codec", "lz4")),
    ("depth", _set("depth.data", b"\x28\xb5\x2f\xfd garbage")),
    ("depth.w", _set("depth.w", 10**6)),
    ("depth.scale", _set("depth.scale", 0)),
    ("detections", _set("detections.w", 40)),
    ("detections.instances", _set("detections.instances", KeyError)),
]


@pytest.mark.parametrize(
    ("field", "mutate"), CASES, ids=[f"{f}-{i}" for i, (f, _) in enumerate(CASES)]
)
def test_a_bad_frame_raises_an_error_naming_the_field(field, mutate):
    message = encoded()
    mutate(message)
    with pytest.raises(InputError) as err:
        parse_frame(message)
    assert err.value.field.startswith(field), str(err.value)


def test_a_message_that_is_not_a_map_is_refused():
    with pytest.raises(InputError, match="message"):
        parse_frame([1, 2, 3])
