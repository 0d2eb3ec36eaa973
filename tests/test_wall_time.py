"""A resumable grid's wall time: each invocation counted once, a stopped one up to its last save or beat."""

import json

from benchmarks.wall_time import WallTime


def test_wall_time_adds_up_across_a_stopped_and_a_resumed_invocation(tmp_path):
    t = [1000.0]
    first = WallTime(tmp_path, resume=False, clock=lambda: t[0])
    t[0] += 100.0
    assert first.now()["this_invocation"] == 100.0  # saved; then the invocation is stopped
    second = WallTime(tmp_path, resume=True, clock=lambda: t[0])  # picks the stopped one up from its file
    t[0] += 50.0
    assert second.now() == {"this_invocation": 50.0, "earlier_invocations": [100.0], "total": 150.0}
    second.finish()
    assert WallTime(tmp_path, resume=True, clock=lambda: t[0]).history == [100.0, 50.0]
    assert WallTime(tmp_path, resume=False).history == []  # a new grid starts from zero
    fresh = WallTime(tmp_path / "new", resume=True, clock=lambda: t[0], earlier=[7.0, 8.0])
    assert fresh.now()["total"] == 15.0  # another machine: the history the committed --out carries
    kept = tmp_path / "kept"  # this machine again, before any invocation finished: --out and the running file agree
    stopped = WallTime(kept, resume=False, clock=lambda: t[0])
    t[0] += 30.0
    assert stopped.now()["this_invocation"] == 30.0  # saved to the running file and to --out; then stopped
    again = WallTime(kept, resume=True, clock=lambda: t[0], earlier=[30.0])
    assert again.history == [30.0]  # counted once


def test_wall_time_beats_between_landings_so_a_stop_counts_to_its_last_beat(tmp_path):
    t = [0.0]
    wall = WallTime(tmp_path, resume=False, clock=lambda: t[0])

    class Minutes:  # the beat's wait: a heartbeat passes each call, the stop comes on the fourth
        calls = 0

        def wait(self, timeout):
            assert timeout == WallTime.HEARTBEAT_S
            Minutes.calls += 1
            t[0] += timeout
            return Minutes.calls > 3

    wall.stop = Minutes()
    wall.beat()  # no unit landed: only the beat wrote
    assert json.loads((tmp_path / "wall_s_running.json").read_text()) == 3 * WallTime.HEARTBEAT_S
    again = WallTime(tmp_path, resume=True, clock=lambda: t[0], earlier=[20.0])  # --out: the last landing
    assert again.history == [3 * WallTime.HEARTBEAT_S]  # the running file's later figure, counted once
    again.start()  # a real thread, waiting a heartbeat: finish wakes and joins it before the history is written
    t[0] += 5.0
    again.finish()
    assert not again.thread.is_alive() and not (tmp_path / "wall_s_running.json").exists()
    assert json.loads((tmp_path / "wall_s.json").read_text()) == [3 * WallTime.HEARTBEAT_S, 5.0]
