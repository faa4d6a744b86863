"""Benchmarks and evidence scripts (run as python -m benchmarks.<name>)."""
