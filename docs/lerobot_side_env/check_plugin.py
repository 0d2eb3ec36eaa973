"""Side env: the GelSight camera plugin (plugins/lerobot_camera_gelsight) through LeRobot 0.4.4 itself.

A video file written here from our sensor model stands in for the GelSight Mini (raw frames with the dark rim
the 15 % crop removes). After ``register_third_party_plugins()``, a ``--robot.cameras``-style dict is parsed by
draccus as lerobot-record parses it and turned into the camera by ``make_cameras_from_configs``; its frames
must be 240 x 320 RGB uint8. Then a small dataset is recorded with ``LeRobotDataset.create`` / ``add_frame`` /
``save_episode`` (dummy state and action, the sensor as observation.images.gs_left). The camera connects at
each episode (the file restarts: 5 background frames, then the episode's 6 no-contact frames and the pressed
ones; its frames are read at the file's pace, then added), so every episode starts with no-contact frames, as
a lab's must (lerobot-record connects once: there the gel is left untouched at each episode's start).

usage: python check_plugin.py ROOT [--video]   (ROOT must not exist; --video: a video feature, else image)
"""
import argparse
import os
import tempfile
from dataclasses import dataclass, field

os.environ.setdefault("HF_HUB_OFFLINE", "1")
import cv2
import draccus
import numpy as np
from lerobot.cameras import CameraConfig, make_cameras_from_configs
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.datasets.utils import hw_to_dataset_features
from lerobot.utils.import_utils import register_third_party_plugins

from controltac_il.tactile import SensorSpec, TactileSensor, contact_mask, to_residual

FPS = 25  # the GelSight Mini's rate: the stand-in file plays at it, the dataset is recorded at it
CONNECT, IDLE, PRESSED, EPISODES = 5, 6, 12, 2  # frames: background at connect, then per episode
PRESSED_READ = 10  # pressed frames recorded per episode (the file holds 2 more: slack for a late read)
RAW_H, RAW_W = 600, 800  # the sensor image fills the central 70 %: the 15 % crop leaves 420 x 560


@dataclass
class Rig:
    """What a robot config holds: named camera configs, parsed from ``--cameras='{...}'``."""

    cameras: dict[str, CameraConfig] = field(default_factory=dict)


def sensor_frames() -> tuple[np.ndarray, list[np.ndarray]]:
    """Our sensor model's no-contact image and PRESSED pressed ones (1.5 .. 7 N), RGB uint8 (240, 320, 3)."""
    sensor = TactileSensor(SensorSpec.gelsight_mini(), optics="polynomial", seed=0)
    forces = np.linspace(1.5, 7.0, PRESSED)
    return sensor.background, [sensor.press("big_sphere", pose=(0.5, 0.0, 0.0), force=(0.0, 0.0, f)).image
                               for f in forces]


def write_stand_in(path: str, background: np.ndarray, pressed: list[np.ndarray]) -> str:
    """The file a connect plays: CONNECT + IDLE no-contact frames, then the pressed ones (BGR, magenta rim)."""
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"FFV1"), FPS, (RAW_W, RAW_H))
    for rgb in [background] * (CONNECT + IDLE) + pressed:
        raw = np.empty((RAW_H, RAW_W, 3), np.uint8)
        raw[:] = (255, 0, 255)
        raw[90:510, 120:680] = cv2.resize(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), (560, 420))
        writer.write(raw)
    writer.release()
    return path


def make_camera(video: str):
    """The camera from a --robot.cameras-style dict, through LeRobot's plugin discovery and factory."""
    register_third_party_plugins()
    arg = f"--cameras={{gs_left: {{type: gelsight_mini, device: {video}, fps: {FPS}, background_frames: {CONNECT}}}}}"
    rig = draccus.parse(Rig, args=[arg])
    cam = make_cameras_from_configs(rig.cameras)["gs_left"]
    print("camera:", type(cam).__module__, type(cam).__name__, "config:", rig.cameras["gs_left"])
    return cam, rig.cameras["gs_left"]


def check_frames(cam, background: np.ndarray) -> None:
    """Frames are 240 x 320 RGB uint8 (the no-contact frame matches the RGB model image, not its BGR)."""
    cam.connect()
    try:
        frames = [cam.async_read(timeout_ms=1000), cam.read(), cam.read_latest()]
    finally:
        cam.disconnect()
    for f in frames:
        assert f.shape == (240, 320, 3) and f.dtype == np.uint8, (f.shape, f.dtype)
    err = np.abs(frames[0].astype(int) - background).mean()
    swapped = np.abs(frames[0][..., ::-1].astype(int) - background).mean()
    assert err < 3 < swapped, (err, swapped)
    print(f"frames: {frames[0].shape} {frames[0].dtype}; |frame - RGB model| {err:.2f}, with R and B swapped "
          f"{swapped:.2f}; background {cam.background.shape} {cam.background.dtype}")


def leading_no_contact(images: list[np.ndarray], background: np.ndarray) -> int:
    """How many frames at the start have no contact: under 0.2 % contact pixels on the residual (the
    augmenter's min_contact_area)."""
    touched = contact_mask(to_residual(np.stack(images), background)).mean(axis=(1, 2)) >= 0.002
    return int(np.argmax(touched)) if touched.any() else len(images)


def record(cam, cfg, root: str, video: bool) -> LeRobotDataset:
    """EPISODES episodes of IDLE no-contact + PRESSED_READ pressed frames, the camera connecting at each."""
    features = {"observation.state": {"dtype": "float32", "shape": (5,), "names": None},
                "action": {"dtype": "float32", "shape": (5,), "names": None},
                **hw_to_dataset_features({"gs_left": (cfg.height, cfg.width, 3)}, "observation", use_video=video)}
    ds = LeRobotDataset.create(repo_id="controltac/gelsight_check", fps=FPS, features=features, root=root,
                               robot_type="controltac_check", use_videos=video, image_writer_threads=0)
    for e in range(EPISODES):
        cam.connect()
        try:
            images = [cam.async_read(timeout_ms=1000) for _ in range(IDLE + PRESSED_READ)]
            background = cam.background
        finally:
            cam.disconnect()
        for t, image in enumerate(images):
            state = np.full(5, 0.01 * t, np.float32)
            ds.add_frame({"observation.state": state, "action": state + 0.01,
                          "observation.images.gs_left": image, "task": "press the gel"})
        ds.save_episode()
        n_idle = leading_no_contact(images, background)
        assert n_idle >= 5, f"episode {e} starts with {n_idle} no-contact frames"
        print(f"episode {e}: {len(images)} frames, the first {n_idle} without contact")
    ds.finalize()
    return ds


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("root", help="dataset folder to create (must not exist)")
    p.add_argument("--video", action="store_true", help="store the sensor as a video feature (default: image)")
    args = p.parse_args()
    background, pressed = sensor_frames()
    with tempfile.TemporaryDirectory() as tmp:
        cam, cfg = make_camera(write_stand_in(os.path.join(tmp, "gelsight_stand_in.avi"), background, pressed))
        check_frames(cam, background)
        record(cam, cfg, args.root, args.video)
    ds = LeRobotDataset("controltac/gelsight_check", root=args.root, video_backend="pyav")
    item = ds[0]["observation.images.gs_left"]
    print(f"dataset: {ds.meta.total_episodes} episodes, {ds.meta.total_frames} frames, "
          f"{ds.meta.features['observation.images.gs_left']['dtype']} feature; item {tuple(item.shape)} {item.dtype}")
    print("dataset root:", os.path.abspath(args.root))


if __name__ == "__main__":
    main()
