"""Acks and errors on the stream socket: what the server packs, the device parses back."""

from __future__ import annotations

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.errors import InputError
from app.protocol import Ack, ErrorReply, parse_reply, unpack_reply
from app.protocol.replies import MAX_DOUBTED_PLACES

FEW = settings(max_examples=60, deadline=None)
seqs = st.integers(0, 2**63 - 1)
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)

acks = st.builds(
    Ack,
    seq=seqs,
    keyframe=st.booleans(),
    map_ms=finite,
    server_t=finite,
    dropped=st.booleans(),
    update_seq=st.none() | seqs,
    objects=st.none() | st.integers(0, 10**6),
    doubted=st.none() | st.lists(st.lists(finite, min_size=5, max_size=5), max_size=32),
)
errors = st.builds(ErrorReply, seq=st.none() | seqs, code=st.text(max_size=20), message=st.text())


def wire(message: dict) -> bytes:
    return msgpack.packb(message, use_bin_type=True)


@FEW
@given(reply=acks | errors)
def test_a_reply_survives_pack_msgpack_parse(reply):
    assert unpack_reply(wire(reply.pack())) == reply


def test_an_ack_packs_the_v1_fields_and_only_the_extensions_it_has():
    assert Ack(3, keyframe=False, server_t=1.5).pack() == {
        "type": "ack",
        "seq": 3,
        "server_t": 1.5,
        "keyframe": False,
        "map_ms": 0.0,
    }
    extended = Ack(4, True, 12.0, 2.0, dropped=True, update_seq=9, objects=5, doubted=[]).pack()
    assert list(extended)[5:] == ["dropped", "update_seq", "objects", "doubted"]


def test_doubted_places_are_capped_in_the_ack_and_fit_the_reply_limits():
    many = [[float(i), 0.0, 2.0, 0.1, 600.0] for i in range(MAX_DOUBTED_PLACES + 10)]
    packed = Ack(4, True, 12.0, 2.0, update_seq=9, objects=5, doubted=many).pack()
    assert len(packed["doubted"]) == MAX_DOUBTED_PLACES
    assert unpack_reply(wire(packed)).doubted == many[:MAX_DOUBTED_PLACES]


def _ack() -> dict:
    return Ack(7, True, 3.0, 100.0, update_seq=2).pack()


def _error() -> dict:
    return ErrorReply(7, "bad_frame", "pose: not finite").pack()


def _without(message: dict, key: str) -> dict:
    return {k: v for k, v in message.items() if k != key}


MALFORMED = [
    ("message", [1, 2]),
    ("type", {**_ack(), "type": "delta"}),
    ("type", _without(_ack(), "type")),
    ("seq", _without(_ack(), "seq")),
    ("seq", {**_ack(), "seq": "7"}),
    ("seq", {**_ack(), "seq": True}),
    ("keyframe", {**_ack(), "keyframe": 1}),
    ("map_ms", {**_ack(), "map_ms": float("nan")}),
    ("map_ms", _without(_ack(), "map_ms")),
    ("server_t", {**_ack(), "server_t": "now"}),
    ("dropped", {**_ack(), "dropped": "yes"}),
    ("update_seq", {**_ack(), "update_seq": 2.5}),
    ("objects", {**_ack(), "objects": "5"}),
    ("doubted", {**_ack(), "doubted": {"x": 1}}),
    ("doubted[1]", {**_ack(), "doubted": [[0, 0, 1, 0.1, 2], [0, 0, 1, 0.1]]}),
    ("doubted[0]", {**_ack(), "doubted": [[0, 0, float("inf"), 0.1, 2]]}),
    ("doubted[0]", {**_ack(), "doubted": [[0, 0, True, 0.1, 2]]}),
    ("doubted", {**_ack(), "doubted": [[0, 0, 1, 0.1, 2]] * 33}),
    ("seq", {**_error(), "seq": 1.0}),
    ("code", _without(_error(), "code")),
    ("message", {**_error(), "message": 5}),
]


@pytest.mark.parametrize(("field", "message"), MALFORMED, ids=[f for f, _ in MALFORMED])
def test_a_malformed_reply_raises_one_error_naming_the_field(field, message):
    with pytest.raises(InputError) as err:
        parse_reply(message)
    assert err.value.field == field, str(err.value)


def test_text_or_garbage_on_the_stream_socket_is_not_a_reply():
    with pytest.raises(InputError, match="text"):
        unpack_reply("ack")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="not msgpack"):
        unpack_reply(b"\xc1")
