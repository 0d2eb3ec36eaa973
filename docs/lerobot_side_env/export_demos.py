"""Project env: the frames of 3 scene demos (from the demo cache) as source_frames.npz, for make_source.py.

    python docs/lerobot_side_env/export_demos.py DEMO_FOLDER WORK_DIR
"""
import sys
from pathlib import Path

import numpy as np

from controltac_il.datasets.episodes import episode_paths, read_episode

demos, work = Path(sys.argv[1]), Path(sys.argv[2])
out = {}
for i, path in enumerate(episode_paths(demos)[:3]):
    ep = read_episode(path)
    out.update({f"state_{i}": ep.qpos, f"action_{i}": ep.action, f"left_{i}": ep.tactile["left"],
                f"right_{i}": ep.tactile["right"], f"wrist_{i}": ep.images["wrist"], f"fl_{i}": ep.force["left"],
                f"fr_{i}": ep.force["right"]})
work.mkdir(parents=True, exist_ok=True)
np.savez(work / "source_frames.npz", **out)
