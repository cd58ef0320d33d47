"""The local map's row store: one row per held object, rows dense in [0, n) (swap-remove).

Numpy columns of `capacity` rows (int8 embeddings and their scales, ids, versions, boxes,
centroids, point boxes, n_obs, last_seen_t, update clock, label codes, point counts), each
object's point bytes and interned label in python lists of the same rows, and the id -> row
index: the held ids sorted (int64) with their rows (int32), 12 bytes an object, rebuilt when
rows come or go, rather than a dict (~100 bytes an object in python ints and table slots).

What the columns mean and how they are filled is the local map's (client_sim.local_map);
this module only keeps rows dense, grows and shrinks the columns, and finds rows by id.
"""

from __future__ import annotations

import math
import sys

import numpy as np
import torch

from client_sim.local_scan import ScanScratch, padded_dim

INDEX_BYTES_PER_OBJECT = 12
"""The id -> row index: an int64 id and an int32 row per object."""

_BYTES_HEADER = sys.getsizeof(b"")
"""Bytes of an empty `bytes` object: the header every object's point bytes carry."""

_GROWTH = 16
"""Capacity grows by 1/_GROWTH (6.25%) at least: amortised O(1) inserts with little slack."""

_SWAP_REMOVE_MAX = 32
"""Removing more rows than this at once compacts the arrays in one pass instead."""


def entry_bytes(data: bytes) -> int:
    """Bytes of one object's point bytes as the allocator holds them (header included)."""
    return _BYTES_HEADER + len(data)


class LocalRows:
    """The columns, point bytes and labels of n held objects, and their id -> row index.

    columns:       name -> numpy column [capacity, ...]; rows [0, n) are held; the int8
                   "embedding" is padded_dim(dim) wide (zero columns past dim: the kernel's)
    embeddings:    the embeddings' first dim columns (a view of columns["embedding"])
    embeddings_t:  zero-copy torch view of columns["embedding"] (the int8 kernel reads it)
    scales_bf16_t: zero-copy bfloat16 torch view of columns["scale_bf16"]
    scratch:       what a query writes, at the columns' capacity (client_sim.local_scan)
    labels:        interned label of each row; points: uint8 [N, 3] point bytes of each row
    points_nbytes: sum of `entry_bytes` over `points`
    index_ids:     held ids, ascending; index_rows: their rows
    """

    def __init__(self, dim: int):
        self.dim = dim
        self.n = 0
        self.columns: dict[str, np.ndarray] = {}
        self.embeddings = np.empty((0, dim), np.int8)
        self.scratch = ScanScratch(0)
        self.embeddings_t = torch.empty(0)
        self.scales_bf16_t = torch.empty(0)
        self.reallocate(0)
        self.labels: list[str] = []
        self.points: list[bytes] = []  # uint8 [N, 3] offsets, see app.mapping.held
        self.points_nbytes = 0
        self.index_ids = np.empty(0, np.int64)
        self.index_rows = np.empty(0, np.int32)

    # --- sizes ----------------------------------------------------------------------------

    @property
    def capacity(self) -> int:
        return self.columns["id"].shape[0]

    def row_bytes(self) -> int:
        """Bytes of one row across all columns (embedding + metadata) and the query scratch."""
        return ScanScratch.BYTES_PER_ROW + sum(
            column.itemsize * math.prod(column.shape[1:]) for column in self.columns.values()
        )

    def nbytes(self) -> int:
        """The columns and the query scratch at their capacity, the id index and the point
        bytes with headers."""
        columns = sum(column.nbytes for column in self.columns.values())
        index = self.index_ids.nbytes + self.index_rows.nbytes
        return columns + self.scratch.nbytes + index + self.points_nbytes

    # --- columns --------------------------------------------------------------------------

    def allocate(self, capacity: int) -> dict[str, np.ndarray]:
        return {
            "embedding": np.zeros((capacity, padded_dim(self.dim)), np.int8),
            "scale": np.zeros(capacity, np.float32),
            "scale_bf16": np.zeros(capacity, np.uint16),  # the kernel's copy, bfloat16 bits
            "points_lo": np.zeros((capacity, 3), np.float32),
            "points_step": np.zeros((capacity, 3), np.float32),
            "id": np.zeros(capacity, np.int64),
            "version": np.zeros(capacity, np.int64),
            "bbox": np.zeros((capacity, 6), np.float32),
            "centroid": np.zeros((capacity, 3), np.float32),
            "held_centroid": np.zeros((capacity, 3), np.float32),  # the relations' centroid
            "n_obs": np.zeros(capacity, np.int64),
            "last_seen_t": np.full(capacity, np.nan, np.float64),
            "updated": np.zeros(capacity, np.int64),
            "label_code": np.zeros(capacity, np.int32),  # the local map's label codes
            "n_points": np.zeros(capacity, np.int32),  # held points
        }

    def reallocate(self, capacity: int) -> None:
        """Move the n live rows into columns of `capacity` rows (>= n), order kept."""
        new = self.allocate(capacity)
        for name, column in self.columns.items():
            new[name][: self.n] = column[: self.n]
        self._set_columns(new)

    def _set_columns(self, columns: dict[str, np.ndarray]) -> None:
        self.columns = columns
        self.embeddings = columns["embedding"][:, : self.dim]
        if self.scratch.capacity != len(columns["id"]):
            self.scratch = ScanScratch(len(columns["id"]))
        # from_numpy shares the buffer: queries read the int8 matrix in place, no copy.
        self.embeddings_t = torch.from_numpy(columns["embedding"])
        self.scales_bf16_t = torch.from_numpy(columns["scale_bf16"]).view(torch.bfloat16)

    def ensure_capacity(self, needed: int) -> None:
        capacity = self.capacity
        if needed > capacity:
            self.reallocate(max(needed, capacity + capacity // _GROWTH))

    def trim(self) -> None:
        """Shrink the columns when they hold over twice the rows (memory follows n)."""
        if self.capacity > 2 * self.n + 16:
            self.reallocate(self.n + self.n // _GROWTH)

    # --- rows -----------------------------------------------------------------------------

    def put(self, row: int, label: str, points: bytes) -> None:
        """Set the label and point bytes of a held row, or append those of row n + k (new
        rows in order; `add_rows` then counts them)."""
        if row < self.n:
            self.points_nbytes -= entry_bytes(self.points[row])
            self.points[row] = points
            self.labels[row] = label
        else:
            self.points.append(points)
            self.labels.append(label)
        self.points_nbytes += entry_bytes(points)

    def add_rows(self, count: int) -> None:
        """Count the `count` rows appended by `put` as held (and index them)."""
        self.n += count
        if count:
            self.rebuild_index()

    def set_points(self, row: int, points: bytes) -> None:
        """Replace one held row's point bytes."""
        self.points_nbytes += entry_bytes(points) - entry_bytes(self.points[row])
        self.points[row] = points

    def clear(self) -> None:
        """No rows (the columns keep their capacity)."""
        self.n = 0
        self.labels = []
        self.points = []
        self.points_nbytes = 0
        self.rebuild_index()

    def keep_rows(self, keep: np.ndarray, capacity: int) -> None:
        """Keep only rows `keep` (int [m], ascending), compacted into columns of `capacity`."""
        m = len(keep)
        new = self.allocate(capacity)
        for name, column in self.columns.items():
            new[name][:m] = column[keep]
        self._set_columns(new)
        kept = keep.tolist()
        self.labels = [self.labels[row] for row in kept]
        self.points = [self.points[row] for row in kept]
        self.points_nbytes = sum(entry_bytes(data) for data in self.points)
        self.n = m
        self.rebuild_index()

    def remove_rows(self, rows: set[int]) -> None:
        """Drop these held rows: swap-remove a few, compact in one pass for many."""
        if len(rows) > _SWAP_REMOVE_MAX:
            keep = np.ones(self.n, bool)
            keep[list(rows)] = False
            self.keep_rows(np.flatnonzero(keep), self.capacity)
            return
        for row in sorted(rows, reverse=True):  # descending: a moved last row is never pending
            self._swap_remove(row)
        if rows:
            self.rebuild_index()

    def _swap_remove(self, row: int) -> None:
        """Remove one row in O(1) by moving the last row into its place (the caller rebuilds
        the index)."""
        last = self.n - 1
        self.points_nbytes -= entry_bytes(self.points[row])
        if row != last:
            for column in self.columns.values():
                column[row] = column[last]
            self.labels[row] = self.labels[last]
            self.points[row] = self.points[last]
        self.labels.pop()
        self.points.pop()
        self.n = last

    # --- id index -------------------------------------------------------------------------

    def rebuild_index(self) -> None:
        """Sort the held ids (after rows came or went): O(n log n), ~2 ms at 50k objects."""
        ids = self.columns["id"][: self.n]
        order = np.argsort(ids, kind="stable")
        self.index_ids = ids[order]
        self.index_rows = order.astype(np.int32)

    def rows_of(self, ids: np.ndarray) -> np.ndarray:
        """int64 rows of int64 `ids` [m], -1 where not held."""
        ids = np.asarray(ids, np.int64)
        at = np.searchsorted(self.index_ids, ids)
        found = at < len(self.index_ids)
        found[found] = self.index_ids[at[found]] == ids[found]
        rows = np.full(len(ids), -1, np.int64)
        rows[found] = self.index_rows[at[found]]
        return rows

    def row(self, oid: int) -> int | None:
        """The row of `oid`, or None if not held."""
        at = int(np.searchsorted(self.index_ids, oid))
        if at < len(self.index_ids) and int(self.index_ids[at]) == oid:
            return int(self.index_rows[at])
        return None
