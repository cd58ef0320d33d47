"""Prometheus text exposition, without a client library: counters, gauges, histograms."""

from __future__ import annotations

import bisect
import threading
from collections import defaultdict

LATENCY_BUCKETS_MS = (1, 2.5, 5, 10, 20, 40, 80, 160, 320, 640, 1280, 2560)


class Metrics:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counters: dict[tuple[str, tuple], float] = defaultdict(float)
        self._hist: dict[str, list] = {}
        self._help: dict[str, tuple[str, str]] = {}

    def describe(self, name: str, kind: str, text: str) -> None:
        self._help[name] = (kind, text)

    def inc(self, name: str, value: float = 1.0, **labels: str) -> None:
        with self._lock:
            self._counters[(name, tuple(sorted(labels.items())))] += value

    def observe_ms(self, name: str, value_ms: float) -> None:
        with self._lock:
            counts, total = self._hist.setdefault(
                name, [[0] * (len(LATENCY_BUCKETS_MS) + 1), [0.0, 0]]
            )
            counts[bisect.bisect_left(LATENCY_BUCKETS_MS, value_ms)] += 1
            total[0] += value_ms
            total[1] += 1

    def render(self, gauges: dict[str, float]) -> str:
        lines: list[str] = []
        with self._lock:
            names = sorted({n for n, _ in self._counters} | set(self._hist) | set(gauges))
            for name in names:
                kind, text = self._help.get(name, ("untyped", name))
                lines += [f"# HELP {name} {text}", f"# TYPE {name} {kind}"]
                if name in gauges:
                    lines.append(f"{name} {gauges[name]:g}")
                for (cname, labels), value in sorted(self._counters.items()):
                    if cname == name:
                        label_text = ",".join(f'{k}="{v}"' for k, v in labels)
                        lines.append(
                            f"{name}{{{label_text}}} {value:g}" if labels else f"{name} {value:g}"
                        )
                if name in self._hist:
                    counts, (total, n) = self._hist[name]
                    cumulative = 0
                    for bound, count in zip((*LATENCY_BUCKETS_MS, "+Inf"), counts, strict=True):
                        cumulative += count
                        lines.append(f'{name}_bucket{{le="{bound}"}} {cumulative}')
                    lines += [f"{name}_sum {total:g}", f"{name}_count {n}"]
        return "\n".join(lines) + "\n"


def make_metrics() -> Metrics:
    m = Metrics()
    m.describe("semanticxr_frames_total", "counter", "Frames received, by outcome")
    m.describe("semanticxr_bytes_in_total", "counter", "Upstream payload bytes, by kind")
    m.describe("semanticxr_bytes_out_total", "counter", "Downstream update bytes, by kind")
    m.describe("semanticxr_dropped_frames_total", "counter", "Keyframes superseded by newer ones")
    m.describe(
        "semanticxr_persist_failures_total",
        "counter",
        "Failed writes to the store (keyframe commits, counter saves); a keyframe whose "
        "commit failed was undone and refused",
    )
    m.describe(
        "semanticxr_mapping_failures_total",
        "counter",
        "Keyframes whose mapping raised an unexpected error (undone and refused as internal)",
    )
    m.describe(
        "semanticxr_slow_subscribers_closed_total",
        "counter",
        "Update subscribers closed (1013) because they could not keep up",
    )
    for fault in (
        "semanticxr_dropped_frames_total",
        "semanticxr_persist_failures_total",
        "semanticxr_mapping_failures_total",
        "semanticxr_slow_subscribers_closed_total",
    ):
        m.inc(fault, 0)  # present at 0 from the start: a dashboard can tell 0 from missing
    m.describe(
        "semanticxr_mapping_latency_ms",
        "histogram",
        "Server time per mapped keyframe: decode + perception + mapping + delta "
        "(committed to the delta log and the store), without queueing",
    )
    m.describe("semanticxr_query_latency_ms", "histogram", "Server query latency")
    m.describe("semanticxr_sessions", "gauge", "Sessions held")
    m.describe("semanticxr_subscribers", "gauge", "Update subscribers connected")
    return m
