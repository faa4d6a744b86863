"""Benchmarks and evidence scripts, grouped by the question each answers (run as
``python -m benchmarks.<question>.<name>``; ``benchmarks/README.md`` lists them)."""
