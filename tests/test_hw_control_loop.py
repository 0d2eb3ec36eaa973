"""Control loop with fake devices, all on the virtual clock (no test waits on wall-clock time): exact
actions in sync and async inference, and fault injection (policy raises, late policy, stale frame, arm
error, hung arm caught by the watchdog thread, Ctrl-C): the arm is stopped before the exception reaches
the caller, nothing is commanded after the fault, and the error says what happened. Policies are plain
callables; a slow one sleeps on the virtual clock, so its duration is exact."""

import signal
import threading

import numpy as np
import pytest

from controltac_il.config import one_line
from hardware.control_loop import ControlLoop, ControlLoopConfig, LoopTiming, PolicyError, PolicyLateError
from hardware.fakes import FAKE_WORKSPACE, FakeArm, FakeGripper, SyntheticFrameSource
from hardware.interfaces import ArmFault, GripperState, SensorError, VirtualClock
from hardware.safety import SafetyLimits, SafetyViolation, WatchdogTimeout
from hardware.temporal_ensembling import TemporalEnsembler

START = (0.4, 0.0, 0.2, 0.0)
LIMITS = SafetyLimits(**FAKE_WORKSPACE, max_step_m=0.05, max_rotation_rad=0.2)


class RampPolicy:
    """Chunk of targets that creep +1 mm in x per step from the observed pose; records its calls.
    Delays are clock seconds (``make`` hands it the loop's clock)."""

    def __init__(self, chunk=5, delay_s=0.0, fail_on_call=None, late_on_call=None, late_s=1.0):
        self.chunk, self.delay_s = chunk, delay_s
        self.fail_on_call, self.late_on_call, self.late_s = fail_on_call, late_on_call, late_s
        self.calls, self.threads, self.qpos = 0, set(), []
        self.clock = None

    def sleep(self, dt):
        if dt:
            self.clock.sleep_until(self.clock.now() + dt)

    def __call__(self, obs):
        self.calls += 1
        self.threads.add(threading.current_thread().name)
        self.qpos.append(obs["qpos"].copy())
        if self.fail_on_call == self.calls:
            raise RuntimeError("boom in the policy")
        if self.late_on_call is not None and self.calls >= self.late_on_call:
            self.sleep(self.late_s)
        self.sleep(self.delay_s)
        q = obs["qpos"].astype(np.float64)
        out = np.tile(np.r_[q[:4], 0.8], (self.chunk, 1))
        out[:, 0] += 0.001 * np.arange(1, self.chunk + 1)
        return out


def make(clock, policy, inference="sync", tactile=True, watchdog_thread=None, **cfg):
    log = []
    if isinstance(policy, RampPolicy):
        policy.clock = clock
    arm, grip = FakeArm(START, clock, log), FakeGripper(clock, log)
    tac = {"left": SyntheticFrameSource("left", (24, 32), clock, background=True)} if tactile else {}
    cams = {"wrist": SyntheticFrameSource("wrist", (24, 32), clock)}
    loop = ControlLoop(arm, policy, gripper=grip, cameras=cams, tactile=tac, limits=LIMITS,
                       config=ControlLoopConfig(inference=inference, chunk_size=5, **cfg), clock=clock,
                       watchdog_thread=watchdog_thread)
    return loop, arm, log


def commands(log):
    return [v for e, v in log if e == "servo"]


def assert_stopped_after_last_command(log):
    events = [e for e, _ in log]
    assert "arm-stop" in events, events
    last_stop = len(events) - 1 - events[::-1].index("arm-stop")
    assert "servo" not in events[last_stop:] and "gripper" not in events[last_stop:]
    assert events.index("arm-stop") < (events.index("gripper-stop") if "gripper-stop" in events else len(events))


def test_sync_virtual_time_matches_hand_ensembling():
    clock = VirtualClock()
    policy = RampPolicy(chunk=5)
    loop, arm, log = make(clock, policy)
    stats = loop.run(max_steps=6)
    # replay: chunk from step s starts at the pose measured at s (the previous command), ramps +1 mm/step
    ens, pose, expected = TemporalEnsembler(5, 5), np.array(START), []
    for t in range(6):
        chunk = np.tile(np.r_[pose, 0.8], (5, 1))
        chunk[:, 0] += 0.001 * np.arange(1, 6)
        ens.add_chunk(t, chunk)
        a = ens.action(t)
        expected.append(a[:4])
        pose = a[:4]
    np.testing.assert_allclose(np.array(commands(log)), np.array(expected), atol=1e-6)
    assert [v for e, v in log if e == "gripper"] == pytest.approx([0.8] * 6)
    assert policy.threads == {threading.main_thread().name} and policy.calls == 6
    assert clock.now() == pytest.approx(0.6)  # 6 periods at 10 Hz in virtual time: no real waiting
    np.testing.assert_allclose(stats.period_errors_s(), 0.0, atol=1e-9)
    assert stats.steps == 6 and stats.deadline_misses == 0 and stats.stop_reason == "finished 6 steps"
    assert log[-2:] == [("arm-stop", None), ("gripper-stop", None)]


def test_observation_keys_and_qpos():
    clock = VirtualClock()
    seen = {}

    class P(RampPolicy):
        def __call__(self, obs):
            seen.update(obs)
            return super().__call__(obs)

    make(clock, P())[0].run(max_steps=1)
    assert set(seen) == {"qpos", "images/wrist", "tactile/left", "tactile_background/left"}
    assert seen["qpos"].dtype == np.float32 and seen["qpos"].tolist() == pytest.approx([*START, 0.0])
    assert seen["tactile/left"].shape == (24, 32, 3) and seen["tactile/left"].dtype == np.uint8


def test_deadline_miss_is_counted_and_period_error_exact():
    clock = VirtualClock()

    class SlowArm(FakeArm):
        def servo(self, target):
            super().servo(target)
            if len(commands(self.log)) == 3:
                clock.advance(0.15)  # the third cycle's work overruns the 0.1 s period by 0.05 s

    policy = RampPolicy()
    loop, _, log = make(clock, policy)
    loop.arm = SlowArm(START, clock, log)
    loop.config = ControlLoopConfig(inference="sync", chunk_size=5, stale_after_periods=5)
    stats = loop.run(max_steps=5)
    np.testing.assert_allclose(stats.period_errors_s(), [0, 0, 0.05, 0], atol=1e-9)
    assert stats.deadline_misses == 1
    assert stats.summary()["period_error_ms"]["max"] == pytest.approx(50.0)


def test_async_inference_runs_in_its_own_thread_at_10hz():
    clock = VirtualClock()
    policy = RampPolicy(chunk=5, delay_s=0.02)  # 20 ms of virtual time per call
    loop, arm, log = make(clock, policy, inference="async")
    stats = loop.run(max_steps=8)
    assert policy.threads == {"policy"}
    assert stats.steps == 8 and len(commands(log)) == 8
    # the first chunk (warm-up) is waited for; then one call per step from step 1, none ever late
    assert policy.calls == 8 and stats.inference_s == pytest.approx([0.02] * 8)
    assert stats.cycle_starts[0] == pytest.approx(0.02)
    np.testing.assert_allclose(stats.period_errors_s(), 0.0, atol=1e-9)
    # the chunk predicted at step s is used from step s + 1 on: step 1 acts on the warm-up chunk only
    assert commands(log)[1][0] == pytest.approx(START[0] + 0.002)
    assert_stopped_after_last_command(log)


def test_policy_exception_stops_arm_and_names_it():
    policy = RampPolicy(fail_on_call=3)
    loop, arm, log = make(VirtualClock(), policy)
    with pytest.raises(PolicyError, match="policy raised RuntimeError: boom in the policy"):
        loop.run(max_steps=10)
    assert arm.stopped and len(commands(log)) == 2
    assert_stopped_after_last_command(log)
    assert "PolicyError" in loop.stats.stop_reason


def test_async_policy_exception_stops_arm():
    policy = RampPolicy(fail_on_call=2)
    loop, arm, log = make(VirtualClock(), policy, inference="async")
    with pytest.raises(PolicyError, match="boom"):
        loop.run(max_steps=20)
    assert arm.stopped and len(commands(log)) == 2  # the call from step 1 failed; step 2 stops
    assert_stopped_after_last_command(log)


@pytest.mark.parametrize("late_s, says", [
    (1.5, r"step 1 has run 0\.300 s, past inference_deadline_s = 0\.25 s"),  # still running at the poll of t = 0.4 s
    (0.28, r"on the observation of step 1 took 0\.280 s, past inference_deadline_s"),  # ended at 0.38 s, between polls
])
def test_a_late_async_policy_stops_the_arm_whether_or_not_its_call_ended_between_two_polls(late_s, says):
    """The call submitted at step 1 (t = 0.1 s) against a 0.25 s deadline: late at the next poll, its chunk never
    used, whether it is still running then or ended just before."""
    clock = VirtualClock()
    policy = RampPolicy(chunk=5, late_on_call=2, late_s=late_s)
    loop, arm, log = make(clock, policy, inference="async", inference_deadline_s=0.25)
    with pytest.raises(PolicyLateError, match=says):
        loop.run(max_steps=50)
    assert arm.stopped and len(commands(log)) == 4
    assert_stopped_after_last_command(log)


def test_chunks_running_out_is_a_late_policy():
    # sync mode querying every 4 steps, the policy's chunks shorter than it says (3 of 5 steps): step 3 has no action
    loop, arm, log = make(VirtualClock(), RampPolicy(chunk=3), query_every=4)
    with pytest.raises(PolicyLateError, match="no action for step 3"):
        loop.run(max_steps=20)
    assert len(commands(log)) == 3
    assert_stopped_after_last_command(log)


def test_malformed_chunk_is_rejected_before_motion():
    class Bad:
        def __call__(self, obs):
            return np.zeros((5, 4))

    loop, arm, log = make(VirtualClock(), Bad())
    with pytest.raises(PolicyError, match=r"shape \(5, 4\), expected \(L, 5\)"):
        loop.run(max_steps=3)
    assert commands(log) == [] and arm.stopped


def test_nan_action_is_a_safety_violation():
    class NaNAfterTwo(RampPolicy):
        def __call__(self, obs):
            out = super().__call__(obs)
            if self.calls >= 3:
                out[:] = np.nan
            return out

    loop, arm, log = make(VirtualClock(), NaNAfterTwo())
    with pytest.raises(PolicyError, match="NaN or inf"):
        loop.run(max_steps=10)
    assert len(commands(log)) == 2
    assert_stopped_after_last_command(log)


def test_a_nan_gripper_reading_is_a_safety_violation_naming_the_gripper_not_the_policy():
    loop, arm, log = make(VirtualClock(), RampPolicy())
    readings = iter([0.0, 0.0, 0.0])  # the warm-up's and two steps' readings, then NaN
    loop.gripper.state = lambda: GripperState(next(readings, float("nan")), loop.clock.now())
    with pytest.raises(SafetyViolation, match=r"^measured gripper position must be a finite number, got nan$"):
        loop.run(max_steps=10)
    assert len(commands(log)) == 2 and ("gripper-stop", None) in log
    assert_stopped_after_last_command(log)


def test_stale_tactile_frame_stops_arm():
    clock = VirtualClock()
    policy = RampPolicy()
    loop, arm, log = make(clock, policy)

    def on_step(step, obs, target):
        if step == 3:
            loop.tactile["left"].freeze()
        return False

    with pytest.raises(WatchdogTimeout, match=r"no fresh frame tactile/left for 0\.300 s \(limit 0\.200 s\)"):
        loop.run(max_steps=20, on_step=on_step)
    assert len(commands(log)) == 6  # frozen at t=0.3: fine at 0.4 and 0.5, stale at 0.6
    assert_stopped_after_last_command(log)


def test_a_tactile_source_stamping_frames_with_another_clock_stops_the_arm_before_it_moves():
    """A source stamping with the wall clock while the loop runs on its own: its frames would look fresh for
    ever (a stamp ahead of the loop's clock is never stale), so the first one stops the arm."""
    from hardware.interfaces import WallClock

    loop, arm, log = make(VirtualClock(), RampPolicy())
    loop.tactile["left"] = SyntheticFrameSource("left", (24, 32), WallClock(), background=True)
    with pytest.raises(SafetyViolation, match=r"frame tactile/left stamped .*not a time on the loop's clock"):
        loop.run(max_steps=20)
    assert commands(log) == [] and ("arm-stop", None) in log


def test_unplugged_sensor_stops_arm():
    loop, arm, log = make(VirtualClock(), RampPolicy())
    with pytest.raises(SensorError, match="left: device unplugged"):
        loop.run(max_steps=20, on_step=lambda s, o, t: s == 2 and loop.tactile["left"].unplug())
    assert len(commands(log)) == 3
    assert_stopped_after_last_command(log)


def test_arm_error_code_stops_arm():
    loop, arm, log = make(VirtualClock(), RampPolicy())

    def on_step(step, obs, target):
        if step == 4:
            arm.error_code = 31
        return False

    with pytest.raises(ArmFault, match="error code 31"):
        loop.run(max_steps=20, on_step=on_step)
    assert len(commands(log)) == 5
    assert_stopped_after_last_command(log)


class DeadGripper(FakeGripper):
    """A gripper whose line died: stopping it fails."""

    def stop(self):
        raise SensorError("writing the action request failed")


def test_a_device_that_fails_to_stop_on_exit_notes_it_on_the_fault_that_ended_the_run():
    """The run's own fault (the arm's error code) is what surfaces; the gripper's failed stop is a note on it. With
    no fault, a failed stop is raised."""
    clock = VirtualClock()
    loop, arm, log = make(clock, RampPolicy())
    arm.error_code = 31
    with pytest.raises(ArmFault, match="error code 31") as info:
        with DeadGripper(clock, log):
            loop.run(max_steps=3)
    assert info.value.__notes__ == ["DeadGripper.stop failed too: writing the action request failed"]
    assert one_line(info.value).endswith("error code 31; DeadGripper.stop failed too: writing the action request failed")
    with pytest.raises(SensorError, match="writing the action request failed"):
        with DeadGripper(clock, log):
            pass

    class Unclosable(DeadGripper):
        def close(self):
            raise OSError("port vanished")

    with pytest.raises(SensorError) as info:  # no fault in flight: the stop's failure, the close's noted on it
        with Unclosable(clock, log):
            pass
    assert info.value.__notes__ == ["Unclosable.close failed too: port vanished"]


def test_measured_pose_outside_workspace_stops_arm():
    loop, arm, log = make(VirtualClock(), RampPolicy())

    def on_step(step, obs, target):
        if step == 1:
            arm.pose = np.array([2.0, 0.0, 0.2, 0.0])  # e.g. a collision pushed it away
        return False

    with pytest.raises(SafetyViolation, match="outside the workspace box"):
        loop.run(max_steps=20, on_step=on_step)
    assert len(commands(log)) == 2
    assert_stopped_after_last_command(log)


@pytest.mark.parametrize("inference", ["sync", "async"])
def test_hung_arm_is_stopped_by_the_watchdog_thread(inference):
    clock = VirtualClock()
    loop, arm, log = make(clock, RampPolicy(chunk=5), inference=inference, watchdog_thread=True)
    stop_times = []
    arm.stop = lambda: (stop_times.append(clock.now()), FakeArm.stop(arm))

    def on_step(step, obs, target):
        if step == 2:
            arm.servo_delay_s = 0.6  # the servo call at step 3 (t = 0.3 s) hangs until t = 0.9 s
        return False

    with pytest.raises(WatchdogTimeout, match=r"no fresh command for 0\.2\d\d s"):
        loop.run(max_steps=20, on_step=on_step)
    events = [e for e, _ in log]
    hung = events.index("servo-returned")
    assert "arm-stop" in events[:hung], "the watchdog thread must stop the arm while servo() hangs"
    assert "gripper" not in events[hung:], "no gripper command after a servo() the watchdog stopped"
    # last command at t = 0.2 s, limit 0.2 s, checked every 0.05 s: stopped at 0.45 s, long before 0.9 s
    assert stop_times[0] == pytest.approx(0.45) and clock.now() == pytest.approx(0.9)
    assert_stopped_after_last_command(log)


def test_the_first_command_is_one_step_from_where_the_arm_is_after_the_warm_up():
    """The arm drifted 8 cm during the policy's warm-up (the first call): the first command moves at most
    max_step_m (5 cm) from where the arm is then, not from where it was before."""
    clock = VirtualClock()

    class Drifting(RampPolicy):
        def __call__(self, obs):
            if self.calls == 0:
                arm.pose = arm.pose + [0.08, 0.0, 0.0, 0.0]
            return super().__call__(obs)

    loop, arm, log = make(clock, Drifting(chunk=5))
    loop.run(max_steps=1)
    first = commands(log)[0]
    assert np.linalg.norm(first[:3] - [0.48, 0.0, 0.2]) == pytest.approx(0.05)  # toward the chunk's 0.401 m


def test_a_failed_stop_from_the_watchdog_thread_is_noted_on_the_fault():
    """The watchdog thread must not die of the arm's error, nor leave no trace of it: the control thread's
    WatchdogTimeout carries it (the loop's own stop afterwards worked)."""
    clock = VirtualClock()
    loop, arm, log = make(clock, RampPolicy(chunk=5), watchdog_thread=True)
    failures = ["controller unreachable"]

    def stop():
        if failures:
            raise ArmFault(failures.pop())
        FakeArm.stop(arm)

    arm.stop = stop

    def on_step(step, obs, target):
        if step == 2:
            arm.servo_delay_s = 0.6
        return False

    with pytest.raises(WatchdogTimeout) as info:
        loop.run(max_steps=20, on_step=on_step)
    assert info.value.__notes__ == ["the watchdog's arm.stop() failed: ArmFault: controller unreachable"]
    assert log[-2:] == [("arm-stop", None), ("gripper-stop", None)]


def test_a_first_command_that_hangs_is_stopped_by_the_watchdog_thread_without_any_sensor():
    """No camera or tactile feed to watch, and no command sent yet: the control thread is watched from its first
    step all the same."""
    clock, log = VirtualClock(), []
    arm = FakeArm(START, clock, log)
    arm.servo_delay_s = 1.0  # the very first servo() hangs
    loop = ControlLoop(arm, RampPolicy(chunk=5), limits=LIMITS, clock=clock, watchdog_thread=True,
                       config=ControlLoopConfig(inference="sync", chunk_size=5))
    with pytest.raises(WatchdogTimeout, match=r"no fresh command"):
        loop.run(max_steps=5)
    events = [e for e, _ in log]
    assert events.index("arm-stop") < events.index("servo-returned")  # stopped while servo() hung


def test_ctrl_c_stops_arm_and_propagates():
    loop, arm, log = make(VirtualClock(), RampPolicy(), inference="async")
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)

    def on_step(step, obs, target):
        if step == 3:
            signal.raise_signal(signal.SIGINT)  # a real SIGINT to this process, handled in this thread
        return False

    try:
        with pytest.raises(KeyboardInterrupt):
            loop.run(on_step=on_step)  # no max_steps: runs until interrupted
    finally:
        signal.signal(signal.SIGINT, previous)
    assert arm.stopped and loop.stats.stop_reason == "Ctrl-C" and loop.stats.steps == 4
    assert_stopped_after_last_command(log)


@pytest.mark.parametrize(
    "kwargs, field",
    [(dict(rate_hz=0), "rate_hz"), (dict(chunk_size=0), "chunk_size"), (dict(inference="threads"), "inference"),
     (dict(query_every=1.5), "query_every"), (dict(stale_after_periods=-1), "stale_after_periods"),
     (dict(inference="sync", chunk_size=5, query_every=6), r"more steps between policy calls than one chunk covers "
                                                            r"\(chunk_size 5\)")],
)
def test_config_validation_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        ControlLoopConfig(**kwargs)


def test_bad_max_steps():
    loop, _, _ = make(VirtualClock(), RampPolicy())
    with pytest.raises(ValueError, match="max_steps"):
        loop.run(max_steps=0)


def test_slow_first_inference_does_not_trip_the_watchdog():
    # the first chunk (model warm-up) takes 0.4 s, twice the 0.2 s frame-age limit: the loop observes afresh
    class SlowFirst(RampPolicy):
        def __call__(self, obs):
            if self.calls == 0:
                self.sleep(0.4)
            return super().__call__(obs)

    clock = VirtualClock()
    loop, arm, log = make(clock, SlowFirst(), inference="async", watchdog_thread=True)
    stats = loop.run(max_steps=3)
    assert stats.steps == 3 and len(commands(log)) == 3
    assert stats.cycle_starts == pytest.approx([0.4, 0.5, 0.6])


@pytest.mark.parametrize("inference", ["sync", "async"])
def test_inference_s_is_clock_seconds_in_both_modes(inference):
    # one meaning in both modes: the loop's clock seconds. A policy that sleeps 30 ms on the (virtual) clock
    # takes exactly 0.03 s; one that only burns CPU takes no clock time at all, whatever the wall clock says
    loop, _, _ = make(VirtualClock(), RampPolicy(chunk=5, delay_s=0.03), inference=inference)
    stats = loop.run(max_steps=4)
    assert stats.inference_s and stats.inference_s == pytest.approx([0.03] * len(stats.inference_s), abs=1e-12)

    class Busy(RampPolicy):
        def __call__(self, obs):
            sum(i * i for i in range(20000))  # wall time only
            return super().__call__(obs)

    loop, _, _ = make(VirtualClock(), Busy(chunk=5), inference=inference)
    assert set(loop.run(max_steps=4).inference_s) == {0.0}


def test_sync_deadline_uses_the_recorded_clock_seconds():
    clock = VirtualClock()
    policy = RampPolicy(chunk=5, late_on_call=3, late_s=0.7)
    loop, arm, log = make(clock, policy, inference_deadline_s=0.5)
    with pytest.raises(PolicyLateError, match=r"policy inference at step 2 took 0\.700 s, past its deadline of 0\.5 s"):
        loop.run(max_steps=10)
    assert loop.stats.inference_s == pytest.approx([0.0, 0.0, 0.7]) and arm.stopped


def test_async_deadline_must_fit_in_the_policys_chunk():
    # asynchronous: a call longer than one chunk runs the loop out of actions first, so such a deadline never fires
    with pytest.raises(ValueError) as info:
        ControlLoopConfig(inference="async", chunk_size=3, inference_deadline_s=0.5)
    assert one_line(info.value) == (
        "inference_deadline_s: longer than one chunk of the policy (chunk_size 3 x 0.1 s = 0.3 s): asynchronous "
        "inference runs out of actions first, so the deadline would never fire; at most 0.3 s (got 0.5)")
    assert ControlLoopConfig(inference="sync", chunk_size=3, inference_deadline_s=0.5).chunk_size == 3  # the call's own
    # the chunk size and the decay are the policy's: for_policy adds them to a setup's timing, and checks again
    timing = LoopTiming(rate_hz=20.0, inference_deadline_s=0.2)
    cfg = ControlLoopConfig.for_policy(timing, chunk_size=6, ensemble_k=0.02)
    assert (cfg.rate_hz, cfg.inference_deadline_s, cfg.chunk_size, cfg.ensemble_k) == (20.0, 0.2, 6, 0.02)
    with pytest.raises(ValueError) as info:
        ControlLoopConfig.for_policy(timing, chunk_size=3, ensemble_k=0.02)
    assert one_line(info.value).startswith("inference_deadline_s: longer than one chunk of the policy (chunk_size 3 x "
                                           "0.05 s = 0.15 s)")
    with pytest.raises(ValueError, match="chunk_size"):
        LoopTiming(chunk_size=20)  # a setup's timing has no chunk size
