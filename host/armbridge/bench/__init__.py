"""Benchmarks: `armbridge bench ...` measures and writes JSON (docs/benchmarks.md)."""
