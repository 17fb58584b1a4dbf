"""Benchmarks: `make bench` runs every bench_*.py module's main(), then the table of the performance targets
(benchmarks/targets.py; `python -m benchmarks targets` runs only what the table needs, `--markdown PATH`
writes it as docs/performance-table.md). The in-process benches run pure and compiled side by side
(benchmarks/sides.py), the EtherCAT ones over a veth pair (benchmarks/wire.py). Results are printed,
never asserted."""
