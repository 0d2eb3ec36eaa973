"""Benchmarks: ``python -m benchmarks.<subject> --out FILE.json``.

Each prints a table and writes JSON whose first key, ``machine``, records where it ran.
"""
