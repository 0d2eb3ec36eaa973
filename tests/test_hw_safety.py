"""Safety filter and watchdog: exact clamping semantics, counts, violations, bad configuration."""

import dataclasses
import math
import re

import numpy as np
import pytest

from hardware.control_loop import ControlLoop
from hardware.fakes import FAKE_WORKSPACE
from hardware.interfaces import VirtualClock
from hardware.safety import SafetyFilter, SafetyLimits, SafetyViolation, Watchdog, WatchdogTimeout, wrap_angle

LIMITS = SafetyLimits(workspace_min=(0.0, -0.5, 0.0), workspace_max=(1.0, 0.5, 0.5), max_step_m=0.01,
                      max_rotation_rad=0.05, gripper_min=0.1, gripper_max=0.9)


def make_filter(pose=(0.5, 0.0, 0.2, 0.0)):
    f = SafetyFilter(LIMITS)
    f.reset(np.array(pose))
    return f


def test_action_within_limits_passes_unchanged():
    f = make_filter()
    a = np.array([0.505, 0.003, 0.2, 0.02, 0.5])
    np.testing.assert_array_equal(f(a), a)
    assert f.counts.as_dict() == dict(workspace=0, yaw_range=0, step=0, rotation=0, tracking=0, gripper=0)


def test_large_step_is_scaled_along_its_direction():
    f = make_filter()
    out = f(np.array([0.53, 0.04, 0.2, 0.0, 0.5]))  # 5 cm away along (3, 4)/5
    np.testing.assert_allclose(out[:3], [0.5 + 0.006, 0.008, 0.2], atol=1e-12)
    assert f.counts.step == 1
    out2 = f(np.array([0.53, 0.04, 0.2, 0.0, 0.5]))  # the next step starts from the last command
    np.testing.assert_allclose(out2[:3], [0.512, 0.016, 0.2], atol=1e-12)


def test_an_arm_blocked_by_contact_is_never_commanded_further_than_the_tracking_limit_ahead():
    """A policy pushing down while the arm stays blocked: commands walk one step a period until they are two
    steps (the default tracking limit) ahead of the measured pose, then stay there, pulled along the push; an
    arm that follows is never pulled. A measured pose just outside the box does not pull a command out of it."""
    f, push, zs = make_filter(), np.array([0.5, 0.0, 0.0, 0.0, 0.5]), []
    for z in (0.2, 0.195, 0.195, 0.195, 0.195):  # moved half a step, then blocked at 0.195 m
        f.check_state(np.array([0.5, 0.0, z, 0.0]))
        zs.append(f(push)[2])
    np.testing.assert_allclose(zs, [0.19, 0.18, 0.175, 0.175, 0.175], atol=1e-12)
    assert LIMITS.tracking_m == 0.02 and f.counts.tracking == 3
    g = make_filter()
    for _ in range(5):  # the arm reaches every command: the step limit alone applies
        out = g(push)
        g.check_state(out[:4])
    assert out[2] == pytest.approx(0.15) and g.counts.tracking == 0
    h = make_filter(pose=(0.5, 0.0, 0.005, 0.0))
    h.check_state(np.array([0.5, 0.0, -0.01, 0.0]))  # 1 cm below the floor: within state_tolerance_m
    out = h(np.array([0.5, 0.0, 0.2, 0.0, 0.5]))
    assert out[2] == pytest.approx(0.01) and h.counts.tracking == 1  # two steps ahead of -0.01 m, inside the box
    pushed = make_filter(pose=(0.5, 0.0, 0.2, 0.0))
    pushed(np.array([0.5, 0.0, 0.19, 0.0, 0.5]))
    pushed.check_state(np.array([0.5, 0.0, 0.13, 0.0]))  # pushed 6 cm down by the world, under the command
    z = pushed(np.array([0.5, 0.0, 0.19, 0.0, 0.5]))[2]
    assert z == pytest.approx(0.15) and pushed.counts.tracking == 1  # 4 cm back toward the arm in one period
    wide = SafetyLimits(workspace_min=(0.0, -0.5, 0.0), workspace_max=(1.0, 0.5, 0.5), max_step_m=0.01,
                        max_tracking_m=0.05)
    assert wide.tracking_m == 0.05


def test_workspace_clamp_then_step_limit():
    f = make_filter(pose=(0.995, 0.0, 0.2, 0.0))
    out = f(np.array([1.5, 0.0, 0.2, 0.0, 0.5]))
    assert out[0] == pytest.approx(1.0)
    assert f.counts.workspace == 1 and f.counts.step == 0


def test_wrap_angle_lands_in_the_half_open_interval_at_its_seam():
    """Just below -pi the modulo rounds up to 2 pi; the heading is -pi (pi is outside [-pi, pi))."""
    below, above = np.nextafter(-math.pi, -np.inf), np.nextafter(math.pi, np.inf)
    wrapped = wrap_angle(np.array([below, -math.pi, math.pi, above, 3 * math.pi, -3 * math.pi]))
    assert ((wrapped >= -math.pi) & (wrapped < math.pi)).all(), wrapped.tolist()
    assert wrapped[1] == -math.pi and wrapped[2] == -math.pi


def test_yaw_step_wraps_through_pi():
    f = make_filter(pose=(0.5, 0.0, 0.2, math.pi - 0.02))
    out = f(np.array([0.5, 0.0, 0.2, -math.pi + 0.01, 0.5]))  # 0.03 rad across the seam: allowed
    assert wrap_angle(out[3] - (-math.pi + 0.01)) == pytest.approx(0.0, abs=1e-12)
    out = f(np.array([0.5, 0.0, 0.2, -math.pi + 0.5, 0.5]))  # 0.49 rad: limited to 0.05
    assert wrap_angle(out[3] - (-math.pi + 0.06)) == pytest.approx(0.0, abs=1e-12)
    assert f.counts.rotation == 1


def test_a_narrower_yaw_range_is_an_arc_the_wrist_never_leaves():
    """With yaw in [-3, 3] the band through ±pi is excluded: a command across it turns the long way, along the arc,
    and no commanded yaw leaves the range (over the full circle, 3.13 and -3.13 are 0.02 rad apart)."""
    lim = SafetyLimits(workspace_min=(0.0, -0.5, 0.0), workspace_max=(1.0, 0.5, 0.5), yaw_min=-3.0, yaw_max=3.0,
                       max_rotation_rad=0.1)
    f = SafetyFilter(lim)
    f.reset(np.array([0.5, 0.0, 0.2, 2.95]))
    up = f(np.array([0.5, 0.0, 0.2, 3.13, 0.5]))  # past yaw_max: clipped to it
    assert up[3] == 3.0 and f.counts.yaw_range == 1 and f.counts.rotation == 0
    yaws = [f(np.array([0.5, 0.0, 0.2, -3.13, 0.5]))[3] for _ in range(5)]  # clipped to -3.0: the long way down
    np.testing.assert_allclose(yaws, [2.9, 2.8, 2.7, 2.6, 2.5], atol=1e-12)
    assert f.counts.rotation == 5
    with pytest.raises(SafetyViolation, match=r"measured yaw 3\.1000 rad is outside the yaw range \[-3\.0, 3\.0\]"):
        f.reset(np.array([0.5, 0.0, 0.2, 3.1]))
    f.reset(np.array([0.5, 0.0, 0.2, 3.04]))  # within state_tolerance_rad (0.05): taken, and turned back inside
    assert f(np.array([0.5, 0.0, 0.2, 3.0, 0.5]))[3] == 3.0
    full = SafetyFilter(SafetyLimits(**FAKE_WORKSPACE, max_rotation_rad=0.1))
    full.reset(np.array([0.5, 0.0, 0.2, 3.13]))  # any yaw is inside the full circle
    assert full(np.array([0.5, 0.0, 0.2, -3.13, 0.5]))[3] == pytest.approx(-3.13)  # 0.0232 rad through the seam


def _yaws(yaw_min, yaw_max, start, wanted, steps=3):
    f = SafetyFilter(SafetyLimits(**FAKE_WORKSPACE, yaw_min=yaw_min, yaw_max=yaw_max, max_rotation_rad=0.1))
    f.reset(np.array([0.5, 0.0, 0.2, start]))
    return [float(f(np.array([0.5, 0.0, 0.2, wanted, 0.5]))[3]) for _ in range(steps)]


def test_a_yaw_range_is_an_arc_on_the_circle_clipped_to_its_nearer_end():
    """A range ending at pi holds pi (which wraps to -pi); a wanted yaw past one end goes to that end, not to the
    other across the circle; a range typed as +-3.14159 is the full circle; a measured yaw at either end is in."""
    assert [abs(y) for y in _yaws(0.0, math.pi, 3.0, math.pi)] == pytest.approx([3.1, math.pi, math.pi])
    assert _yaws(-1.0, 3.0, 2.95, 3.2) == pytest.approx([3.0, 3.0, 3.0])  # 3.2 is nearer 3.0 than -1.0
    assert _yaws(-1.0, 3.0, 2.95, -1.3) == pytest.approx([2.85, 2.75, 2.65])  # nearer -1.0: the long way there
    assert _yaws(-3.14159, 3.14159, 3.1, -3.1) == pytest.approx([-3.1] * 3)  # 0.08 rad through the seam
    for low, high, measured in ((0.0, math.pi, math.pi), (-math.pi, 0.0, 3.13), (-math.pi, 0.0, -math.pi)):
        SafetyFilter(SafetyLimits(**FAKE_WORKSPACE, yaw_min=low, yaw_max=high)).reset(np.array([0.5, 0.0, 0.2, measured]))


def test_gripper_clipped_to_limits():
    f = make_filter()
    assert f(np.array([0.5, 0, 0.2, 0, 1.0]))[4] == pytest.approx(0.9)
    assert f(np.array([0.5, 0, 0.2, 0, -3.0]))[4] == pytest.approx(0.1)
    assert f.counts.gripper == 2


@pytest.mark.parametrize("bad", [[np.nan, 0, 0.2, 0, 0], [0.5, 0, 0.2, np.inf, 0], [0.5, 0, 0.2, 0]])
def test_non_finite_or_misshaped_action_is_a_violation(bad):
    with pytest.raises(SafetyViolation, match="NaN or inf|shape"):
        make_filter()(np.array(bad, dtype=float))


def test_measured_pose_outside_box_is_a_violation():
    f = make_filter()
    f.check_state(np.array([1.015, 0, 0.2, 0]))  # within the 2 cm tolerance
    with pytest.raises(SafetyViolation, match="outside the workspace box"):
        f.check_state(np.array([1.03, 0, 0.2, 0]))


def test_filter_requires_reset():
    with pytest.raises(RuntimeError, match="reset"):
        SafetyFilter(LIMITS)(np.zeros(5))


@pytest.mark.parametrize(
    "kwargs, field",
    [(dict(workspace_min=(0, 0, 1), workspace_max=(1, 1, 0.5)), "workspace_min: must be below workspace_max"),
     (dict(workspace_min=(0, 0)), r"workspace_min: expected \[x, y, z\] \(3 values\)"),
     (dict(workspace_min=(0, 0, float("nan"))), r"workspace_min\[2\]: Input should be a finite number"),
     (dict(max_step_m=0.0), r"max_step_m: Input should be greater than 0"),
     (dict(max_step_m=0.5), r"max_step_m: Input should be less than or equal to 0\.1"),
     (dict(max_rotation_rad=-1), "max_rotation_rad"), (dict(max_rotation_rad=1.0), "max_rotation_rad"),
     (dict(gripper_min=0.5, gripper_max=0.2), "gripper_min: must be below gripper_max"),
     (dict(yaw_min=-4.0), "yaw_min"), (dict(state_tolerance_m="2 cm"), "state_tolerance_m"),
     (dict(max_step_m=0.02, max_tracking_m=0.015), r"max_tracking_m: must be at least max_step_m \(0\.02\)"),
     (dict(max_tracking_m=0.3), r"max_tracking_m: Input should be less than or equal to 0\.2"),
     (dict(workspace_min=None, workspace_max=None), r"^workspace_min: Field required; workspace_max: Field required$"),
     (dict(workspace_min=(200, -300, 0), workspace_max=(700, 300, 500)),  # millimetres
      r"^workspace_min: must lie within ±2 m of the base \(metres, not mm\)")],
)
def test_limits_validation_names_the_field(kwargs, field):
    """The limits a robot starts with: refused in one line naming the field (the constructor's own message); the
    box has no default, a set-up states it (None here: not given)."""
    given = {k: v for k, v in {**FAKE_WORKSPACE, **kwargs}.items() if v is not None}
    with pytest.raises(ValueError) as info:
        SafetyLimits(**given)
    assert re.search(field, str(info.value)) and "\n" not in str(info.value), str(info.value)


def test_limits_take_numpy_values_and_are_frozen():
    lim = SafetyLimits(workspace_min=np.array([0.1, -0.2, 0.0]), workspace_max=(0.5, 0.2, 0.4),
                       max_step_m=np.float32(0.01), yaw_max=np.float64(1.0))
    assert lim.workspace_min == (0.1, -0.2, 0.0) and lim.max_step_m == pytest.approx(0.01) and lim.yaw_max == 1.0
    with pytest.raises(dataclasses.FrozenInstanceError, match="cannot assign"):
        lim.max_step_m = 0.05
    with pytest.raises(ValueError, match="max_step_m"):
        SafetyLimits(**FAKE_WORKSPACE, max_step_m=True)  # a boolean is not a distance


def test_watchdog_trips_on_the_silent_feed_only():
    clock = VirtualClock()
    wd = Watchdog(0.2, clock)
    wd.feed("command", 0.0)
    wd.feed("frame:tactile/left", 0.0)
    clock.advance(0.15)
    wd.feed("command", clock.now())
    wd.check()
    clock.advance(0.1)  # frame last fed at 0.0, now 0.25
    with pytest.raises(WatchdogTimeout, match=r"no fresh frame tactile/left for 0\.250 s \(limit 0\.200 s\)"):
        wd.check()
    wd.feed("frame:tactile/left", clock.now())
    with pytest.raises(WatchdogTimeout):  # stays tripped
        wd.check()


@pytest.mark.parametrize("stamp", [float("nan"), float("inf"), 0.3])
def test_a_feed_stamped_with_no_time_of_the_clock_is_refused(stamp):
    """NaN, inf or a time the clock has not reached (another clock's) would keep a feed fresh for ever; a NaN
    check time would never trip either."""
    clock = VirtualClock()
    clock.advance(0.2)
    wd = Watchdog(0.1, clock)
    with pytest.raises(SafetyViolation, match=r"watchdog: frame left stamped .*not a time on the loop's clock"):
        wd.feed("frame:left", stamp)
    wd.feed("frame:left", 0.2)
    with pytest.raises(SafetyViolation, match="not a time"):
        wd.check(float("nan"))


def test_watchdog_thread_calls_on_trip():
    import threading

    clock = VirtualClock()
    clock.attach()  # time moves only while this thread waits on the clock
    wd = Watchdog(0.05, clock)
    tripped, trip_times = threading.Event(), []
    wd.feed("command", 0.0)
    wd.start(lambda: trip_times.append(clock.now()) or tripped.set())
    assert clock.now() == 0.0 and not tripped.is_set()
    assert clock.wait(tripped, 2.0)  # virtual time runs the watchdog thread's checks every 12.5 ms
    wd.stop()
    clock.detach()
    assert "no fresh command" in wd.tripped
    assert trip_times == [pytest.approx(0.0625)]  # the first check past the 0.05 s limit


@pytest.mark.parametrize("make, says", [(lambda: ControlLoop(None, None, limits=None),
                                         r"^limits: expected SafetyLimits \(the workspace box"),
                                        (lambda: SafetyFilter(None), r"^limits: expected SafetyLimits \(the workspace box is the caller's to state\), got NoneType$"),
                                        (lambda: Watchdog("1", VirtualClock()), "^timeout_s must be a positive number"),
                                        (lambda: Watchdog(float("nan"), VirtualClock()), "^timeout_s must be a positive")])
def test_a_filter_or_watchdog_without_real_limits_is_refused_in_one_line(make, says):
    with pytest.raises(ValueError, match=says):
        make()
