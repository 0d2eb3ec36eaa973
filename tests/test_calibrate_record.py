"""``python -m controltac_il.calibrate record``: presses through the control loop and its limits, in the MuJoCo scene
(the pad force known), refused before moving, stopped past the abort force; the F/T readers at the SDK boundary."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import re
import subprocess
import sys
import types
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.stats import spearmanr

from controltac_il.app.press_record import ForceLimitExceeded, PressPlan, record_presses
from controltac_il.calibrate.recordings import RecordingOptions, recordings_to_presses
from controltac_il.tactile.dataset import load_dataset
from controltac_il.tactile.residual import residual_magnitude, to_residual
from envs.config import PegInHoleConfig
from envs.sim_robot import SimRobot
from hardware.interfaces import GRIPPER, Arm, ArmFault, ForceSample, ForceSensor, HardwareError, SensorError
from hardware.ur import URArm, URForce
from hardware.xarm import XArm, XArmForce

REPO = Path(__file__).resolve().parents[1]
SCENE = PegInHoleConfig(cameras=(), grip_force_range_n=(14.0, 14.0))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "recs"
    with SimRobot(SCENE, seed=0) as robot:
        summary = record_presses(robot, "left", robot.force["left"], PressPlan(presses=3), robot.squeeze_pose(), out)
    return out, summary


def test_a_press_is_written_by_the_writer_thread_never_the_control_thread(tmp_path, monkeypatch):
    """PNG encoding (about 5 ms a frame) on the control thread would hold it past the watchdog window on a robot."""
    import threading

    writers, imwrite = set(), cv2.imwrite

    def recording(path, image):
        writers.add(threading.current_thread().name)
        return imwrite(path, image)

    monkeypatch.setattr(cv2, "imwrite", recording)
    with SimRobot(SCENE, seed=0) as robot:
        summary = record_presses(robot, "left", robot.force["left"], PressPlan(presses=1), robot.squeeze_pose(),
                                 tmp_path / "recs")
    assert summary["presses"] == 1 and len(list((tmp_path / "recs" / "press_000").glob("*.png"))) > 10
    assert len(writers) == 1 and next(iter(writers)).startswith("press-writer")


def test_a_png_that_cannot_be_written_stops_the_recording_unpublished(tmp_path, monkeypatch):
    monkeypatch.setattr(cv2, "imwrite", lambda path, image: False)  # as OpenCV answers a full disk
    with SimRobot(SCENE, seed=0) as robot:
        with pytest.raises(OSError, match=r"frame_00000\.png: the PNG could not be written"):
            record_presses(robot, "left", robot.force["left"], PressPlan(presses=1), robot.squeeze_pose(),
                           tmp_path / "recs")
    assert list(tmp_path.iterdir()) == []


def _log(path: Path) -> np.ndarray:
    return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def test_sim_presses_are_ramps_from_no_contact_to_fz_max_whose_frames_follow_the_force(recorded):
    out, summary = recorded
    assert summary["presses"] == 3 and sorted(p.name for p in out.iterdir()) == [
        "press_000", "press_000.csv", "press_001", "press_001.csv", "press_002", "press_002.csv", "record.json"]
    for i in range(3):
        t, fz = _log(out / f"press_{i:03d}.csv").T
        frames = sorted((out / f"press_{i:03d}").glob("*.png"))
        assert len(frames) == len(fz) and np.all(np.diff(t) > 0)
        assert (fz[:5] < 0.2).all() and fz[-1] < 0.2  # out of contact first (the background) and last
        assert 9.0 <= fz.max() <= 12.0  # turned back at fz_max, never near the abort
        peak = int(fz.argmax())
        ramp = np.flatnonzero(fz[:peak + 1] >= 1.0)
        assert len(ramp) >= 8 and np.all(np.diff(fz[ramp]) > 0)  # a slow, rising loading ramp
        images = np.stack([cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in frames])
        background = np.median(images[fz < 0.2], axis=0).astype(np.uint8)
        touch = fz >= 0.5
        signal = [residual_magnitude(to_residual(im, background)).mean() for im in images[touch]]
        assert spearmanr(signal, fz[touch]).statistic > 0.9  # the frames show the known contact force


def test_presses_touch_different_parts_of_the_gel(recorded):
    out, _ = recorded
    peaks = []
    for i in range(3):
        fz = _log(out / f"press_{i:03d}.csv")[:, 1]
        k = int(fz.argmax())
        img = cv2.imread(str(out / f"press_{i:03d}" / f"frame_{k:05d}.png")).astype(np.float32)
        bg = cv2.imread(str(out / f"press_{i:03d}" / "frame_00000.png")).astype(np.float32)
        col = np.abs(img - bg).max(-1).sum(0)  # the peg's stripe across the image columns
        peaks.append(float((col * np.arange(len(col))).sum() / col.sum()))
    assert np.ptp(peaks) > 2.0  # px: the spread moved the contact along the gel


def test_calibrate_reads_the_recordings_one_background_each_labels_in_range(recorded, tmp_path):
    out, _ = recorded
    info = recordings_to_presses(out, tmp_path / "presses", RecordingOptions(size=(120, 160), lag="auto"))
    assert set(info) == {"press_000", "press_001", "press_002"}
    assert all(v["presses"] == 1 and v["frames"] >= 8 and v["lag_frames"] == 0 for v in info.values())
    ds = load_dataset(tmp_path / "presses")
    fz = ds.forces()[:, 2]
    assert ((fz >= 1.0) & (fz <= 10.0)).all()
    assert len(list((tmp_path / "presses" / "backgrounds").glob("*.png"))) == 3


class Spiking(ForceSensor):
    """The pad force, reading 9 N too high once past 4 N: the abort must stop the run."""

    def __init__(self, inner):
        self.inner, self.name = inner, "spiking"

    def read(self):
        s = self.inner.read()
        return ForceSample(s.normal_n + (9.0 if s.normal_n > 4.0 else 0.0), s.timestamp)


class Latching(Arm):
    """The simulated arm under the xArm's contract: once stopped, ``servo`` refuses until ``connect``."""

    def __init__(self, inner):
        self.inner, self.stopped = inner, False

    def connect(self):
        self.inner.connect()
        self.stopped = False

    def stop(self):
        self.stopped = True
        self.inner.stop()

    def state(self):
        return self.inner.state()

    def servo(self, target):
        if self.stopped:
            raise ArmFault("stopped; call connect() to enable motion again")
        self.inner.servo(target)


@pytest.mark.parametrize("latching", [False, True])
def test_force_past_the_abort_stops_backs_out_and_writes_nothing(tmp_path, latching):
    """The abort stops the arm; backing out enables it again first (an xArm refuses motion once stopped)."""
    with SimRobot(SCENE, seed=0) as robot:
        robot.arm = Latching(robot.arm) if latching else robot.arm
        with pytest.raises(ForceLimitExceeded, match="fz_abort 12"):
            record_presses(robot, "left", Spiking(robot.force["left"]), PressPlan(presses=2), robot.squeeze_pose(),
                           tmp_path / "recs")
        assert robot.command[GRIPPER] == 0.0 and robot.force["left"].read().normal_n < 0.2  # released
    assert list(tmp_path.iterdir()) == []  # nothing written, no partial folder


class Faulted(Latching):
    """An arm whose controller raised its own error at the abort (e.g. its collision stop)."""

    def state(self):
        if self.stopped:
            raise ArmFault("controller error code 22 (self-collision); clear it on the controller")
        return super().state()


def test_the_back_out_never_clears_an_error_the_controller_raised(tmp_path):
    with SimRobot(SCENE, seed=0) as robot:
        robot.arm = Faulted(robot.arm)
        with pytest.raises(ArmFault, match="error code 22") as info:
            record_presses(robot, "left", Spiking(robot.force["left"]), PressPlan(presses=2), robot.squeeze_pose(),
                           tmp_path / "recs")
        assert robot.arm.stopped  # never enabled again, never moved
    assert isinstance(info.value.__context__, ForceLimitExceeded)


class Blind(ForceSensor):
    """A reading that turns NaN at the third call."""

    def __init__(self, inner):
        self.inner, self.name, self.calls = inner, "blind", 0

    def read(self):
        self.calls += 1
        s = self.inner.read()
        return ForceSample(float("nan") if self.calls >= 3 else s.normal_n, s.timestamp)


def test_a_nan_force_stops_the_arm_and_writes_nothing(tmp_path):
    with SimRobot(SCENE, seed=0) as robot:
        with pytest.raises(HardwareError, match="blind: the force reads nan"):
            record_presses(robot, "left", Blind(robot.force["left"]), PressPlan(presses=1), robot.squeeze_pose(),
                           tmp_path / "recs")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("change, field", [(dict(start_dz=-0.2), "start"), (dict(spread_m=0.01, start_dx="edge"), "spread_m"),
                                           (dict(mode="press", fast_step=0.05), "fast_step")])
def test_a_plan_outside_the_limits_is_refused_before_anything_moves(tmp_path, change, field):
    with SimRobot(SCENE, seed=0) as robot:
        start = robot.squeeze_pose() + [0.0, 0.0, change.pop("start_dz", 0.0), 0.0]
        if change.pop("start_dx", None) == "edge":  # the first press on the box's edge, others beyond it
            start[0] = robot.limits.workspace_min[0]
        with pytest.raises(ValueError, match=field):
            record_presses(robot, "left", robot.force["left"], PressPlan(**change), start, tmp_path / "recs")
        assert robot.steps == 0
    assert not (tmp_path / "recs").exists()


@pytest.mark.parametrize("kw, field", [(dict(fz_max=10.5), "fz_max"), (dict(fz_max=9.0, fz_abort=9.0), "fz_abort"),
                                       (dict(fz_abort=16.0), "fz_abort"), (dict(slow_step=0.05), "slow_step"),
                                       (dict(max_travel=1e9), "max_travel: a squeeze moves in closing fractions"),
                                       (dict(fast_step=2.0), "fast_step: a squeeze")])
def test_force_bounds_are_validated(kw, field):
    with pytest.raises(ValueError, match=field):
        PressPlan(**kw)


def test_cli_one_line_errors(tmp_path):
    def run(*args):
        return subprocess.run([sys.executable, "-m", "controltac_il.calibrate", "record", *args], cwd=REPO,
                              capture_output=True, text=True, timeout=120)

    bad = run("--sim", "--out", str(tmp_path / "r"), "--fz-max", "11")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--fz-max" in bad.stderr
    bad = run("--sim", "--mode", "press", "--out", str(tmp_path / "r"))
    assert bad.returncode == 2 and "--mode squeeze" in bad.stderr and not (tmp_path / "r").exists()


@pytest.mark.parametrize("start, says", [(["nan", "0", "0.2", "0"], "start must be 4 finite numbers"),
                                         (["1e9", "0", "0.2", "0"], "start: .* lies outside the workspace box"),
                                         (["0.4", "0", "0.2", "0", "--tactile-size", "120", "160"],
                                          "--tactile-size: the simulation's")])
def test_a_robot_start_outside_its_limits_is_refused_before_any_device_connects(tmp_path, monkeypatch, capsys,
                                                                               start, says):
    import hardware.config
    from controltac_il.app.record_cli import main

    def connect(cfg):
        raise AssertionError("a device was connected")

    monkeypatch.setattr(hardware.config, "open_setup", connect)
    code = main(["--setup", str(REPO / "hardware" / "configs" / "xarm7_gelsight.yaml"), "--sensor", "left",
                 "--start", *start, "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and re.search(says, err), err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("args, says", [
    (["--start", "0", "0", "0", "0", "--out", "r"], "--start: a robot's pose"),
    (["--out", "/proc/controltac-recordings"], "--out /proc/controltac-recordings: no file can be made in /proc")])
def test_sim_flags_a_press_cannot_use_are_refused_before_any_press(tmp_path, capsys, monkeypatch, args, says):
    from controltac_il.app.record_cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["--sim", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and says in err and list(tmp_path.iterdir()) == [], err


class FakeRTDE:
    """ur-rtde's receive and control interfaces, as far as URForce uses them."""

    def __init__(self, wrench):
        self.wrench, self.zeroed = wrench, 0

    def zeroFtSensor(self):
        self.zeroed += 1
        return True

    def getActualTCPForce(self):
        return self.wrench


def test_ur_wrist_reads_the_magnitude_after_zeroing():
    rtde = FakeRTDE([3.0, 0.0, -4.0, 0.1, 0.2, 0.3])
    arm = URArm("10.0.0.2", control=rtde, receive=rtde, connect_timeout_s=None)
    with URForce(arm) as f:
        assert rtde.zeroed == 1 and f.read().normal_n == pytest.approx(5.0)
        rtde.wrench = [float("nan")] * 6
        with pytest.raises(SensorError, match="getActualTCPForce"):
            f.read()


@pytest.mark.parametrize("new_names", [True, False])
def test_xarm_ft_is_enabled_zeroed_and_back_in_motion_state(new_names):
    calls = []
    api = types.SimpleNamespace(connected=True, set_state=lambda s: calls.append(("state", s)) or 0,
                                get_ft_sensor_data=lambda: (0, [0.0, 6.0, 8.0, 0.0, 0.0, 0.0]))
    enable, zero = ("set_ft_sensor_enable", "set_ft_sensor_zero") if new_names else ("ft_sensor_enable", "ft_sensor_set_zero")
    setattr(api, enable, lambda on: calls.append(("enable", on)) or 0)
    setattr(api, zero, lambda: calls.append(("zero",)) or 0)
    arm = XArm("10.0.0.3", api=api, connect_timeout_s=None)
    with XArmForce(arm) as f:
        assert calls == [("enable", 1), ("zero",), ("state", 0)]
        assert f.read().normal_n == pytest.approx(10.0)
        api.get_ft_sensor_data = lambda: (3, [0.0] * 6)
        with pytest.raises(SensorError, match="code 3"):
            f.read()
    assert calls[-1] == ("enable", 0)
