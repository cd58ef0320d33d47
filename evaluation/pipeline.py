"""What every scenario does between the world and the scores: the frames between keyframes
kept for sighting, and the keyframes fed through decode, mapping and the downstream update
(`map_keyframes`), every organisation on the same bytes."""

from __future__ import annotations

import sys
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field

import msgpack
import numpy as np

from app.mapping.engine import MappingEngine
from app.mapping.object import Change, MapObject
from app.mapping.publish import update_message
from app.protocol import FrameInput, parse_frame, parse_sighting
from app.protocol.delta import SEQ_FIELD
from app.protocol.frame import DETECTIONS_FIELD, INSTANCES_FIELD, LABEL_FIELD
from client_sim.encoder import FrameEncoder, downsample_depth
from client_sim.sources.synthetic import SyntheticFrame

Progress = Callable[[str], None]
"""Where a scenario reports how far it got (one line at a time)."""


def stderr_progress(message: str) -> None:
    """The default `Progress`: a line on stderr."""
    print(message, file=sys.stderr, flush=True)


@dataclass
class Sighting:
    """A non-keyframe sent whole, kept compact between rendering and mapping (instance ids
    compressed)."""

    seq: int
    t: float
    pose: np.ndarray
    intrinsics: tuple
    rgb_size: tuple[int, int]
    depth_by_ratio: dict[int, np.ndarray]
    instance_ids_z: bytes
    instances: list[dict]

    @classmethod
    def of(cls, frame: SyntheticFrame, encoders: dict[int, FrameEncoder]) -> Sighting:
        """A rendered frame kept for sighting, its depth at each encoder's ratio."""
        height, width = frame.depth_m.shape
        return cls(
            seq=frame.index,
            t=frame.t,
            pose=frame.pose,
            intrinsics=frame.intrinsics,
            rgb_size=(width, height),
            depth_by_ratio={
                ratio: downsample_depth(frame.depth_m, ratio, encoder.depth_method)
                for ratio, encoder in encoders.items()
            },
            instance_ids_z=zlib.compress(
                np.ascontiguousarray(frame.instance_ids, np.uint16).tobytes(), 1
            ),
            instances=frame.instances,
        )

    def frame(self, ratio: int) -> FrameInput:
        w, h = self.rgb_size
        ids = np.frombuffer(zlib.decompress(self.instance_ids_z), np.uint16).reshape(h, w)
        return FrameInput(
            seq=self.seq,
            t=self.t,
            pose=self.pose,
            intrinsics=self.intrinsics,
            rgb_size=self.rgb_size,
            depth_m=self.depth_by_ratio[ratio],
            instance_ids=ids,
            instances=self.instances,
        )

    def decode(self, engine: MappingEngine, ratio: int) -> tuple[FrameInput, object]:
        """(frame, sent) as the server would hand them to `sight`."""
        frame = self.frame(ratio)
        return frame, engine.validate_frame(frame)


@dataclass
class SightingMessage:
    """A non-keyframe as the device's `sighting` message (the sightings extension)."""

    packed: bytes

    def decode(self, engine: MappingEngine, ratio: int) -> tuple[FrameInput, object]:
        """(frame, sent) as the server would hand them to `sight` (any depth ratio: a
        sighting's depth has its own)."""
        frame = parse_sighting(msgpack.unpackb(self.packed))
        return frame, engine.validate_sighting(frame)


def labels_of(messages: list[dict]) -> list[str]:
    """The distinct detection labels in encoded frames, in first-seen order."""
    labels = (
        inst[LABEL_FIELD]
        for message in messages
        for inst in message.get(DETECTIONS_FIELD, {}).get(INSTANCES_FIELD, [])
    )
    return list(dict.fromkeys(labels))


@dataclass
class MappedRun:
    """What mapping the keyframes cost one engine."""

    latencies_ms: list[float] = field(default_factory=list)
    """Per keyframe: decode + mapping + the downstream update."""
    update_bytes: list[int] = field(default_factory=list)
    """Size of each downstream update."""
    stages_ms: dict[str, list[float]] = field(default_factory=dict)
    """Per keyframe, by stage: "decode", the engine's own stages (IntegrationStats.timings_ms
    but its "total") and "update" (0 on keyframes without one)."""

    sightings_ms: list[float] = field(default_factory=list)
    """Per non-keyframe handed over as sightings: decode + validate + `MappingEngine.sight`."""

    changes: list[Change] = field(default_factory=list)
    """What the living map concluded on the walk (added, moved, removed), in order."""
    retired: list[MapObject] = field(default_factory=list)
    """The objects it removed from the map (kept as history), as they were removed."""
    retracted_added: set[int] = field(default_factory=set)
    """Objects merged into another after their `added` change: it no longer stands."""
    retracted_removed: set[int] = field(default_factory=set)
    """Removed objects found later at a new place: their `removed` change no longer stands."""

    def standing_changes(self) -> list[Change]:
        """The changes as the store keeps them: retracted ones left out."""
        return [
            c
            for c in self.changes
            if not (c.kind == "added" and c.id in self.retracted_added)
            and not (c.kind == "removed" and c.id in self.retracted_removed)
        ]

    def add_stage(self, stage: str, ms: float) -> None:
        self.stages_ms.setdefault(stage, []).append(ms)


def map_keyframe(
    engine: MappingEngine,
    message: dict,
    run: MappedRun,
    published: dict[str, int],
    name: str,
) -> None:
    """One keyframe's wire message through decode + mapping + the downstream update into
    `run` (docs/evaluation.md "Evaluation definitions": mapping latency): its changes, the
    objects it retired or retracted, its latency and stages; `published[name]` is the seq the
    engine's last downstream update went out at."""
    t0 = time.perf_counter()
    frame = parse_frame(message, engine.backend.needs_rgb)
    t1 = time.perf_counter()
    stats = engine.integrate(frame)
    run.changes.extend(stats.changes)
    run.retired.extend(stats.retired)
    run.retracted_added.update(stats.retracted_added)
    run.retracted_removed.update(stats.retracted_removed)
    t2 = time.perf_counter()
    if stats.keyframe % engine.knobs.local_map_update_frequency == 0:
        update = update_message(engine, published[name])
        run.update_bytes.append(len(msgpack.packb(update)))
        published[name] = update[SEQ_FIELD]
    t3 = time.perf_counter()
    run.latencies_ms.append((t3 - t0) * 1e3)
    run.add_stage("decode", (t1 - t0) * 1e3)
    for stage, ms in stats.timings_ms.items():
        if stage != "total":
            run.add_stage(stage, ms)
    run.add_stage("update", (t3 - t2) * 1e3)


def map_keyframes(
    messages: dict[str, list[dict]],
    engines: dict[str, MappingEngine],
    progress: Progress,
    sightings: dict[int, list[Sighting | SightingMessage]] | None = None,
    ratios: dict[str, int] | None = None,
) -> dict[str, MappedRun]:
    """Feed each engine its wire messages through decode + mapping + the downstream update
    (docs/evaluation.md "Evaluation definitions": mapping latency). The engines take turns keyframe by keyframe, so a change
    in machine load during the run affects every organisation alike.

    sightings: the non-keyframes after each keyframe (by its position), handed to each
    engine's `sight` after that keyframe at its depth ratio (`ratios`, by engine name,
    required with sightings)."""
    sightings = sightings or {}
    n_keyframes = len(next(iter(messages.values()), []))
    runs = {name: MappedRun() for name in engines}
    published = dict.fromkeys(engines, 0)
    for i in range(n_keyframes):
        for name, engine in engines.items():
            run = runs[name]
            map_keyframe(engine, messages[name][i], run, published, name)
            for sighting in sightings.get(i, []):
                t4 = time.perf_counter()
                engine.sight(*sighting.decode(engine, ratios[name]))  # type: ignore[index]
                run.sightings_ms.append((time.perf_counter() - t4) * 1e3)
        if (i + 1) % 20 == 0 or i + 1 == n_keyframes:
            progress(
                f"[eval] mapped {i + 1}/{n_keyframes} keyframes: "
                + ", ".join(
                    f"{name} p50 {np.median(runs[name].latencies_ms):.1f} ms" for name in engines
                )
            )
    return runs
