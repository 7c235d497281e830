"""Benchmark scripts: print figures, never assert timings."""
