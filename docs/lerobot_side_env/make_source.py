"""Side env: write a LeRobot v3.0 dataset with LeRobot's own writer from our sim's frames (3 peg-in-hole demos):
gelsight_left as an image feature, gelsight_right as a video feature (LeRobot's default libsvtav1), a wrist video,
state, action and both force labels."""
import os, sys
os.environ.setdefault("HF_HUB_OFFLINE", "1")
import numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDataset

root = sys.argv[1]  # argv[2]: the WORK_DIR of export_demos.py
d = np.load(os.path.join(sys.argv[2], "source_frames.npz"))
cam = {"names": ["height", "width", "channels"]}
features = {
    "observation.state": {"dtype": "float32", "shape": (5,), "names": None},
    "action": {"dtype": "float32", "shape": (5,), "names": None},
    "observation.images.gelsight_left": {"dtype": "image", "shape": (120, 160, 3), **cam},
    "observation.images.gelsight_right": {"dtype": "video", "shape": (120, 160, 3), **cam},
    "observation.images.wrist": {"dtype": "video", "shape": (96, 128, 3), **cam},
    "observation.gelsight_left.force": {"dtype": "float32", "shape": (3,), "names": ["fx", "fy", "fz"]},
    "observation.gelsight_right.force": {"dtype": "float32", "shape": (3,), "names": ["fx", "fy", "fz"]},
}
ds = LeRobotDataset.create(repo_id="controltac/peg_src", fps=10, features=features, root=root, robot_type="controltac_sim",
                           use_videos=True, image_writer_processes=0, image_writer_threads=0, encoder_threads=1)
for e in range(3):
    for t in range(len(d[f"state_{e}"])):
        ds.add_frame({"observation.state": d[f"state_{e}"][t], "action": d[f"action_{e}"][t],
                      "observation.images.gelsight_left": d[f"left_{e}"][t],
                      "observation.images.gelsight_right": d[f"right_{e}"][t],
                      "observation.images.wrist": d[f"wrist_{e}"][t],
                      "observation.gelsight_left.force": d[f"fl_{e}"][t],
                      "observation.gelsight_right.force": d[f"fr_{e}"][t], "task": "insert the peg"})
    ds.save_episode()
ds.finalize()
print("wrote", root, ds.meta.total_episodes, ds.meta.total_frames)
