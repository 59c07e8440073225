"""The benchmark suite: this framework against what users would pick instead, as ratios measured
in one process (`python -m bench --help`; the sections are `ik_throughput`, `select_time`,
`simulator` and `scaling`, run together by `bench.run`)."""
