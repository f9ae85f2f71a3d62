"""Benchmarks: ``python -m bench [NAME ...] [--quick]`` runs every ``bench/bench_*.py`` and prints one table.

Each benchmark module defines ``run(quick: bool) -> list[bench.common.Result]``; a result names the
figure, our value, and where a peer was measured in the same run, the peer's value and the ratio.
"""
