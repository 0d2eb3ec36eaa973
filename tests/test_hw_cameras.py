"""GelSight / camera reader through the real OpenCV path on video files written here from the tactile
sensor model: device lookup by name, border crop and resize, background, residuals, pacing,
stale and unplugged sensors (also inside the control loop). Files play on a virtual clock that the
test's own thread holds (attached), so every frame is seen and stamped exactly, without sleeping."""

import os

import cv2
import numpy as np
import pytest

from controltac_il.tactile import SensorSpec, TactileSensor, to_residual
from hardware.cameras import GelSightMini, OpenCVFrameSource, crop_and_resize, find_video_device
from hardware.control_loop import ControlLoop, ControlLoopConfig
from hardware.fakes import FAKE_WORKSPACE, FakeArm
from hardware.interfaces import SensorError
from hardware.safety import SafetyLimits

MAGENTA_BGR = (255, 0, 255)
RAW_H, RAW_W = 600, 800  # 15 % of each side removed leaves 420 x 560 = 1.75 x (240 x 320)


@pytest.fixture(scope="module")
def sensor_frames():
    sensor = TactileSensor(SensorSpec.gelsight_mini(), optics="polynomial", seed=0)
    contacts = [sensor.press("big_sphere", pose=(x, 0.0, 0.0), force=(0.0, 0.0, 6.0)).image for x in (-2.0, 0.0, 2.0)]
    return sensor.background, contacts


def raw_frame(rgb):
    """The sensor image scaled into the central 70 % of a raw frame with a magenta border (BGR)."""
    raw = np.empty((RAW_H, RAW_W, 3), np.uint8)
    raw[:] = MAGENTA_BGR
    core = cv2.resize(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), (560, 420), interpolation=cv2.INTER_LINEAR)
    raw[90:510, 120:680] = core
    return raw


def write_video(path, frames_rgb, fps=25.0):
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), fps, (RAW_W, RAW_H))
    assert w.isOpened()
    for f in frames_rgb:
        w.write(raw_frame(f))
    w.release()
    return str(path)


@pytest.fixture(scope="module")
def gelsight_video(tmp_path_factory, sensor_frames):
    background, contacts = sensor_frames
    return write_video(tmp_path_factory.mktemp("gs") / "gelsight.avi", [background] * 5 + contacts * 2)


def mae(a, b):
    return float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean())



def test_crop_and_resize_removes_exactly_the_border():
    bgr = np.zeros((100, 200, 3), np.uint8)
    bgr[:15] = bgr[85:] = 255
    bgr[:, :30] = bgr[:, 170:] = 255
    bgr[15:85, 30:170] = (10, 20, 30)
    out = crop_and_resize(bgr, 0.15, (70, 140))
    assert out.shape == (70, 140, 3) and (out == (30, 20, 10)).all()  # RGB order, nothing of the border


def test_find_video_device_by_name(tmp_path):
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    for node, link in [("video0", "usb-046d_HD_Pro_Webcam_C920_ABC-video-index0"),
                       ("video2", "usb-GelSight_GelSight_Mini_R0B_2BKH-F4S7-video-index0"),
                       ("video3", "usb-GelSight_GelSight_Mini_R0B_2BKH-F4S7-video-index1"),
                       ("video4", "usb-GelSight_GelSight_Mini_R0B_28J3-CWXU-video-index0")]:
        (tmp_path / node).touch()
        os.symlink(tmp_path / node, by_id / link)
    assert find_video_device("webcam c920", str(by_id)) == str(tmp_path / "video0")
    assert find_video_device("GelSight Mini R0B 2BKH", str(by_id)) == str(tmp_path / "video2")
    with pytest.raises(SensorError, match="several video devices match 'GelSight Mini'"):
        find_video_device("GelSight Mini", str(by_id))
    with pytest.raises(SensorError, match="no video device whose name contains 'DIGIT'.*found: usb-046d"):
        find_video_device("DIGIT", str(by_id))


def test_gelsight_background_residual_and_frames(gelsight_video, sensor_frames, clock):
    background, contacts = sensor_frames
    with GelSightMini("left", gelsight_video, background_frames=5, clock=clock) as gs:
        assert gs.background.shape == (240, 320, 3) and gs.background.dtype == np.uint8
        assert mae(gs.background, background) < 2.0  # averaged no-contact frames, through crop + resize
        assert not (gs.background == (255, 0, 255)).all(-1).any()  # no border pixel left
        seen = []
        frame = gs.latest()
        while len(seen) < 3:
            frame = gs.wait_for_frame(frame.index, 2.0)
            seen.append(frame)
        assert [f.index for f in seen] == [6, 7, 8]  # frames 6, 7, 8, ... are the contacts, 1-5 the background
        # the file plays at its recorded 25 fps like the camera it stands in for, not as fast as it decodes
        assert [f.timestamp for f in seen] == pytest.approx([0.2, 0.24, 0.28])
        for f in seen:
            expected = to_residual(contacts[(f.index - 6) % 3], background)
            assert mae(gs.residual(f), expected) < 2.5
        assert mae(gs.residual(seen[0]), np.full_like(background, 127)) > 1.0  # there is a contact


def test_end_of_stream_is_reported_as_unplugged(gelsight_video, clock):
    with GelSightMini("left", gelsight_video, background_frames=5, clock=clock) as gs:
        with pytest.raises(SensorError, match="left: capture stopped delivering frames after 11 frames"):
            for _ in range(100):
                gs.wait_for_frame(gs.latest().index, 2.0)


def test_stale_frame_by_age(tmp_path, sensor_frames, clock):
    video = write_video(tmp_path / "slow.avi", sensor_frames[1], fps=1.0)  # the next frame is due at t = 1 s
    with OpenCVFrameSource("wrist", video, max_age_s=0.2, clock=clock) as cam:
        frame = cam.wait_for_frame(0, 2.0)
        assert frame.index == 1 and frame.timestamp == 0.0 and clock.now() < 0.01  # start() polled for it
        clock.advance(0.19)
        assert cam.latest() is frame  # under 0.2 s old: fresh
        clock.advance(0.3)
        with pytest.raises(SensorError, match=r"wrist: newest frame is 0\.49\d s old \(limit 0\.2 s\): stalled"):
            cam.latest()


def test_missing_file_or_device_is_a_clear_error(tmp_path):
    with pytest.raises(SensorError, match="cannot open video source|no video device"):
        OpenCVFrameSource("cam", str(tmp_path / "nope.avi")).start()


@pytest.mark.parametrize("kwargs, field", [(dict(crop_fraction=0.5), "crop_fraction"), (dict(size=(0, 3)), "size"),
                                           (dict(max_age_s=0), "max_age_s")])
def test_bad_settings(kwargs, field):
    with pytest.raises(ValueError, match=field):
        OpenCVFrameSource("cam", "x.avi", **kwargs)


def test_sensor_unplugged_mid_run_stops_the_arm(tmp_path, sensor_frames, clock):
    background, contacts = sensor_frames
    video = write_video(tmp_path / "short.avi", [background] * 3 + contacts, fps=25.0)

    def hold(obs):
        return np.tile(np.r_[obs["qpos"][:4], 0.0], (20, 1))

    log = []
    arm = FakeArm(log=log, clock=clock)
    with GelSightMini("left", video, background_frames=3, clock=clock) as gs:
        # frames 1-3 (t = 0 .. 0.08 s) are the background, the last frame comes at 0.2 s, the end of the file at
        # 0.24 s: the loop (steps at 0.08, 0.18, 0.28 s) commands twice, then finds the sensor gone
        loop = ControlLoop(arm, hold, tactile={"left": gs}, config=ControlLoopConfig(inference="sync"), clock=clock,
                           limits=SafetyLimits(**FAKE_WORKSPACE))
        with pytest.raises(SensorError, match="left: capture stopped delivering frames after 6 frames"):
            loop.run(max_steps=100)
    events = [e for e, _ in log]
    assert events.count("servo") == 2 and events[-1] == "arm-stop"
