"""The revisit table prints every figure, the walk's share of the time to update beside it."""

from __future__ import annotations

from evaluation.revisit import format_revisit_table


def test_the_table_has_a_row_per_mode_and_the_walks_share_of_the_time_to_update():
    changes = {
        "precision": 1.0,
        "precision_wilson_low": 0.92,
        "recall": 0.9,
        "recall_wilson_low": 0.8,
        "time_to_update_s": {"p95": 8.4},
        "walk_bound_s": {"p95": 6.0},
        "beyond_walk_bound_s": {"p95": None},
        "false_removals_occluded": 0,
        "stale_answers": 2,
        "stale_answers_shown_enough": 0,
        "last_seen_error_m": {"p50": 0.06},
        "last_seen_error_s": {"p50": 0.0},
        "mapping_cost_pct": 12.6,
        "added": {"precision": 0.8, "recall": 0.9},
    }
    result = {
        "scene": "apartment",
        "seeds": [0],
        "scripted_changes": 14,
        "walk_frames": 500,
        "gap_s": 600.0,
        "modes": {"semanticxr": {"changes": changes}},
    }
    lines = format_revisit_table(result).splitlines()
    assert "t2u p95 s  walk beyond" in lines[1]
    row = lines[2].split()
    assert row[0] == "semanticxr"
    assert row[5:8] == ["8.4", "6.0", "-"]  # t2u, walk, beyond (none measured)
    assert row[9] == "2/0"  # stale answers: all, about things the walk showed enough
    assert lines[-1].startswith("targets:")
