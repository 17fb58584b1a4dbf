"""Benchmarks: `make bench` runs every bench_*.py module's main(); results are printed, never asserted."""
