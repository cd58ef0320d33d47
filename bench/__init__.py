"""Benchmarks: speed, size and quality figures, side by side with the baseline (never in tests)."""
