"""v1 frame messages: what the device packs and encodes, the server parses back exactly."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from app.codecs import DEPTH_CODECS, encode_jpeg, encode_uint16_image, pose_to_bytes
from app.errors import InputError
from app.protocol import Uint16Image, pack_depth_patches, pack_frame, parse_frame
from client_sim.encoder import FrameEncoder

W, H = 80, 60


def sensor() -> tuple[np.ndarray, np.ndarray]:
    """(rgb uint8 [H, W, 3], depth float32 [H, W] metres) of every encoded test frame."""
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    return rgb, rng.uniform(0.5, 4.0, (H, W)).astype(np.float32)


def encoded(ratio=5, with_detections=True) -> dict:
    rgb, depth = sensor()
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


def test_a_frame_not_mapped_skips_only_what_mapping_reads():
    full, lean = parse_frame(encoded()), parse_frame(encoded(), mapped=False)
    assert full.depth_patches and lean.depth_patches == [] and lean.rgb is None
    assert lean.rgb_size == full.rgb_size
    np.testing.assert_array_equal(lean.depth_m, full.depth_m)
    np.testing.assert_array_equal(lean.instance_ids, full.instance_ids)
    # the JPEG's stream and the patches' data are read only where the frame is mapped
    message = encoded()
    message["rgb"]["data"] = message["rgb"]["data"][: len(message["rgb"]["data"]) // 2]
    message["depth_patches"]["data"] = b"\x28\xb5\x2f\xfd garbage"
    assert parse_frame(message, mapped=False).seq == 7
    with pytest.raises(InputError, match="^rgb: "):
        parse_frame(message)


def test_a_small_detection_carries_its_box_at_full_depth_resolution():
    _, full_depth = sensor()
    frame = parse_frame(encoded(ratio=5))
    [patch] = frame.depth_patches
    assert patch.box_px == (20, 10, 50, 30)
    assert patch.depth_m.shape == (20, 30)
    np.testing.assert_allclose(patch.depth_m, full_depth[10:30, 20:50], atol=0.005 + 1e-6)


def test_no_depth_patch_at_full_depth_resolution_or_for_large_boxes():
    assert parse_frame(encoded(ratio=1)).depth_patches == []
    message = (
        FrameEncoder(5, depth_patch_max_area_px=600)
        .encode(
            seq=0,
            t=0.0,
            rgb=np.zeros((H, W, 3), np.uint8),
            depth_m=np.ones((H, W), np.float32),
            pose=np.eye(4),
            intrinsics=(70.0, 70.0, 39.5, 29.5),
            instance_ids=np.pad(np.full((20, 30), 3, np.uint16), ((10, 30), (20, 30))),
            instances=[{"id": 3, "label": "mug", "score": 0.7}],
        )
        .message
    )
    assert "depth_patches" not in message  # 600 px is not under 600


def test_detections_are_optional():
    frame = parse_frame(encoded(with_detections=False))
    assert frame.instance_ids is None and frame.instances == []


def test_a_frame_says_how_far_its_image_was_from_its_pose_when_they_were_paired():
    message = encoded()
    assert parse_frame(message).pose_skew_s is None
    message["pose_skew_s"] = -0.012
    assert parse_frame(message).pose_skew_s == pytest.approx(-0.012)


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


GARBLED_PATCHES = _set("depth_patches.data", b"\x28\xb5\x2f\xfd garbage")

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
    ("depth_patches", _set("depth_patches", [1, 2])),
    ("depth_patches.boxes[0]", _set("depth_patches.boxes", [[20, 10, 90, 30]])),
    ("depth_patches.boxes[0]", _set("depth_patches.boxes", [[20, 10, 20, 30]])),
    ("depth_patches.boxes[0]", _set("depth_patches.boxes", [[20, 10, 50.5, 30]])),
    ("depth_patches", GARBLED_PATCHES),
    ("depth_patches", _set("depth_patches.boxes", [[0, 0, W, H], [0, 0, W, H]])),
    ("pose_skew_s", _set("pose_skew_s", "0.1")),
    ("pose_skew_s", _set("pose_skew_s", float("nan"))),
    ("pose_skew_s", _set("pose_skew_s", 11.0)),
    ("pose_skew_s", _set("pose_skew_s", True)),
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
    if mutate is not GARBLED_PATCHES:  # the one check that needs the patches decoded
        with pytest.raises(InputError) as err:
            parse_frame(message, mapped=False)
        assert err.value.field.startswith(field), str(err.value)


def test_a_message_that_is_not_a_map_is_refused():
    with pytest.raises(InputError, match="message"):
        parse_frame([1, 2, 3])


# --- pack_frame -> msgpack -> parse_frame ---------------------------------------------------

uint16_images = hnp.arrays(
    np.uint16, st.tuples(st.integers(1, 12), st.integers(1, 12)), elements=st.integers(0, 65535)
)
instances = st.lists(
    st.fixed_dictionaries(
        {
            "id": st.integers(1, 65535),
            "label": st.text(max_size=20),
            "score": st.floats(0, 1, allow_nan=False),
        }
    ),
    max_size=4,
)


@settings(max_examples=40, deadline=None)
@given(
    seq=st.integers(0, 2**63 - 1),
    t=st.floats(-1e6, 1e6),
    translation=st.lists(st.floats(-100, 100, width=32), min_size=3, max_size=3),
    intrinsics=st.lists(st.floats(1, 1e4, width=32), min_size=4, max_size=4),
    depth=uint16_images,
    scale=st.floats(1e-4, 1.0),
    codec=st.sampled_from(DEPTH_CODECS),
    with_detections=st.booleans(),
    frame_instances=instances,
)
def test_a_packed_frame_survives_msgpack_and_parses_to_the_same_frame(
    seq, t, translation, intrinsics, depth, scale, codec, with_detections, frame_instances
):
    rgb = np.full((depth.shape[0] * 2, depth.shape[1] * 2, 3), 128, np.uint8)
    pose = np.eye(4)
    pose[:3, 3] = translation
    ids = np.zeros(rgb.shape[:2], np.uint16)
    ids[:1, :1] = 7
    message = pack_frame(
        seq=seq,
        t=t,
        pose=pose_to_bytes(pose),
        intrinsics=intrinsics,
        rgb_jpeg=encode_jpeg(rgb),
        depth=Uint16Image(codec, depth.shape[1], depth.shape[0], encode_uint16_image(depth, codec)),
        depth_scale_m=scale,
        detections=Uint16Image("zstd", ids.shape[1], ids.shape[0], encode_uint16_image(ids, "zstd"))
        if with_detections
        else None,
        instances=frame_instances if with_detections else (),
    )

    frame = parse_frame(msgpack.unpackb(msgpack.packb(message, use_bin_type=True), raw=False))

    assert (frame.seq, frame.t, frame.intrinsics) == (seq, t, tuple(intrinsics))
    np.testing.assert_array_equal(frame.pose, pose.astype(np.float32))
    assert frame.rgb_size == (rgb.shape[1], rgb.shape[0]) and frame.rgb.shape == rgb.shape
    np.testing.assert_array_equal(frame.depth_m, depth.astype(np.float32) * np.float32(scale))
    if with_detections:
        np.testing.assert_array_equal(frame.instance_ids, ids)
        assert frame.instances == frame_instances
    else:
        assert frame.instance_ids is None and frame.instances == []


@st.composite
def boxes_in(draw, width: int, height: int):
    """Non-empty half-open boxes (x0, y0, x1, y1) inside a width x height image."""
    x0 = draw(st.integers(0, width - 1))
    y0 = draw(st.integers(0, height - 1))
    return (x0, y0, draw(st.integers(x0 + 1, width)), draw(st.integers(y0 + 1, height)))


@settings(max_examples=40, deadline=None)
@given(
    data=st.data(),
    size=st.tuples(st.integers(1, 24), st.integers(1, 24)),
    codec=st.sampled_from(DEPTH_CODECS),
)
def test_depth_patches_survive_msgpack_and_parse_to_the_same_depth(data, size, codec):
    width, height = size
    units = data.draw(hnp.arrays(np.uint16, (height, width), elements=st.integers(0, 65535)))
    boxes = data.draw(st.lists(boxes_in(width, height), min_size=1, max_size=3))
    assume(sum((x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in boxes) <= width * height)
    message = pack_frame(
        seq=1,
        t=0.0,
        pose=pose_to_bytes(np.eye(4)),
        intrinsics=(10.0, 10.0, 1.0, 1.0),
        rgb_jpeg=encode_jpeg(np.zeros((height, width, 3), np.uint8), 90),
        depth=Uint16Image("raw", width, height, units.tobytes()),
        depth_scale_m=0.001,
        depth_patches=pack_depth_patches(units, boxes, codec),
    )
    frame = parse_frame(msgpack.unpackb(msgpack.packb(message)))
    assert [p.box_px for p in frame.depth_patches] == boxes
    for patch, (x0, y0, x1, y1) in zip(frame.depth_patches, boxes, strict=True):
        expected = units[y0:y1, x0:x1].astype(np.float32) * np.float32(0.001)
        np.testing.assert_array_equal(patch.depth_m, expected)
