"""A map's objects as a file and back: the JSON export's object records and the PLY.

Export rounds the way the wire does (points to 0.1 mm, embeddings to 1e-6), and everything
derived from the points (box, centroid) is computed from the rounded points, so an export
imported and exported again gives the same text: float32 holds a 0.1 mm coordinate (under
MAX_WORLD_M) and a 1e-6 embedding component closely enough to round back to it.

The living map's history travels too: each object's device-clock first/last seen and its
stays (places rounded to 0.1 mm from their float32 form, the form a store keeps, so an
export reads the same before and after a restart), the removed objects kept as history, and
the changes with their update seq. Times are exported exactly.
"""

from __future__ import annotations

import io
import json
import zlib
from collections import Counter
from collections.abc import Iterable, Iterator

import numpy as np

from app.mapping.object import Change, MapObject, Stay

POINT_DECIMALS = 4
"""0.1 mm, as on the wire."""
EMBEDDING_DECIMALS = 6
UNIT_TOLERANCE = 1e-5
"""An embedding sum this close to unit length is exported as it is: re-normalising an
imported (rounded) unit vector would move it by a rounding step."""


def exported_points(obj: MapObject) -> np.ndarray:
    """float64 [N, 3] metres, rounded to 0.1 mm: the points an export holds."""
    return np.asarray(obj.points, np.float64).round(POINT_DECIMALS)


def exported_embedding(obj: MapObject) -> list[float]:
    """The object's unit embedding, rounded to 1e-6."""
    assert obj.embedding_sum is not None
    vector = np.asarray(obj.embedding_sum, np.float64)
    norm = float(np.linalg.norm(vector))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        vector = vector / max(norm, 1e-12)
    return vector.round(EMBEDDING_DECIMALS).tolist()


def export_record(obj: MapObject, with_embedding: bool) -> dict:
    """One object of a JSON export (`protocol.ExportedObject`), full server resolution."""
    points = exported_points(obj)
    record = {
        "id": obj.id,
        "version": obj.version,
        "label": obj.label,
        "bbox": np.concatenate([points.min(0), points.max(0)]).round(POINT_DECIMALS).tolist()
        if len(points)
        else [0.0] * 6,
        "centroid": points.mean(0).round(POINT_DECIMALS).tolist() if len(points) else [0.0] * 3,
        "n_obs": obj.n_obs,
        "points": points.tolist(),
    }
    if with_embedding:
        record["embedding"] = exported_embedding(obj)
    if obj.first_seen_t is not None:
        record["first_seen_t"] = obj.first_seen_t
    if obj.last_seen_t is not None:
        record["last_seen_t"] = obj.last_seen_t
    if obj.stays:
        record["stays"] = [exported_stay(stay) for stay in obj.stays]
    return record


def _exported_place(values: Iterable[float]) -> list[float]:
    """Metres rounded to 0.1 mm from their float32 form (the form a store keeps)."""
    return np.asarray(list(values), np.float32).astype(np.float64).round(POINT_DECIMALS).tolist()


def exported_stay(stay: Stay) -> dict:
    """One stay of an export: {"t_from", "t_to", "centroid", "bbox"} (`protocol.ExportedStay`)."""
    return {
        "t_from": stay.t_from,
        "t_to": stay.t_to,
        "centroid": _exported_place(stay.centroid),
        "bbox": _exported_place(stay.bbox),
    }


def export_change(change: Change) -> dict:
    """One change of an export: its wire form and the update seq that published it."""
    return {**change.to_json(), "seq": change.seq}


def export_json_chunks(
    header: dict,
    objects: Iterable[MapObject],
    removed_objects: Iterable[MapObject],
    changes: Iterable[Change],
    with_embedding: bool,
) -> Iterator[bytes]:
    """The JSON export (`protocol.MapExport`) as UTF-8 chunks, one object at a time (the
    whole map is never one JSON text in memory): `header` (format, version, session), then
    "objects", "removed_objects" and "changes"."""
    yield json.dumps(header)[:-1].encode() + b', "objects": ['
    for i, obj in enumerate(objects):
        yield (b", " if i else b"") + json.dumps(export_record(obj, with_embedding)).encode()
    yield b'], "removed_objects": ['
    for i, obj in enumerate(removed_objects):
        yield (b", " if i else b"") + json.dumps(export_record(obj, with_embedding)).encode()
    yield b'], "changes": ' + json.dumps([export_change(c) for c in changes]).encode() + b"}"


def imported_object(
    object_id: int,
    version: int,
    label: str,
    n_obs: int,
    points: list[list[float]],
    embedding: np.ndarray,
    resolution_m: float,
    *,
    first_seen_t: float | None = None,
    last_seen_t: float | None = None,
    stays: Iterable[Stay] = (),
    state: str = "present",
) -> MapObject:
    """A confirmed MapObject from an export's record. embedding: float32 [d] (the export's,
    or the label's when the export has none). The label histogram is the label n_obs times
    (an export keeps only the winner); there are no per-label sums (the embedding is the
    object's). state: "removed" for a removed object of the export."""
    return MapObject(
        id=object_id,
        points=np.asarray(points, np.float32).reshape(-1, 3),
        embedding_sum=np.asarray(embedding, np.float32),
        label_counts=Counter({label: n_obs}),
        n_obs=n_obs,
        frames_seen=n_obs,
        version=version,
        confirmed=True,
        resolution_m=resolution_m,
        first_seen_t=first_seen_t,
        last_seen_t=last_seen_t,
        state=state,  # type: ignore[arg-type]
        stays=list(stays),
    )


def imported_stay(t_from: float, t_to: float, centroid: list[float], bbox: list[float]) -> Stay:
    """A Stay from an export's stay record."""
    return Stay(
        float(t_from),
        float(t_to),
        tuple(float(v) for v in centroid),  # type: ignore[arg-type]
        tuple(float(v) for v in bbox),  # type: ignore[arg-type]
    )


def label_colour(label: str) -> tuple[int, int, int]:
    """A stable RGB colour per label (the same label, the same colour, in every file)."""
    h = zlib.crc32(label.encode())
    return 64 + (h & 0xFF) % 192, 64 + (h >> 8 & 0xFF) % 192, 64 + (h >> 16 & 0xFF) % 192


def ply_bytes(objects: Iterable[MapObject]) -> bytes:
    """Binary little-endian PLY of the objects' points (0.1 mm), with per-point
    `object_id` (int32) and a colour per label (red, green, blue uint8)."""
    from plyfile import PlyData, PlyElement  # only export needs it

    objects = list(objects)
    n = sum(len(o.points) for o in objects)
    vertex = np.empty(
        n,
        dtype=[
            ("x", "<f4"),
            ("y", "<f4"),
            ("z", "<f4"),
            ("red", "u1"),
            ("green", "u1"),
            ("blue", "u1"),
            ("object_id", "<i4"),
        ],
    )
    start = 0
    for obj in objects:
        end = start + len(obj.points)
        points = exported_points(obj)
        vertex["x"][start:end], vertex["y"][start:end], vertex["z"][start:end] = points.T
        r, g, b = label_colour(obj.label)
        vertex["red"][start:end], vertex["green"][start:end], vertex["blue"][start:end] = r, g, b
        vertex["object_id"][start:end] = obj.id
        start = end
    out = io.BytesIO()
    PlyData(
        [PlyElement.describe(vertex, "vertex")],
        text=False,
        byte_order="<",
        comments=["semanticxr-map: confirmed objects' points, per-point object_id"],
    ).write(out)
    return out.getvalue()
