"""A resumable run's wall seconds across invocations, kept beside its results so a stopped run is counted."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

from controltac_il.io import write_json


class WallTime:
    """A resumable grid's wall seconds across invocations: the finished ones in ``RUNS/wall_s.json``, the running
    one in ``RUNS/wall_s_running.json`` at every save and every ``HEARTBEAT_S`` between saves (:meth:`beat`), so a
    stopped invocation counts up to a minute before its stop, not to its last landed unit. ``earlier``: the history a
    committed ``--out`` carries when ``RUNS`` is new (another session's machine)."""

    HEARTBEAT_S = 60.0

    def __init__(self, runs: Path, resume: bool, clock=time.perf_counter, earlier: list | None = None):
        self.clock, self.lock, self.stop = clock, threading.Lock(), threading.Event()
        self.history_path, self.running_path = runs / "wall_s.json", runs / "wall_s_running.json"
        self.history = []
        if resume:  # the stopped invocation is in the running file and, on a machine that kept RUNS, in --out too
            running = [json.loads(self.running_path.read_text())] if self.running_path.is_file() else []
            if self.history_path.is_file():
                self.history = json.loads(self.history_path.read_text()) + running
            else:  # --out's last invocation is the running file's, saved at a landing, so no later than it
                self.history = list(earlier or [])[:-1] + running if running else list(earlier or [])
            if running:
                write_json(self.history_path, self.history)
                self.running_path.unlink()
        self.t0 = clock()
        self.thread = threading.Thread(target=self.beat, daemon=True, name="wall-time")

    def now(self) -> dict:
        """This invocation's seconds so far (also kept in the running file), the earlier ones and the total."""
        with self.lock:
            elapsed = round(self.clock() - self.t0, 1)
            write_json(self.running_path, elapsed)
        return {"this_invocation": elapsed, "earlier_invocations": self.history,
                "total": round(sum(self.history) + elapsed, 1)}

    def beat(self) -> None:
        """Keep the running file current until :meth:`finish` (the body of :meth:`start`'s daemon thread)."""
        while not self.stop.wait(self.HEARTBEAT_S):
            self.now()

    def start(self) -> None:
        """Beat in a daemon thread until :meth:`finish`."""
        self.thread.start()

    def finish(self) -> None:
        """End the beat, then move this invocation from the running file to the history."""
        self.stop.set()
        if self.thread.is_alive():
            self.thread.join()
        self.history.append(round(self.clock() - self.t0, 1))
        write_json(self.history_path, self.history)
        self.running_path.unlink(missing_ok=True)
