"""VirtualClock with several threads: time moves only when every attached thread sleeps on it, to the
earliest wake-up asked for, so multi-threaded runs are deterministic and nothing waits on the wall clock."""

import threading

import pytest

from hardware.interfaces import VirtualClock, WallClock


def test_single_thread_jumps_at_once():
    clock = VirtualClock(1.0)
    clock.sleep_until(3.5)
    assert clock.now() == 3.5
    clock.sleep_until(2.0)  # already past
    clock.advance(0.5)
    assert clock.now() == 4.0
    with pytest.raises(ValueError, match="dt must be >= 0"):
        clock.advance(-1)


def test_threads_interleave_in_time_order():
    clock = VirtualClock()
    clock.attach()
    log = []

    def ticker(name, period, n):
        try:
            for _ in range(n):
                clock.sleep_until(clock.now() + period)
                log.append((round(clock.now(), 9), name))
        finally:
            clock.detach()

    threads = [threading.Thread(target=ticker, args=("a", 0.3, 3)), threading.Thread(target=ticker, args=("b", 0.2, 4))]
    for th in threads:
        clock.attach(th)  # before start: time must not move before the thread has run
        th.start()
    assert clock.now() == 0.0
    clock.sleep_until(1.0)
    for th in threads:
        th.join()
    assert log == [(0.2, "b"), (0.3, "a"), (0.4, "b"), (0.6, "a"), (0.6, "b"), (0.8, "b"), (0.9, "a")] or \
        log == [(0.2, "b"), (0.3, "a"), (0.4, "b"), (0.6, "b"), (0.6, "a"), (0.8, "b"), (0.9, "a")]  # a tie at 0.6
    assert clock.now() == 1.0


def test_time_waits_for_a_running_attached_thread():
    clock = VirtualClock()
    done = threading.Event()

    def worker():
        try:
            sum(i * i for i in range(300_000))  # computing outside the clock: time must not move meanwhile
            done.set()
        finally:
            clock.detach()

    th = threading.Thread(target=worker)
    clock.attach(th)
    th.start()
    assert clock.wait(done, 10.0)  # returns when the worker sets it, at virtual time 0
    assert clock.now() == 0.0
    th.join()


def test_a_finished_thread_no_longer_holds_time():
    clock = VirtualClock()
    th = threading.Thread(target=lambda: None)  # ends without detaching
    clock.attach(th)
    th.start()
    th.join()
    clock.sleep_until(2.0)
    assert clock.now() == 2.0


def test_a_follower_alone_never_runs_time_on():
    clock = VirtualClock()
    stop, ticks = threading.Event(), []

    def follower():  # like the watchdog: a check every 0.1 s of clock time
        try:
            while not clock.wait(stop, 0.1):
                ticks.append(round(clock.now(), 9))
        finally:
            clock.detach()

    th = threading.Thread(target=follower)
    clock.attach(th, follows=True)
    th.start()
    sum(i * i for i in range(300_000))  # this thread (not attached) works; the follower must not run time on
    assert clock.now() == 0.0 and ticks == []
    clock.sleep_until(0.35)  # a thread that wants time to move: the follower ticks along
    assert ticks == [0.1, 0.2, 0.3] and clock.now() == 0.35
    stop.set()
    th.join()


def test_wait_times_out_in_virtual_time():
    clock = VirtualClock()
    assert not clock.wait(threading.Event(), 0.25)
    assert clock.now() == 0.25
    ev = threading.Event()
    ev.set()
    assert clock.wait(ev, 1.0) and clock.now() == 0.25


def test_wall_clock_defaults():
    clock = WallClock()
    ev = threading.Event()
    ev.set()
    clock.attach()
    clock.detach()
    assert clock.realtime and clock.wait(ev, 0.0)
