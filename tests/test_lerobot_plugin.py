"""The LeRobot camera plugin (plugins/lerobot_camera_gelsight) without LeRobot, which this environment lacks:
the names LeRobot 0.4.4 looks the plugin up by (the distribution's metadata Name as setuptools builds it,
the module of that name, the camera class named like its config without "Config"), and the plugin's frame
path (frames.py, the lerobot-free module its Camera wraps) on a real video file standing in for the sensor,
played on a virtual clock held by the test's thread (every frame seen, no sleeping)."""

import ast
import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from controltac_il.datasets import read_background_image
from hardware.interfaces import SensorError

PLUGIN = Path(__file__).resolve().parents[1] / "plugins" / "lerobot_camera_gelsight"
DIST = "lerobot_camera_gelsight"
RAW_H, RAW_W = 300, 400  # 15 % of each side removed leaves 210 x 280, resized to 240 x 320
BORDER_BGR = (255, 0, 255)
NO_CONTACT, CONTACT = 4, 3  # frames of the test video: the gel untouched, then pressed


@pytest.fixture(scope="module")
def frames_module():
    """frames.py imported as a file: the package's __init__ imports LeRobot, this module does not."""
    spec = importlib.util.spec_from_file_location("gelsight_plugin_frames", PLUGIN / DIST / "frames.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def gel_image(pressed: bool) -> np.ndarray:
    """A 210 x 280 RGB gel picture: R 200, G a ramp, B 30; a pressed gel has a bright disc in the middle."""
    rgb = np.empty((RAW_H - 90, RAW_W - 120, 3), np.uint8)
    rgb[..., 0], rgb[..., 2] = 200, 30
    rgb[..., 1] = np.linspace(60, 120, rgb.shape[1]).round().astype(np.uint8)[None, :]
    if pressed:
        cv2.circle(rgb, (140, 105), 40, (255, 255, 255), -1)
    return rgb


def write_gel_video(path: Path, n_pressed: int = CONTACT, fps: float = 25.0) -> str:
    """NO_CONTACT untouched then ``n_pressed`` pressed frames, each inside a magenta 15 % border (BGR file)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), fps, (RAW_W, RAW_H))
    assert writer.isOpened()
    for pressed in [False] * NO_CONTACT + [True] * n_pressed:
        raw = np.empty((RAW_H, RAW_W, 3), np.uint8)
        raw[:] = BORDER_BGR
        raw[45:RAW_H - 45, 60:RAW_W - 60] = cv2.cvtColor(gel_image(pressed), cv2.COLOR_RGB2BGR)
        writer.write(raw)
    writer.release()
    return str(path)



def expected(pressed: bool) -> np.ndarray:
    return cv2.resize(gel_image(pressed), (320, 240), interpolation=cv2.INTER_AREA)


def mae(a, b) -> float:
    return float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean())


def test_distribution_name_is_what_lerobot_looks_for(tmp_path):
    """setuptools' own metadata: Name with underscores and the lerobot_camera_ prefix, one top-level
    package of exactly that name (register_third_party_plugins imports the Name as a module)."""
    src = tmp_path / "src"
    shutil.copytree(PLUGIN, src, ignore=shutil.ignore_patterns("*.egg-info", "build", "__pycache__"))
    code = "import sys; from setuptools import build_meta as b; print(b.prepare_metadata_for_build_wheel(sys.argv[1]))"
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], cwd=src, capture_output=True, text=True,
                         check=True).stdout.strip().splitlines()[-1]
    metadata = (tmp_path / out / "METADATA").read_text()
    name = next(line.split(":", 1)[1].strip() for line in metadata.splitlines() if line.startswith("Name:"))
    assert name == DIST and name.startswith("lerobot_camera_") and "-" not in name
    assert (tmp_path / out / "top_level.txt").read_text().split() == [name]
    assert (PLUGIN / name / "__init__.py").is_file()
    assert "Requires-Dist: controltac-il" in metadata


def test_camera_class_is_the_config_name_without_config():
    """make_device_from_device_class looks for <config name minus Config> in the config's module (or its parent)."""
    tree = ast.parse((PLUGIN / DIST / "__init__.py").read_text())
    classes = {c.name: c for c in tree.body if isinstance(c, ast.ClassDef)}
    registered = [c for c in classes.values() for d in c.decorator_list
                  if isinstance(d, ast.Call) and ast.unparse(d.func) == "CameraConfig.register_subclass"
                  and [a.value for a in d.args] == ["gelsight_mini"]]
    assert len(registered) == 1
    config = registered[0]
    assert config.name.endswith("Config") and [ast.unparse(b) for b in config.bases] == ["CameraConfig"]
    camera = classes[config.name[:-len("Config")]]
    assert [ast.unparse(b) for b in camera.bases] == ["Camera"]
    assert {f.name for f in camera.body if isinstance(f, ast.FunctionDef)} >= {
        "connect", "read", "async_read", "read_latest", "disconnect", "is_connected", "find_cameras"}
    fields = {a.target.id: ast.literal_eval(a.value) for a in config.body
              if isinstance(a, ast.AnnAssign) and isinstance(a.value, ast.Constant)}
    assert (fields["height"], fields["width"], fields["fps"], fields["crop_fraction"]) == (240, 320, 25, 0.15)


def test_frames_are_240x320_rgb_uint8_with_the_background(frames_module, tmp_path, clock):
    video = write_gel_video(tmp_path / "gel.avi")
    gs = frames_module.GelSightFrames(video, background_frames=3, clock=clock)
    gs.open(background_path=str(tmp_path / "backgrounds" / "gs_left.png"))
    try:
        assert gs.background.shape == (240, 320, 3) and gs.background.dtype == np.uint8
        assert mae(gs.background, expected(False)) < 2.0 and not (gs.background == (255, 0, 255)).all(-1).any()
        saved = cv2.cvtColor(cv2.imread(str(tmp_path / "backgrounds" / "gs_left.png")), cv2.COLOR_BGR2RGB)
        assert np.array_equal(saved, gs.background)
        assert np.array_equal(read_background_image(tmp_path / "backgrounds" / "gs_left.png"), gs.background)
        seen = [gs.next_frame(1.0) for _ in range(NO_CONTACT - 3 + CONTACT)]  # frames 4..7: the rest of the file
        for image, pressed in zip(seen, [False] + [True] * CONTACT):
            assert image.shape == (240, 320, 3) and image.dtype == np.uint8
            assert mae(image, expected(pressed)) < 2.5
        assert abs(float(seen[0][..., 0].mean()) - 200) < 2 and abs(float(seen[0][..., 2].mean()) - 30) < 2  # RGB
        with pytest.raises(SensorError, match="capture stopped delivering frames after 7 frames"):
            gs.next_frame(1.0)
    finally:
        gs.close()
    assert not gs.is_open


def test_bgr_order_timeouts_and_stale_frames(frames_module, tmp_path, clock):
    video = write_gel_video(tmp_path / "slow.avi", fps=1.0)  # one frame a second: the next is due at t = 1 s
    gs = frames_module.GelSightFrames(video, background_frames=1, color_order="bgr", clock=clock)
    gs.open()
    try:
        assert abs(float(gs.newest(0.5)[..., 2].mean()) - 200) < 2  # BGR: red last
        with pytest.raises(TimeoutError, match="no new frame within 200 ms"):
            gs.next_frame(0.2)
        clock.advance(0.35)
        with pytest.raises(TimeoutError, match=r"newest frame is 5\d\d ms old \(limit 500 ms\)"):
            gs.newest(0.5)
        assert gs.next_frame(1.0).shape == (240, 320, 3)  # the frame due at 1 s
    finally:
        gs.close()


def test_reopen_after_close(frames_module, tmp_path, clock):
    gs = frames_module.GelSightFrames(write_gel_video(tmp_path / "gel.avi"), background_frames=2, clock=clock)
    for _ in range(2):
        gs.open()
        assert gs.next_frame(1.0).shape == (240, 320, 3)
        gs.close()


def test_find_gelsight_devices(frames_module, tmp_path):
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    for node, link in [("video0", "usb-046d_HD_Pro_Webcam_C920_ABC-video-index0"),
                       ("video2", "usb-GelSight_GelSight_Mini_R0B_2BKH-F4S7-video-index0"),
                       ("video3", "usb-GelSight_GelSight_Mini_R0B_2BKH-F4S7-video-index1")]:
        (tmp_path / node).touch()
        (by_id / link).symlink_to(tmp_path / node)
    assert frames_module.find_gelsight_devices(str(by_id)) == [
        {"name": "usb-GelSight_GelSight_Mini_R0B_2BKH-F4S7-video-index0", "type": "gelsight_mini",
         "id": str(tmp_path / "video2")}]


def test_bad_settings(frames_module):
    with pytest.raises(ValueError, match="color_order"):
        frames_module.GelSightFrames("x.avi", color_order="rgba")
    with pytest.raises(ValueError, match="crop_fraction"):
        frames_module.GelSightFrames("x.avi", crop_fraction=0.5)
