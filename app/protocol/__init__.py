"""Wire protocol v1 (docs/protocol.md): the one place that knows its field names.

Every message has one typed definition here, its pack and its parse side by side; the
server, the device, the viewer, the benches and the tests all use them, and nothing else
builds or parses a message. msgpack maps travel in binary WebSocket messages (binary fields
are raw bytes), JSON over HTTP.

    frame.py     device -> server, stream socket: `pack_frame`, `unpack_frame_message`,
                 `parse_frame` -> `FrameInput`
    sighting.py  device -> server, stream socket, the negotiated sightings extension:
                 `SIGHTINGS_SUBPROTOCOL`, `pack_sighting`, `parse_sighting` -> `FrameInput`
    replies.py   server -> device, stream socket: `Ack`, `ErrorReply`, `parse_reply`
    delta.py     server -> subscribers, updates socket: `UpsertEntry`, `DeltaMessage`,
                 `pack_delta`, `unpack_update`, `parse_delta` (raises `DeltaError`)
    rest.py      REST answers: session records, `ObjectRecord`, `QueryResult`
    limits.py    `PROTOCOL_VERSION` and every limit, the bounded msgpack unpacking, the
                 server's per-frame `FrameBudget` (`LimitError`)

This package imports only the codecs and the error type below it: never perception,
mapping or the server.
"""

from app.errors import InputError
from app.protocol.delta import (
    ChangeEntry,
    DeltaError,
    DeltaMessage,
    UpsertEntry,
    pack_delta,
    parse_delta,
    unpack_update,
)
from app.protocol.frame import (
    DepthPatch,
    EncodedDepthPatches,
    FrameInput,
    Uint16Image,
    pack_depth_patches,
    pack_frame,
    parse_frame,
    patch_rows,
    unpack_frame_message,
)
from app.protocol.limits import (
    DEFAULT_EMBEDDING_DIM,
    MAX_IMAGE_SIDE_PX,
    MAX_INSTANCES_PER_FRAME,
    MAX_INTRINSIC_PX,
    MAX_LABEL_CHARS,
    MAX_REMOVED_PER_DELTA,
    MAX_UPSERTS_PER_DELTA,
    PROTOCOL_VERSION,
    FrameBudget,
    LimitError,
)
from app.protocol.replies import Ack, ErrorReply, parse_reply, unpack_reply
from app.protocol.rest import (
    KNOB_CHANGES_SCHEMA,
    MAX_QUERY_CHARS,
    ChangeList,
    ChangeRecord,
    CreateSession,
    EmbeddingInfo,
    ErrorBody,
    KnobsBody,
    ObjectHistory,
    ObjectRecord,
    PlaceRecord,
    QueryHit,
    QueryResult,
    SessionCreated,
    SessionStats,
    SessionSummary,
    SpokenQueryResult,
    UnprocessableBody,
    parse_query_result,
    parse_record,
)
from app.protocol.sighting import SIGHTINGS_SUBPROTOCOL, pack_sighting, parse_sighting

__all__ = [
    "DEFAULT_EMBEDDING_DIM",
    "MAX_IMAGE_SIDE_PX",
    "MAX_INSTANCES_PER_FRAME",
    "MAX_INTRINSIC_PX",
    "MAX_LABEL_CHARS",
    "MAX_REMOVED_PER_DELTA",
    "MAX_UPSERTS_PER_DELTA",
    "PROTOCOL_VERSION",
    "SIGHTINGS_SUBPROTOCOL",
    "KNOB_CHANGES_SCHEMA",
    "MAX_QUERY_CHARS",
    "Ack",
    "CreateSession",
    "ErrorBody",
    "KnobsBody",
    "UnprocessableBody",
    "SpokenQueryResult",
    "DeltaError",
    "ChangeEntry",
    "DeltaMessage",
    "DepthPatch",
    "EncodedDepthPatches",
    "EmbeddingInfo",
    "ErrorReply",
    "FrameBudget",
    "FrameInput",
    "InputError",
    "LimitError",
    "ChangeList",
    "ChangeRecord",
    "ObjectHistory",
    "ObjectRecord",
    "PlaceRecord",
    "QueryHit",
    "QueryResult",
    "SessionCreated",
    "SessionStats",
    "SessionSummary",
    "Uint16Image",
    "UpsertEntry",
    "pack_delta",
    "pack_depth_patches",
    "pack_frame",
    "pack_sighting",
    "patch_rows",
    "parse_delta",
    "parse_frame",
    "parse_sighting",
    "parse_query_result",
    "parse_record",
    "parse_reply",
    "unpack_frame_message",
    "unpack_reply",
    "unpack_update",
]
