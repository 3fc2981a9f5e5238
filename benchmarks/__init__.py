"""Benchmarks: figures, not pass/fail."""
