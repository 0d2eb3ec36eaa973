"""Robustness probes: bad input, faults and interruptions on every public surface, each with its verdict.

    python -m benchmarks.robustness --out benchmarks/results/robustness.json       # all probes
    python -m benchmarks.robustness --only hardware.check                           # one surface

Verdicts (``harness.VERDICTS``):
    clear error    refused: exit 2 with a one-line message, or an exception whose one-line message names
                   what is wrong (the flag, the field or the file)
    handled        the right thing happened (e.g. an interrupted build resumed, a file left alone)
    unclear error  refused, but with a raw traceback or a message that does not name what is wrong
    silent wrong   accepted, and something wrong was produced
    data loss      a file the user owns was changed or removed

Modules: harness.py (verdicts, fixtures, the probe registry), probes_*.py (the probes, one surface
family each), __main__.py (runs them, writes the JSON table).
"""
