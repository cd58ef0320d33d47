"""A smooth, collision-free walking camera through the rooms of a Scene.

Planning happens on a 5 cm floor grid: cells closer than CLEARANCE_M to furniture or walls
are blocked, viewpoints are picked in every room (the most open spot first, then spread-out
extra ones), the rooms are visited in the order that walks the least, and Dijkstra on the
grid (with a cost that keeps away from obstacles) joins consecutive viewpoints through the
doorways. The path is smoothed, timed so that the camera turns at most a few degrees per
frame, and the camera looks ahead and towards nearby furniture with a gentle side-to-side
scan and a slightly downward pitch.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from world.scene import WALL_THICKNESS_M, Scene

EYE_HEIGHT_M = 1.55
CLEARANCE_M = 0.3
"""Minimum distance of planned positions from walls and furniture footprints."""
GRID_M = 0.05
STEP_TARGET_M = 0.035
"""Preferred distance between consecutive frames (~1 m/s at 30 fps)."""
STEP_MAX_M = 0.05
MAX_TURN_DEG = 3.0
"""Turning allowed per frame before the walk slows down in bends."""
_OBSTACLE_TOP_M = 2.0  # anything whose bottom is below this blocks a walking person
_EXTRA_VIEWPOINTS = 6


def walk_trajectory(scene: Scene, n_frames: int, seed: int = 0) -> list[np.ndarray]:
    """`n_frames` camera-to-world poses (float64 [4, 4], OpenCV camera axes) of a walk.

    Consecutive poses are 2-5 cm and a few degrees apart; the camera stays inside the rooms
    at eye height (~1.55 m) and at least ~20 cm from any obstacle. Around 300-600 frames
    visit every room of the apartment; more frames add viewpoints, fewer walk a prefix.
    """
    if n_frames <= 0:
        return []
    rng = np.random.default_rng([int(seed), 0x7A11])
    space = _FreeSpace(scene)
    route = space.plan_route(n_frames, rng)
    xy, heading = _time_route(route, n_frames, space)
    return _poses(xy, heading, rng)


class _FreeSpace:
    """Walkable floor cells, their distance to obstacles and the grid graph over them."""

    def __init__(self, scene: Scene):
        self.scene = scene
        x0, y0, x1, y1 = scene.bounds
        self.origin = np.array([x0, y0])
        self.shape = (int(math.ceil((x1 - x0) / GRID_M)), int(math.ceil((y1 - y0) / GRID_M)))
        gx = x0 + (np.arange(self.shape[0]) + 0.5) * GRID_M
        gy = y0 + (np.arange(self.shape[1]) + 0.5) * GRID_M
        self.cx, self.cy = np.meshgrid(gx, gy, indexing="ij")
        inside = np.zeros(self.shape, bool)
        self.room_of = np.full(self.shape, -1, np.int32)
        for i, room in enumerate(scene.rooms):
            rx0, ry0, rx1, ry1 = room.bounds
            mask = (self.cx >= rx0) & (self.cx <= rx1) & (self.cy >= ry0) & (self.cy <= ry1)
            inside |= mask
            self.room_of[mask & (self.room_of < 0)] = i
        blocked = ~inside
        for obj in scene.objects:
            if obj.category in ("floor", "ceiling") or obj.bbox[2] > _OBSTACLE_TOP_M:
                continue
            blocked |= self._box_mask(obj.bbox[[0, 1, 3, 4]])
        # Wall objects are whole lines; open their doorways again.
        t = WALL_THICKNESS_M / 2 + GRID_M
        for door in scene.doorways:
            cx, cy = door.center
            half = door.width / 2
            rect = (
                (cx - t, cy - half, cx + t, cy + half)
                if door.wall_axis == 0
                else (cx - half, cy - t, cx + half, cy + t)
            )
            blocked &= ~self._box_mask(np.array(rect))
        self.dist = ndimage.distance_transform_edt(~blocked) * GRID_M
        walkable = self.dist >= CLEARANCE_M
        labels, n = ndimage.label(walkable, structure=np.ones((3, 3)))
        if n == 0:
            raise ValueError(f"scene {scene.name!r} has no walkable floor")
        # The component that reaches the most rooms (ties: the largest) is where we walk.
        best = max(
            range(1, n + 1),
            key=lambda k: (len(np.unique(self.room_of[labels == k])), int((labels == k).sum())),
        )
        self.walkable = labels == best
        self.node_of = np.full(self.shape, -1, np.int64)
        self.cells = np.argwhere(self.walkable)
        self.node_of[self.walkable] = np.arange(len(self.cells))
        self._graph = self._build_graph()

    def _box_mask(self, rect: np.ndarray) -> np.ndarray:
        x0, y0, x1, y1 = rect
        return (self.cx >= x0) & (self.cx <= x1) & (self.cy >= y0) & (self.cy <= y1)

    def xy_of(self, nodes: np.ndarray) -> np.ndarray:
        cells = self.cells[nodes]
        return self.origin + (cells + 0.5) * GRID_M

    def dist_at(self, xy: np.ndarray) -> np.ndarray:
        ij = np.floor((np.asarray(xy) - self.origin) / GRID_M).astype(int)
        ij[:, 0] = np.clip(ij[:, 0], 0, self.shape[0] - 1)
        ij[:, 1] = np.clip(ij[:, 1], 0, self.shape[1] - 1)
        return self.dist[ij[:, 0], ij[:, 1]]

    def _build_graph(self):
        # Moving close to obstacles costs more, so paths run down the middle of free space.
        cost = 1.0 + 2.0 * np.clip((0.9 - self.dist) / 0.55, 0.0, 1.0)
        i, j = self.cells.T
        node_cost = cost[i, j]
        rows, cols, weights = [], [], []
        for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):  # 8-connected, each edge once
            ni, nj = i + di, j + dj
            ok = (ni >= 0) & (ni < self.shape[0]) & (nj >= 0) & (nj < self.shape[1])
            ok[ok] &= self.walkable[ni[ok], nj[ok]]
            a = np.flatnonzero(ok)
            b = self.node_of[ni[ok], nj[ok]]
            rows.append(a)
            cols.append(b)
            weights.append(GRID_M * math.hypot(di, dj) * 0.5 * (node_cost[a] + node_cost[b]))
        n = len(self.cells)
        return coo_matrix(
            (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
        ).tocsr()

    def _viewpoints(self, rng: np.random.Generator) -> list[list[int]]:
        """Per room: the most open walkable cell, then up to 6 spread-out extra ones."""
        out: list[list[int]] = []
        for i in range(len(self.scene.rooms)):
            nodes = np.flatnonzero(self.room_of[self.walkable] == i)
            if len(nodes) == 0:
                out.append([])
                continue
            d = self.dist[tuple(self.cells[nodes].T)]
            # Stay off the doorway line so a viewpoint clearly belongs to its room.
            xy = self.xy_of(nodes)
            inner = np.array([self.scene.rooms[i].contains_xy(x, y, 0.5) for x, y in xy])
            if inner.any():
                nodes, d, xy = nodes[inner], d[inner], xy[inner]
            first = int(np.argmax(d + rng.uniform(0, 0.02, len(d))))
            chosen = [first]
            spread = np.linalg.norm(xy - xy[first], axis=1)
            roomy = d >= min(0.5, d.max())
            for _ in range(_EXTRA_VIEWPOINTS):
                score = np.where(roomy, spread, -1.0)
                k = int(np.argmax(score))
                if score[k] < 0.8:  # the room is covered
                    break
                chosen.append(k)
                spread = np.minimum(spread, np.linalg.norm(xy - xy[k], axis=1))
            out.append([int(nodes[k]) for k in chosen])
        return out

    def plan_route(self, n_frames: int, rng: np.random.Generator) -> np.ndarray:
        """float [M, 2] polyline through the rooms' viewpoints, sized for n_frames."""
        views = self._viewpoints(rng)
        rooms = [i for i, v in enumerate(views) if v]
        sources = sorted({n for v in views for n in v})
        index = {n: k for k, n in enumerate(sources)}
        dist, pred = dijkstra(
            self._graph, directed=False, indices=sources, return_predecessors=True
        )

        def geo(a: int, b: int) -> float:
            return float(dist[index[a], b])

        # Visit the rooms in the order that walks the least (at most 4! orders).
        orders = [list(p) for p in itertools.permutations(rooms)]
        orders.sort(
            key=lambda o: sum(geo(views[a][0], views[b][0]) for a, b in itertools.pairwise(o))
        )
        order = orders[0][:: -1 if rng.random() < 0.5 else 1]

        def waypoints(extras: list[int]) -> list[int]:
            seq: list[int] = []
            for r in order:
                here = views[r][0]
                seq.append(here)
                todo = list(views[r][1 : 1 + extras[r]])
                while todo:  # nearest first, by walking distance
                    nxt = min(todo, key=lambda n, h=here: geo(h, n))
                    todo.remove(nxt)
                    seq.append(nxt)
                    here = nxt
            return seq

        def length(seq: list[int]) -> float:
            return sum(geo(a, b) for a, b in itertools.pairwise(seq))

        # Add extra viewpoints one at a time, round robin over the rooms, until the walk is
        # long enough for n_frames at the preferred pace (but still affordable at full pace).
        wanted = (n_frames - 1) * STEP_TARGET_M
        affordable = (n_frames - 1) * STEP_MAX_M * 0.8  # bends slow the walk down
        extras = [0] * len(views)
        if len(order) == 1 and len(views[order[0]]) > 1:
            extras[order[0]] = 1  # one room: walk at least between two viewpoints
        seq = waypoints(extras)
        candidates = itertools.cycle(order)
        for _ in range(_EXTRA_VIEWPOINTS * len(order)):
            if length(seq) >= wanted:
                break
            r = next(candidates)
            if extras[r] + 1 >= len(views[r]):
                continue
            extras[r] += 1
            longer = waypoints(extras)
            if length(longer) > affordable:  # would not reach the last room in time
                extras[r] -= 1
                break
            seq = longer
        # Long walks go back and forth over the tour rather than crawling.
        while 0 < length(seq) < wanted * 0.9:
            seq = seq + seq[-2::-1]
        cells: list[int] = []
        for a, b in itertools.pairwise(seq):
            path = [b]
            while path[-1] != a:
                path.append(int(pred[index[a], path[-1]]))
            cells += path[::-1][1 if cells else 0 :]
        if not cells:
            cells = seq[:1] or [int(np.argmax(self.dist[self.walkable]))]
        return self.xy_of(np.array(cells))


def _resample(polyline: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """(points [K, 2] every `spacing` metres along the polyline, their arc lengths [K])."""
    seg = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-9])
    polyline = polyline[keep]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(polyline, axis=0), axis=1))])
    if s[-1] <= 0:
        return polyline[:1], np.zeros(1)
    t = np.arange(0.0, s[-1] + 1e-9, spacing)
    return np.stack([np.interp(t, s, polyline[:, 0]), np.interp(t, s, polyline[:, 1])], 1), t


def _time_route(
    route: np.ndarray, n_frames: int, space: _FreeSpace
) -> tuple[np.ndarray, np.ndarray]:
    """Frame positions [n, 2] and look directions [n] (yaw, radians) along a smoothed route."""
    ds = 0.02
    raw, _ = _resample(route, ds)
    if len(raw) < 3:
        xy = np.repeat(raw[:1], n_frames, axis=0)
        return xy, np.zeros(n_frames)
    smooth = np.stack(
        [ndimage.gaussian_filter1d(raw[:, k], 0.25 / ds, mode="nearest") for k in (0, 1)], 1
    )
    # Smoothing cuts corners; where it cuts too close to an obstacle keep the planned cells.
    tight = space.dist_at(smooth) < CLEARANCE_M * 0.6
    smooth[tight] = raw[tight]
    smooth = np.stack(
        [ndimage.gaussian_filter1d(smooth[:, k], 2.0, mode="nearest") for k in (0, 1)], 1
    )
    path, s = _resample(smooth, ds)
    if len(path) < 3:
        return np.repeat(path[:1], n_frames, axis=0), np.zeros(n_frames)
    # Heading: towards a point ~0.6 m ahead, which turns before bends instead of in them.
    ahead = np.minimum(np.arange(len(path)) + int(0.6 / ds), len(path) - 1)
    delta = path[ahead] - path
    delta[ahead == np.arange(len(path))] = path[-1] - path[-2]
    heading = np.unwrap(np.arctan2(delta[:, 1], delta[:, 0]))
    heading = ndimage.gaussian_filter1d(heading, 0.3 / ds, mode="nearest")
    # Look where you walk, pulled towards the furniture of the room you are in.
    look = np.stack([np.cos(heading), np.sin(heading)], 1) + 0.8 * _interest_directions(
        space.scene, path
    )
    heading = np.unwrap(np.arctan2(look[:, 1], look[:, 0]))
    heading = ndimage.gaussian_filter1d(heading, 0.4 / ds, mode="nearest")
    turn_per_m = np.maximum(np.abs(np.gradient(heading, s)), 1e-6)
    budget = max(n_frames - 1, 1)
    # Speed per frame: the nominal step, slower where the heading turns faster than allowed;
    # short walks that could not reach every room otherwise take their bends faster.
    for max_turn_deg, step_max in (
        (MAX_TURN_DEG, STEP_MAX_M),
        (4.5, STEP_MAX_M),
        (6.0, STEP_MAX_M),
        (6.0, STEP_MAX_M * 1.3),
    ):
        turn_cap = np.maximum(math.radians(max_turn_deg) / turn_per_m, 0.004)
        if float(np.sum(ds / np.minimum(step_max, turn_cap)[:-1])) <= budget:
            break

    def frames_needed(step: float) -> float:
        speed = np.minimum(step, turn_cap)
        return float(np.sum(ds / speed[:-1]))

    lo, hi = 0.002, step_max
    if frames_needed(hi) > budget:
        step = hi  # cannot finish the route: walk a prefix at full speed
    else:
        for _ in range(40):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if frames_needed(mid) > budget else (lo, mid)
        step = hi
    speed = np.minimum(step, turn_cap)
    frame_time = np.concatenate([[0.0], np.cumsum(ds / speed[:-1])])
    frames = np.arange(n_frames, dtype=float)
    at = np.interp(frames, frame_time, s)
    xy = np.stack([np.interp(at, s, path[:, 0]), np.interp(at, s, path[:, 1])], 1)
    return xy, np.interp(at, s, heading)


def _poses(xy: np.ndarray, heading: np.ndarray, rng: np.random.Generator) -> list[np.ndarray]:
    n = len(xy)
    frames = np.arange(n, dtype=float)
    # A slow side-to-side scan (<= 1.5 deg/frame), like someone looking around while walking.
    period = rng.uniform(130, 170)
    yaw = heading + math.radians(30.0) * np.sin(
        2 * math.pi * frames / period + rng.uniform(0, 2 * math.pi)
    )
    limit = math.radians(6.0)
    for i in range(1, n):  # a hard cap on the turn rate (rarely active after the smoothing)
        yaw[i] = yaw[i - 1] + np.clip(yaw[i] - yaw[i - 1], -limit, limit)
    pitch = -np.radians(
        17.0 + 7.0 * np.sin(2 * math.pi * frames / rng.uniform(180, 240) + rng.uniform(0, 6.3))
    )
    roll = np.radians(0.8) * np.sin(2 * math.pi * frames / rng.uniform(70, 110))
    walked = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    z = EYE_HEIGHT_M + rng.uniform(-0.03, 0.03) + 0.008 * np.sin(2 * math.pi * walked / 0.7)
    poses = []
    for i in range(n):
        forward = np.array(
            [
                math.cos(pitch[i]) * math.cos(yaw[i]),
                math.cos(pitch[i]) * math.sin(yaw[i]),
                math.sin(pitch[i]),
            ]
        )
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        c, s = math.cos(roll[i]), math.sin(roll[i])
        right, down = c * right + s * down, -s * right + c * down
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, down, forward
        pose[:3, 3] = (xy[i, 0], xy[i, 1], z[i])
        poses.append(pose)
    return poses


def _interest_directions(scene: Scene, xy: np.ndarray) -> np.ndarray:
    """[n, 2] unit pull towards the furniture of the room each point is in (0 if none)."""
    objects = [o for o in scene.objects if not o.is_background and o.bbox[2] < _OBSTACLE_TOP_M]
    if not objects:
        return np.zeros_like(xy)
    centers = np.array([o.center[:2] for o in objects])
    rooms = np.array([o.room for o in objects])
    here = np.array([scene.room_index_at(x, y) for x, y in xy])
    diff = centers[None] - xy[:, None]
    dist = np.linalg.norm(diff, axis=2) + 1e-6
    weight = (rooms[None] == here[:, None]) / (1.0 + dist)
    pull = np.einsum("nk,nkc->nc", weight, diff / dist[..., None])
    norm = np.linalg.norm(pull, axis=1, keepdims=True)
    pull = np.where(norm > 1e-6, pull / np.maximum(norm, 1e-6), 0.0)
    return pull
