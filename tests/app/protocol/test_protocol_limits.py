"""msgpack unpacking within the protocol's limits: hostile messages are refused while they
are unpacked, before a few bytes can amplify into much memory (docs/faults.md, "Limits on
what the network may send")."""

from __future__ import annotations

import struct
import tracemalloc

import msgpack
import numpy as np
import pytest

from app.errors import InputError
from app.protocol import (
    MAX_INSTANCES_PER_FRAME,
    UpsertEntry,
    pack_delta,
    unpack_frame_message,
    unpack_update,
)
from app.protocol.limits import FRAME_LIMITS, UPDATE_LIMITS

EIGHT_MIB = 8 << 20


def _flat_empty_arrays(total_bytes: int) -> bytes:
    """One array holding ~total_bytes empty arrays (1 byte each on the wire)."""
    count = total_bytes - 5
    return b"\xdd" + struct.pack(">I", count) + b"\x90" * count


def _nested_empty_arrays(total_bytes: int, fan_out: int = 256) -> bytes:
    """Arrays of `fan_out` arrays of `fan_out` empty arrays: each level within the per-array
    limit, ~total_bytes empty arrays in all."""
    leaf = b"\xdc" + struct.pack(">H", fan_out) + b"\x90" * fan_out
    middle = b"\xdc" + struct.pack(">H", fan_out) + leaf * fan_out
    count = total_bytes // len(middle)
    return b"\xdc" + struct.pack(">H", count) + middle * count


def _peak_bytes_of(unpack, raw: bytes) -> tuple[object, int]:
    tracemalloc.start()
    try:
        try:
            outcome: object = unpack(raw)
        except InputError as exc:
            outcome = exc
        return outcome, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("shape", ["flat", "nested"])
def test_eight_mib_of_empty_arrays_is_refused_on_the_frame_socket_without_expanding(shape):
    raw = _flat_empty_arrays(EIGHT_MIB) if shape == "flat" else _nested_empty_arrays(EIGHT_MIB)
    assert len(raw) <= EIGHT_MIB

    outcome, peak = _peak_bytes_of(unpack_frame_message, raw)

    assert isinstance(outcome, InputError) and outcome.field == "message"
    assert "limit" in outcome.message, outcome.message
    # Unpacked whole it would be ~500 MB of lists; refused, it stays near the message size.
    assert peak < 64 << 20, peak


@pytest.mark.parametrize("shape", ["flat", "nested"])
def test_eight_mib_of_empty_arrays_is_refused_on_the_updates_socket_without_expanding(shape):
    raw = _flat_empty_arrays(EIGHT_MIB) if shape == "flat" else _nested_empty_arrays(EIGHT_MIB)

    outcome, peak = _peak_bytes_of(unpack_update, raw)

    assert isinstance(outcome, str) and "message: " in outcome and "limit" in outcome
    assert peak < 128 << 20, peak


def test_each_limit_is_named_in_the_error():
    too_many_instances = msgpack.packb({"instances": [{}] * (MAX_INSTANCES_PER_FRAME + 1)})
    long_string = msgpack.packb({"label": "x" * (FRAME_LIMITS.max_str_len + 1)})
    big_map = msgpack.packb({str(i): i for i in range(FRAME_LIMITS.max_map_len + 1)})
    for raw, words in (
        (too_many_instances, f"a list of {MAX_INSTANCES_PER_FRAME + 1} items"),
        (long_string, f"a string of {FRAME_LIMITS.max_str_len + 1} bytes"),
        (big_map, f"a map of {FRAME_LIMITS.max_map_len + 1} pairs"),
    ):
        with pytest.raises(InputError, match=f"^message: {words} is over the protocol's limit"):
            unpack_frame_message(raw)


def test_garbage_is_not_msgpack_and_text_is_not_an_update():
    with pytest.raises(InputError, match=r"^message: not msgpack \("):
        unpack_frame_message(b"\xc1\xc1 not msgpack")
    assert unpack_update(b"\xc1").startswith("message: not msgpack")
    assert "text" in unpack_update("hello")  # type: ignore[arg-type]


def test_a_delta_of_the_largest_map_a_session_holds_still_unpacks():
    # Within UPDATE_LIMITS by construction: the item budget is what a full snapshot needs.
    upserts = [
        UpsertEntry(i, 1, "chair", np.ones(4), np.zeros((1, 3)), (0, 0, 0, 1, 1, 1), 2)
        for i in range(2000)
    ]
    raw = msgpack.packb(pack_delta(1, upserts, removed=list(range(10_000, 60_000))))
    message = unpack_update(raw)
    assert isinstance(message, dict) and len(message["upserts"]) == 2000
    per_upsert = 1 + 7 + 1 + 6  # its map and its pairs, the bbox list and its numbers
    assert UPDATE_LIMITS.max_items >= 50_000 * per_upsert + 100_000


def test_map_keys_of_any_type_unpack_so_that_the_frame_check_names_them():
    assert unpack_frame_message(msgpack.packb({1: "x"})) == {1: "x"}
