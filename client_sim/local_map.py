"""The device's sparse local map: per-object entries fed by v1 `delta` messages.

It answers local queries (LQ) when the network is down, so it must be light: memory grows
only with the number of objects it holds, never with the history of updates.

Storage (one row per object, rows dense in [0, n) thanks to swap-remove), 8-bit where the
bulk is (docs/evaluation.md "Targets": 50k objects of 200 points and 384-d embeddings within
64 MB):

- embeddings: ONE contiguous int8 matrix [capacity, dim padded to 16] plus a float32 scale
  per row, so `int8 row * scale` is exactly a unit vector and a score is a cosine; scanned
  by torch's weight-only int8 kernel into score buffers kept at the rows' capacity (nothing
  map-sized allocated per query), the k-th best found by a partition, then the candidates
  within the kernel's error bound re-scored exactly in float32 (client_sim.local_scan).
- points: one `bytes` of uint8 [<= max_points_per_object, 3] per object (3 bytes a point):
  each axis quantised in 255 steps of the object's point box (lo, step: float32 columns;
  app.mapping.held, which the server imports too: it measures relations on these points), so
  a point is within step / 2 of the received float16 one: 3.9 mm per axis for a 2 m object
  (uint16 would give 0.015 mm at twice the bytes; the wire's own float16 rounding is up to
  3.9 mm at 8-16 m from the origin and 15.6 mm at 32-64 m).
- ids, versions, boxes, centroids, n_obs, last_seen_t, update clock: numpy columns of the
  same rows (last_seen_t float64 device-clock seconds, NaN when the server did not send it:
  docs/protocol.md "The living map"; removed objects and their history are not kept on the
  device);
  labels (interned) and point bytes in python lists; id -> row by a sorted index (12 bytes
  an object). The columns, lists and index are client_sim.local_rows.LocalRows.

Eviction (whenever `memory_bytes()` exceeds the budget): objects are ranked into groups,
evicted group by group: first ordinary objects, then those within `distance_threshold_m` of
the user, last those of a priority class. Inside a group the farthest centroid from the user
goes first (with no user position, the least recently updated). The ranking is computed
once and the number to keep is found in closed form, so enforcement cannot loop.

Questions about how things stand (`relational_query`) are answered by the server's
own `app.answering.ask` on the held points, measured when asked
(`OnDemandRelations`): labels as codes, held-point centroids and point counts are columns (16
bytes an object); the relation bodies a question builds are kept for the next one within
`relation_cache_mb`, counted in `memory_bytes()` and dropped first when over budget.

Not thread-safe: the device applies deltas and answers queries from one loop.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.answering.ask import ask, relational_reading
from app.answering.things import MapThings, RelationalHit
from app.mapping.held import POINT_LEVELS, dequantise_points
from app.protocol import DEFAULT_EMBEDDING_DIM, DeltaError, parse_delta
from app.relations.bodies import Z_UP, Body, snap_to_axis
from app.relations.grammar import Reading
from app.relations.on_demand import OnDemandRelations
from app.semantics import TextEncoder
from client_sim.local_bodies import BodyCache
from client_sim.local_delta import ParsedDelta, cap_points, held_centroid, read_upserts
from client_sim.local_rows import INDEX_BYTES_PER_OBJECT, LocalRows, entry_bytes
from client_sim.local_scan import bfloat16_bits, exact_scores, nearest_rows

log = logging.getLogger(__name__)

BYTES_PER_MB = 1_000_000
"""`budget_mb` is in SI megabytes (the stricter reading of "128 MB")."""

PYTHON_BYTES_PER_OBJECT = 24
"""Estimate of the python-side bytes of one object besides its point bytes (which are counted
exactly, header included): two list slots (16) with the lists' over-allocation and a share
of the interned label. Checked against tracemalloc in the tests and the bench."""

RELATION_CACHE_MB = 4.0
"""Default bound on the relation bodies a local map keeps between questions (SI MB; ~1,200
objects of 200 points), always within what the budget leaves free."""

_BOX_MARGIN_M = 1e-3
"""A held object's point box is widened this much for the relation prefilters (float32
rounding of the stored points; a wider box only costs a pair measured to be 0)."""

_UNSET: Any = object()
"""Default of `set_policy(distance_threshold_m=...)`: unchanged (None means "no threshold")."""


@dataclass
class LocalHit:
    """One local query result; `bbox` [x0, y0, z0, x1, y1, z1] and `centroid` in metres."""

    id: int
    label: str
    score: float
    bbox: list[float]
    centroid: list[float]
    last_seen_t: float | None = None
    """Device-clock seconds of the newest keyframe that observed it, as the server sent it
    (None: the server did not send it, e.g. an older server)."""


def _is_finite_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _seconds_or_none(value: float) -> float | None:
    """A stored time as answers give it: None where the server sent none (NaN)."""
    return None if math.isnan(value) else float(value)


class LocalMap:
    """Sparse, budgeted, prioritised local copy of the server's confirmed map.

    dim:                   embedding dimension announced by the session (float16 on the wire)
    max_points_per_object: point cap per object (`max_object_points_client`)
    budget_mb:             bound on `memory_bytes()`, in SI MB (`local_map_budget_mb`)
    priority_classes:      labels kept first when over budget (`priority_class`; any case)
    distance_threshold_m:  objects this close to the user are kept before farther ones
    relation_cache_mb:     bound on the relation bodies kept between relational questions
                           (`relational_query`), in SI MB; within the budget's free room
    """

    seq: int
    """Seq of the last applied delta (0 before any)."""
    evicted: int
    """Objects removed by budget enforcement so far (deltas' removals are not counted)."""

    def __init__(
        self,
        dim: int = DEFAULT_EMBEDDING_DIM,
        max_points_per_object: int = 200,
        budget_mb: float = 500.0,
        priority_classes: Sequence[str] = (),
        distance_threshold_m: float | None = None,
        relation_cache_mb: float = RELATION_CACHE_MB,
    ):
        if isinstance(dim, bool) or not isinstance(dim, int) or dim < 1:
            raise ValueError(f"dim must be a positive integer, got {dim!r}")
        self.dim = dim
        self.seq = 0
        self.evicted = 0
        self._max_points = 0
        self._budget_bytes = 0
        self._priority: frozenset[str] = frozenset()
        self._distance_threshold_m: float | None = None
        self._user_position: np.ndarray | None = None  # float64 [3], metres
        self._clock = 0  # bumped per applied upsert: "least recently updated" without wall time

        self._store = LocalRows(dim)  # the columns, point bytes, labels and id index
        # What relational questions keep between them (`relational_query`), in
        # `memory_bytes()`, dropped for objects that change, go or are evicted:
        if not (_is_finite_number(relation_cache_mb) and relation_cache_mb >= 0):
            raise ValueError(f"relation_cache_mb must be a number >= 0, got {relation_cache_mb!r}")
        self._bodies = BodyCache(int(relation_cache_mb * BYTES_PER_MB))
        # label -> code (the "label_code" column) and back, so a question reads each row's
        # label as an int; compacted when labels no longer held pile up
        self._label_codes: dict[str, int] = {}
        self._code_labels: list[str] = []
        # label -> the texts the server sent with it (the match rule's input; a label the
        # server sent none for is rated by the shipped background's texts, else alone)
        self._label_texts: dict[str, tuple[str, ...]] = {}

        self.set_policy(
            budget_mb=budget_mb,
            priority_classes=priority_classes,
            distance_threshold_m=distance_threshold_m,
            max_points_per_object=max_points_per_object,
        )

    # --- inspection -----------------------------------------------------------------------

    def __len__(self) -> int:
        return self._store.n

    def __contains__(self, oid: object) -> bool:
        return isinstance(oid, int | np.integer) and self._store.row(int(oid)) is not None

    def ids(self) -> list[int]:
        """Ids of the held objects, ascending."""
        return self._store.index_ids.tolist()

    def get(self, oid: int) -> dict:
        """One held object: id, version, label, bbox [6], centroid [3] (metres), points
        float32 [N, 3] (dequantised: within points_step / 2 per axis of the received ones),
        points_step [3] (metres per stored step), n_obs, last_seen_t (seconds, None if the
        server did not send it). KeyError if not held."""
        row = self._store.row(oid)
        if row is None:
            raise KeyError(oid)
        rows = self._store.columns
        return {
            "id": int(rows["id"][row]),
            "version": int(rows["version"][row]),
            "label": self._store.labels[row],
            "bbox": [float(v) for v in rows["bbox"][row]],
            "centroid": [float(v) for v in rows["centroid"][row]],
            "points": dequantise_points(
                self._store.points[row], rows["points_lo"][row], rows["points_step"][row]
            ),
            "points_step": [float(v) for v in rows["points_step"][row]],
            "n_obs": int(rows["n_obs"][row]),
            "last_seen_t": _seconds_or_none(float(rows["last_seen_t"][row])),
        }

    def label_texts(self) -> dict[str, tuple[str, ...]]:
        """label -> its texts as the server sent them (`rate_hits`' label_texts)."""
        return self._label_texts

    def labels(self) -> list[str]:
        """The distinct labels of the held objects."""
        return self._labels_by_row()[0]

    def snapshot(self) -> dict[int, tuple[int, str]]:
        """id -> (version, label) of every held object (to compare with the server)."""
        versions = self._store.columns["version"]
        return {
            oid: (int(versions[row]), self._store.labels[row])
            for oid, row in zip(
                self._store.index_ids.tolist(), self._store.index_rows.tolist(), strict=True
            )
        }

    def memory_bytes(self) -> int:
        """Bytes held: the row arrays at their capacity (int8 embeddings, scales and metadata
        columns), the id index, the point bytes with their headers,
        `PYTHON_BYTES_PER_OBJECT` per object for python-side metadata, and what relational
        questions keep between them (relation bodies)."""
        return self._map_bytes() + self._relation_bytes()

    def _map_bytes(self) -> int:
        return self._store.nbytes() + self._store.n * PYTHON_BYTES_PER_OBJECT

    def _relation_bytes(self) -> int:
        return self._bodies.nbytes

    @property
    def user_position(self) -> np.ndarray | None:
        """The user's position float64 [3] in world metres (`set_user_position`), or None."""
        return None if self._user_position is None else self._user_position.copy()

    # --- knobs ----------------------------------------------------------------------------

    def set_user_position(self, xyz: Sequence[float] | np.ndarray | None) -> None:
        """The user's position [x, y, z] in world metres (None: unknown) for eviction order.

        Moving changes no memory, so nothing is evicted until the next delta or policy change.
        """
        if xyz is None:
            self._user_position = None
            return
        position = np.asarray(xyz, dtype=np.float64)
        if position.shape != (3,) or not np.all(np.isfinite(position)):
            raise ValueError(f"user position must be 3 finite numbers, got {xyz!r}")
        self._user_position = position

    def set_policy(
        self,
        *,
        budget_mb: float | None = None,
        priority_classes: Sequence[str] | None = None,
        distance_threshold_m: float | None = _UNSET,
        max_points_per_object: int | None = None,
    ) -> None:
        """Change knobs at run time (None: unchanged; but `distance_threshold_m=None` clears
        the threshold). A lower point cap re-caps held objects; the budget is re-enforced."""
        if budget_mb is not None and not (_is_finite_number(budget_mb) and budget_mb > 0):
            raise ValueError(f"budget_mb must be a positive number, got {budget_mb!r}")
        if priority_classes is not None and (
            isinstance(priority_classes, str)
            or not all(isinstance(c, str) for c in priority_classes)
        ):
            raise ValueError(f"priority_classes must be a list of labels, got {priority_classes!r}")
        threshold = distance_threshold_m
        if threshold not in (_UNSET, None) and not (
            _is_finite_number(threshold) and threshold >= 0
        ):
            raise ValueError(
                f"distance_threshold_m must be a number >= 0 or None, got {threshold!r}"
            )
        if max_points_per_object is not None and (
            isinstance(max_points_per_object, bool)
            or not isinstance(max_points_per_object, int)
            or max_points_per_object < 1
        ):
            raise ValueError(
                f"max_points_per_object must be a positive integer, got {max_points_per_object!r}"
            )

        if budget_mb is not None:
            self._budget_bytes = int(budget_mb * BYTES_PER_MB)
        if priority_classes is not None:
            self._priority = frozenset(c.strip().casefold() for c in priority_classes)
        if distance_threshold_m is not _UNSET:
            self._distance_threshold_m = (
                None if distance_threshold_m is None else float(distance_threshold_m)
            )
        if max_points_per_object is not None:
            lowered = 0 < max_points_per_object < self._max_points
            self._max_points = max_points_per_object
            if lowered:
                self._recap_points()
        self._enforce_budget()

    # --- updates --------------------------------------------------------------------------

    def apply_delta(self, message: dict) -> None:
        """Apply one v1 `delta` (a msgpack-unpacked dict with bytes fields).

        Validates everything first: a malformed or out-of-order delta raises DeltaError and
        leaves the map unchanged. `full` replaces the map; otherwise stale upserts (version
        below the held one) are ignored and removals of unknown ids (e.g. evicted) are fine.
        On return `memory_bytes()` is within the budget.
        """
        delta = self._parse(message)
        if delta.full:
            self._clear()
            self._label_texts = {}
        else:
            self._remove_ids(delta.removed)
        self._label_texts.update(delta.label_texts)
        self._upsert(delta)
        self.seq = delta.seq
        self._store.trim()  # memory follows the object count
        self._enforce_budget()

    def _parse(self, message: Any) -> ParsedDelta:
        """The delta as columns, or DeltaError naming the first wrong field; no side effects."""
        delta = parse_delta(message, self.dim)
        if not delta.full and delta.seq < self.seq:
            raise DeltaError(
                "seq", f"{delta.seq} is older than the applied seq {self.seq} (out of order)"
            )
        return read_upserts(delta, self.dim, self._max_points)

    def _upsert(self, delta: ParsedDelta) -> None:
        """Write the fresh upserts of a validated delta (ids unique, as parse_delta checks):
        existing rows in place, new at the end."""
        held_versions = self._store.columns["version"]
        rows = np.empty(len(delta.ids), np.int64)
        fresh = np.ones(len(delta.ids), bool)
        held_rows = self._store.rows_of(delta.ids)
        n_new = 0
        for i, row in enumerate(held_rows.tolist()):
            if row < 0:
                rows[i] = self._store.n + n_new
                n_new += 1
            elif delta.versions[i] < held_versions[row]:
                fresh[i] = False
            else:
                rows[i] = row
        if not fresh.all():
            log.debug("ignored %d stale upserts (older than the held version)", (~fresh).sum())
        self._store.ensure_capacity(self._store.n + n_new)

        take = np.flatnonzero(fresh)
        target = rows[take]
        columns = self._store.columns
        columns["id"][target] = delta.ids[take]
        columns["version"][target] = delta.versions[take]
        self._store.embeddings[target] = delta.embeddings[take]
        columns["scale"][target] = delta.scales[take]
        columns["scale_bf16"][target] = bfloat16_bits(delta.scales[take])
        columns["points_lo"][target] = delta.points_lo[take]
        columns["points_step"][target] = delta.points_step[take]
        columns["bbox"][target] = delta.bboxes[take]
        columns["centroid"][target] = delta.centroids[take]
        columns["held_centroid"][target] = delta.held_centroids[take]
        columns["n_obs"][target] = delta.n_obs[take]
        columns["last_seen_t"][target] = delta.last_seen_t[take]
        columns["label_code"][target] = [self._label_code(delta.labels[i]) for i in take.tolist()]
        columns["n_points"][target] = [len(delta.points[i]) // 3 for i in take.tolist()]
        columns["updated"][target] = self._clock + np.arange(1, len(take) + 1)
        self._clock += len(take)
        self._bodies.forget(delta.ids[take].tolist())
        for i, row in zip(take.tolist(), target.tolist(), strict=True):
            # new rows were numbered in order, so they append in order
            self._store.put(row, delta.labels[i], delta.points[i])
        self._store.add_rows(n_new)
        if len(self._code_labels) > 2 * self._store.n + 1024:
            self._recode_labels()

    def _label_code(self, label: str) -> int:
        code = self._label_codes.get(label)
        if code is None:
            code = self._label_codes[label] = len(self._code_labels)
            self._code_labels.append(label)
        return code

    def _recode_labels(self) -> None:
        """Codes for the held labels only (labels of objects gone no longer kept)."""
        self._label_codes, self._code_labels = {}, []
        self._store.columns["label_code"][: self._store.n] = [
            self._label_code(label) for label in self._store.labels
        ]

    def _clear(self) -> None:
        self._bodies.forget()
        self._label_codes, self._code_labels = {}, []
        self._store.clear()

    def _remove_ids(self, ids: Sequence[int]) -> None:
        """Drop the held ones of `ids` (unknown ids may have been evicted: not an error)."""
        self._bodies.forget(list(ids))
        held = self._store.rows_of(np.fromiter(set(ids), np.int64))
        rows = set(held[held >= 0].tolist())
        if len(rows) < len(set(ids)):
            log.debug(
                "%d removed ids were not held (evicted or never seen)", len(set(ids)) - len(rows)
            )
        self._store.remove_rows(rows)

    def _recap_points(self) -> None:
        """Subsample held objects over a lowered point cap (same rule as on arrival). The
        kept offsets stay as they are in their box: no second rounding."""
        ids, versions = self._store.columns["id"], self._store.columns["version"]
        for row, data in enumerate(self._store.points):
            if len(data) > 3 * self._max_points:
                offsets = np.frombuffer(data, np.uint8).reshape(-1, 3)
                capped = cap_points(
                    offsets, self._max_points, int(ids[row]), int(versions[row])
                ).tobytes()
                self._store.set_points(row, capped)
                self._store.columns["n_points"][row] = len(capped) // 3
                lo, step = (
                    self._store.columns["points_lo"][row],
                    self._store.columns["points_step"][row],
                )
                self._store.columns["held_centroid"][row] = held_centroid(
                    capped, lo, step, self._store.columns["held_centroid"][row]
                )
                self._bodies.forget([int(ids[row])])

    # --- budget ---------------------------------------------------------------------------

    def _eviction_order(self) -> np.ndarray:
        """int64 [n] rows, the first to evict first (groups, then farthest / oldest, then id)."""
        n = self._store.n
        columns = self._store.columns
        group = np.zeros(n, np.int8)  # 0: ordinary, 1: near the user, 2: priority class
        if self._user_position is not None:
            distance_m = np.linalg.norm(
                columns["centroid"][:n].astype(np.float64) - self._user_position, axis=1
            )
            if self._distance_threshold_m is not None:
                group[distance_m <= self._distance_threshold_m] = 1
            within_group = -distance_m  # farthest first
        else:
            within_group = columns["updated"][:n]  # least recently updated first
        if self._priority:
            is_priority = np.fromiter(
                (label.strip().casefold() in self._priority for label in self._store.labels),
                bool,
                n,
            )
            group[is_priority] = 2
        return np.lexsort((columns["id"][:n], within_group, group))

    def _enforce_budget(self) -> None:
        """Evict (and shrink the columns) until `memory_bytes()` is within the budget."""
        if self.memory_bytes() <= self._budget_bytes:
            return
        self._bodies.forget()  # a cache goes before any object
        if self.memory_bytes() <= self._budget_bytes:
            return
        n = self._store.n
        order = self._eviction_order()
        row_bytes = self._store.row_bytes()
        per_object = np.fromiter((entry_bytes(data) for data in self._store.points), np.int64, n)
        per_object += PYTHON_BYTES_PER_OBJECT + INDEX_BYTES_PER_OBJECT + row_bytes
        # cost[k]: bytes when keeping the k objects that come last in the eviction order, in
        # columns of exactly k rows. It increases with k, so the largest k that fits is found
        # by one search, with no evict-and-recheck loop.
        cost = np.concatenate(([0], np.cumsum(per_object[order[::-1]])))
        keep_count = int(np.searchsorted(cost, self._budget_bytes, side="right")) - 1
        spare_rows = (self._budget_bytes - int(cost[keep_count])) // row_bytes
        capacity = min(self._store.capacity, keep_count + spare_rows)
        self.evicted += n - keep_count
        if n - keep_count:
            log.debug(
                "evicted %d objects to stay within %d bytes", n - keep_count, self._budget_bytes
            )
        self._store.keep_rows(np.sort(order[n - keep_count :]), capacity)
        self._bodies.forget([oid for oid in self._bodies.ids() if self._store.row(oid) is None])

    # --- queries --------------------------------------------------------------------------

    def query_embedding(self, embedding: np.ndarray, k: int = 5) -> list[LocalHit]:
        """The k held objects most similar (cosine) to `embedding` float [dim], best first."""
        query = np.asarray(embedding, dtype=np.float32)
        if query.shape != (self.dim,) or not np.all(np.isfinite(query)):
            raise ValueError(f"query embedding must be {self.dim} finite numbers")
        n = self._store.n
        if k < 1 or n == 0:
            return []
        query = query / max(float(np.linalg.norm(query)), 1e-12)
        store = self._store
        rows, scores = nearest_rows(
            store.embeddings,
            store.columns["scale"],
            store.columns["id"],
            store.embeddings_t,
            store.scales_bf16_t,
            n,
            query,
            k,
            store.scratch,
        )
        columns = store.columns
        return [
            LocalHit(
                id=int(columns["id"][row]),
                label=store.labels[row],
                score=score,
                bbox=columns["bbox"][row].tolist(),
                centroid=columns["centroid"][row].tolist(),
                last_seen_t=_seconds_or_none(float(columns["last_seen_t"][row])),
            )
            for row, score in zip(rows.tolist(), scores.tolist(), strict=True)
        ]

    def relational_query(
        self,
        question: str | Reading,
        encoder: TextEncoder,
        viewer: Sequence[float] | np.ndarray | None = None,
        up: Sequence[float] | np.ndarray | None = None,
        k: int = 5,
    ) -> list[RelationalHit] | None:
        """The k held objects best answering a question about how things stand ("the mug on
        the desk", "the lamp closest to me"), best first, as the server answers it: the same
        `app.answering.ask` on the same points (the server measures relations
        on the points a device holds, app.mapping.held). None: a plain question, or one to
        answer as plain (an anchor the map holds nothing confident of, a question seen from
        the asker with no position): answer it with `query_embedding`.

        encoder: the session's text encoder; viewer: the asker's position, world metres
        (None: the user's position, `set_user_position`, if any); up: the world axis that is
        up, float [3] (None: Z, app.relations.bodies.Z_UP).

        Cheap at 10k objects: nothing is prepared ahead. A question builds relation bodies
        only for the objects it touches (anchors, what is within reach of them, the target
        category's extremes), keeps up to `relation_cache_mb` of them for the next one
        (dropped when their object changes, goes or is evicted, and before any object when
        over budget), and reads labels and centroids from columns.
        """
        reading = relational_reading(question)
        if reading is None or self._store.n == 0:
            return None
        up_axis = Z_UP if up is None else snap_to_axis(np.asarray(up, np.float64))
        position = self._user_position if viewer is None else np.asarray(viewer, np.float64)
        labels, label_of, rows = self._labels_by_row()
        if len(rows) == 0:
            return None
        columns = self._store.columns
        lo = columns["points_lo"][rows].astype(np.float64)
        hi = lo + POINT_LEVELS * columns["points_step"][rows].astype(np.float64)
        relations = OnDemandRelations(
            columns["id"][rows],
            lo - _BOX_MARGIN_M,
            hi + _BOX_MARGIN_M,
            bodies_of=lambda ids: self._held_bodies(ids, up_axis),
            centroids_of=lambda positions: columns["held_centroid"][rows[positions]],
            up=up_axis,
        )
        things = MapThings(
            ids=columns["id"][rows],
            labels=labels,
            label_of=label_of[rows],
            cosines=lambda positions, query: exact_scores(
                self._store.embeddings, columns["scale"], rows[positions], query
            ),
        )
        return ask(reading, things, relations, encoder, position, k, self._label_texts)

    def _labels_by_row(self) -> tuple[list[str], np.ndarray, np.ndarray]:
        """(the distinct labels held, each row's label int [n] as an index into them, the
        rows with points int [m]), from the label and point-count columns."""
        n = self._store.n
        codes, label_of = np.unique(self._store.columns["label_code"][:n], return_inverse=True)
        with_points = self._store.columns["n_points"][:n] > 0
        rows = np.arange(n) if with_points.all() else np.flatnonzero(with_points)
        return [self._code_labels[code] for code in codes.tolist()], label_of, rows

    def _held_bodies(self, ids: np.ndarray, up: np.ndarray) -> list[Body]:
        """The relation bodies of held objects' points for `up`, from the cache where there."""
        rows = self._store.rows_of(ids)
        if (rows < 0).any():
            raise KeyError(f"not held: {np.asarray(ids)[rows < 0][:5].tolist()}")
        columns = self._store.columns
        axis = tuple(up.tolist())
        bodies = []
        for oid, row, version in zip(
            np.asarray(ids).tolist(), rows.tolist(), columns["version"][rows].tolist(), strict=True
        ):
            key = (version, axis)
            cached = self._bodies.get(oid, key)
            if cached is not None:
                bodies.append(cached)
                continue
            points = dequantise_points(
                self._store.points[row], columns["points_lo"][row], columns["points_step"][row]
            )
            body = Body(points, up)
            self._bodies.keep(oid, key, body, self._budget_bytes - self._map_bytes())
            bodies.append(body)
        return bodies
