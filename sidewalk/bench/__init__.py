"""Benchmarks printed by ``runners/bench.py``: one module per section, each with ``run(args) -> list[dict]``."""
