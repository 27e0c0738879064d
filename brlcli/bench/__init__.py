"""Benchmarks: the paper's lane-keeping test table and the CoRL2017 suite (definitions in docs/benchmarks.md)."""
