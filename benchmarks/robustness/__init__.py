"""Robustness probes: bad input, faults and interruptions on every public surface, each with its verdict.

    python -m benchmarks.robustness --out benchmarks/results/robustness.json       # all probes
    python -m benchmarks.robustness --only hardware.check                           # one surface
    python -m benchmarks.robustness --faults --out /tmp/robustness.json             # the CLIs' runtime faults

Verdicts (``harness.VERDICTS``):
    clear error    refused: exit 2 with a one-line message, or an exception whose one-line message names
                   what is wrong (the flag, the field or the file)
    handled        the right thing happened (e.g. an interrupted build resumed, a file left alone)
    unclear error  refused, but with a raw traceback or a message that does not name what is wrong
    silent wrong   accepted, and something wrong was produced
    data loss      a file the user owns was changed or removed

Every row also records, for a command, its exit code and whether it reported on one line (stderr, progress
bars aside, one line and no traceback). The runtime-fault probes (``probes_faults.py``, kind "fault") run every
CLI a user runs into what a user can cause or meet: a missing or corrupt file, a robot that does not answer, a
checkpoint that does not fit, Ctrl-C, an output it cannot write; each must print one line and exit non-zero.

Modules: harness.py (verdicts, fixtures, the probe registry), probes_*.py (the probes, one surface
family each), __main__.py (runs them, writes the JSON table).
"""
