"""bench.local_map: `--tower static` measures the static tower and keeps the other tower's
figures in local_map.json."""

from __future__ import annotations

import json

from bench.local_map import main


def test_the_static_tower_run_writes_its_figures_beside_the_minilm_ones(tmp_path, capsys):
    minilm = {"config": {"tower": "minilm", "dim": 384}, "sizes": [{"objects": 80}]}
    (tmp_path / "local_map.json").write_text(json.dumps({"towers": {"minilm": minilm}}))

    status = main(
        [
            "--tower", "static", "--sizes", "80,300", "--similarity-reps", "5",
            "--end-to-end-reps", "5", "--out", str(tmp_path),
        ]
    )  # fmt: skip

    document = json.loads((tmp_path / "local_map.json").read_text())
    static = document["towers"]["static"]
    assert status == 0
    assert document["towers"]["minilm"] == minilm
    assert static["config"]["dim"] == 256 and static["config"]["model"].startswith("static-")
    assert "RANDOM rows" in static["config"]["tower_source"]
    assert "RANDOM rows" in capsys.readouterr().out  # said where the figures are read
    assert [row["objects"] for row in static["sizes"]] == [80, 300]
    for row in static["sizes"]:
        assert (
            row["memory_with_tower_bytes"] - row["memory_bytes"]
            == static["config"]["tower_bytes"]
            > 256 * 30_000
        )  # the table at least
        assert {"p50", "p95"} <= row["similarity_ms"].keys() & row["end_to_end_ms"].keys()
    assert static["text_encoding_ms"]["p50"] > 0
    assert (tmp_path / "local_map_static.png").exists()
