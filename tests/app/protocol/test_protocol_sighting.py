"""The sightings extension's `sighting` message: what the device packs, the server parses back
exactly, within the same limits as a frame; the engine checks what only it knows."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from app.codecs import DEPTH_CODECS, encode_uint16_image, pose_to_bytes
from app.errors import InputError
from app.mapping.engine import MappingEngine, make_perception
from app.protocol import FrameBudget, LimitError, Uint16Image, pack_sighting, parse_sighting
from client_sim.encoder import FrameEncoder

W, H = 640, 480


def encoded() -> dict:
    """A 640x480 frame with a mug (id 3) and a chair (id 5) seen as a sighting; id 9 is
    listed but too thin for the coarse instance image."""
    depth = np.full((H, W), 3.0, np.float32)
    depth[100:200, 300:380] = 1.2
    ids = np.zeros((H, W), np.uint16)
    ids[100:200, 300:380] = 3
    ids[250:470, 20:200] = 5
    ids[0:2, 0:2] = 9
    instances = [
        {"id": 3, "label": "mug", "score": 0.7},
        {"id": 5, "label": "chair", "score": 0.9},
        {"id": 9, "label": "pen", "score": 0.4},
    ]
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 0.5]
    return (
        FrameEncoder()
        .encode_sighting(
            seq=11,
            t=2.2,
            depth_m=depth,
            pose=pose,
            intrinsics=(525.0, 525.0, 319.5, 239.5),
            instance_ids=ids,
            instances=instances,
        )
        .message
    )


def test_a_sighting_carries_coarse_detections_and_depth_in_about_a_kilobyte():
    message = encoded()
    assert len(msgpack.packb(message, use_bin_type=True)) < 1500
    sighting = parse_sighting(msgpack.unpackb(msgpack.packb(message, use_bin_type=True)))
    assert sighting.seq == 11 and sighting.rgb_size == (W, H) and sighting.rgb is None
    assert sighting.instance_ids.shape == (H // 8, W // 8)
    assert sighting.depth_m.shape == (H // 20, W // 20)
    # a block's nearest depth: the mug's blocks read the mug, not the wall behind it
    assert sighting.depth_m.min() == pytest.approx(1.2)
    assert [i["label"] for i in sighting.instances] == ["mug", "chair"]  # the pen fell through
    assert set(np.unique(sighting.instance_ids)) == {0, 3, 5}


def test_the_engine_takes_a_sighting_at_coarse_resolution(encoder):
    engine = MappingEngine(encoder, backend=make_perception())
    sent = engine.validate_sighting(parse_sighting(encoded()))
    assert sorted(d.label for d in sent.detections) == ["chair", "mug"]


def _without(key):
    def mutate(message):
        del message[key]

    return mutate


def _set(path, value):
    def mutate(message):
        *parents, leaf = path.split(".")
        node = message
        for p in parents:
            node = node[p]
        node[leaf] = value

    return mutate


@pytest.mark.parametrize(
    ("field", "mutate"),
    [
        ("type", _set("type", "frame")),
        ("size", _without("size")),
        ("size", _set("size", [640])),
        ("size", _set("size", [640.0, 480.0])),
        ("size", _set("size", [0, 480])),
        ("detections", _without("detections")),
        ("detections", _set("detections", "none")),
        ("detections", _set("detections.data", b"not zstd")),
        ("depth.scale", _set("depth.scale", 0)),
        ("pose", _set("pose", b"\x00" * 64)),
    ],
)
def test_a_bad_sighting_raises_an_error_naming_the_field(field, mutate):
    message = encoded()
    mutate(message)
    with pytest.raises(InputError) as err:
        parse_sighting(message)
    assert err.value.field.startswith(field), str(err.value)


@pytest.mark.parametrize(
    ("field", "budget"),
    [
        ("size", FrameBudget(max_frame_pixels=W * H - 1)),
        ("detections.instances", FrameBudget(max_instances_per_frame=1)),
    ],
)
def test_a_sighting_over_the_servers_budget_is_refused_naming_the_flag(field, budget):
    with pytest.raises(LimitError) as err:
        parse_sighting(encoded(), budget=budget)
    assert err.value.field == field and "--max-" in str(err.value)


@pytest.mark.parametrize(
    ("field", "mutate"),
    [
        ("detections", lambda s: setattr(s, "instance_ids", s.instance_ids[:, :-1].copy())),
        ("depth", lambda s: setattr(s, "depth_m", s.depth_m[:-1].copy())),
        ("detections.instances", lambda s: s.instances.pop(0)),  # the mug's id unlabelled
    ],
)
def test_the_engine_refuses_coarse_images_that_do_not_fit_the_rgb_size(encoder, field, mutate):
    sighting = parse_sighting(encoded())
    mutate(sighting)
    with pytest.raises(InputError) as err:
        MappingEngine(encoder, backend=make_perception()).validate_sighting(sighting)
    assert err.value.field == field, str(err.value)


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
    rgb_size=st.tuples(st.integers(1, 8192), st.integers(1, 8192)),
    depth=uint16_images,
    ids=uint16_images,
    scale=st.floats(1e-4, 1.0),
    codec=st.sampled_from(DEPTH_CODECS),
    sighting_instances=instances,
)
def test_a_packed_sighting_survives_msgpack_and_parses_to_the_same_sighting(
    seq, t, translation, intrinsics, rgb_size, depth, ids, scale, codec, sighting_instances
):
    pose = np.eye(4)
    pose[:3, 3] = translation
    message = pack_sighting(
        seq=seq,
        t=t,
        pose=pose_to_bytes(pose),
        intrinsics=intrinsics,
        rgb_size=rgb_size,
        depth=Uint16Image(codec, depth.shape[1], depth.shape[0], encode_uint16_image(depth, codec)),
        depth_scale_m=scale,
        detections=Uint16Image(codec, ids.shape[1], ids.shape[0], encode_uint16_image(ids, codec)),
        instances=sighting_instances,
    )

    sighting = parse_sighting(msgpack.unpackb(msgpack.packb(message, use_bin_type=True)))

    assert (sighting.seq, sighting.t, sighting.intrinsics) == (seq, t, tuple(intrinsics))
    assert sighting.rgb_size == rgb_size and sighting.rgb is None
    np.testing.assert_array_equal(sighting.pose, pose.astype(np.float32))
    np.testing.assert_array_equal(sighting.depth_m, depth.astype(np.float32) * np.float32(scale))
    np.testing.assert_array_equal(sighting.instance_ids, ids)
    assert sighting.instances == sighting_instances
