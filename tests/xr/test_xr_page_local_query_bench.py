"""bench.page_local_query runs end to end on a small map (its figures are the bench's to
judge, not this test's): the page answers, each stage is timed, the tower's sizes are said.
In a process of its own: a second Playwright cannot start beside the tests' own."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).parents[2]


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_page_bench_answers_a_small_map_and_writes_its_figures(tmp_path):
    command = [sys.executable, "-m", "bench.page_local_query", "--objects", "300"]
    command += ["--queries", "20", "--out", str(tmp_path)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), *sys.path])}
    done = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=280)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    document = json.loads((tmp_path / "bench_page_local_query.json").read_text())
    figures = document["sizes"]["300"]
    assert figures["objects"] == 300 and figures["lq_ms"]["n"] == 20
    assert {"embed_ms", "rank_ms", "rate_ms", "load_ms"} <= figures.keys()
    tower = document["tower"]
    assert tower["dim"] == 256 and 0 < tower["gzip_bytes"] < tower["bytes"]
    assert document["lq_equals_sq"] is None  # --compare not asked
