"""Shared bench helpers: targets checked and printed, JSON written, plots saved."""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np


class _HelpFormatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """The module docstring as written, and every flag's default after its help."""


def bench_parser(doc: str | None) -> argparse.ArgumentParser:
    """The argument parser of a bench: its module docstring as the description."""
    return argparse.ArgumentParser(description=doc, formatter_class=_HelpFormatter)


def machine() -> dict:
    import os

    return {
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "platform": platform.platform(),
    }


def check(name: str, value: float, op: str, target: float, unit: str = "") -> dict:
    """A target verdict, printed as it is measured."""
    ok = value <= target if op == "<=" else value >= target
    print(f"  [{'PASS' if ok else 'MISS'}] {name}: {value:.2f}{unit} (target {op} {target}{unit})")
    return {"name": name, "value": value, "op": op, "target": target, "unit": unit, "ok": ok}


def write_outputs(out_dir: str, stem: str, document: dict) -> Path:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{stem}.json"
    path.write_text(json.dumps(document, indent=2) + "\n")
    print(f"wrote {path}", file=sys.stderr)
    return path


def save_plot(fig, out_dir: str, stem: str) -> Path:
    path = Path(out_dir) / f"{stem}.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")
    print(f"wrote {path}", file=sys.stderr)
    return path


def timed_ms(
    run: Callable[[], object], reps: int, before: Callable[[], object] = lambda: None
) -> dict:
    """p50/p95/p99/mean/min in ms of `reps` calls of `run` (after one warm-up call); `before`
    runs untimed before each call (and the warm-up)."""
    before()
    run()
    times_ms = []
    for _ in range(reps):
        before()
        start = time.perf_counter_ns()
        run()
        times_ms.append((time.perf_counter_ns() - start) / 1e6)
    return {
        "p50": float(np.percentile(times_ms, 50)),
        "p95": float(np.percentile(times_ms, 95)),
        "p99": float(np.percentile(times_ms, 99)),
        "mean": float(np.mean(times_ms)),
        "min": float(np.min(times_ms)),
    }
