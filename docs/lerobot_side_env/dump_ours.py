"""Project env: every camera of every item of an augmented folder as our reader returns it (ours.npz), for
check_with_lerobot.py.

    python docs/lerobot_side_env/dump_ours.py OUT WORK_DIR
"""
import sys
from pathlib import Path

import numpy as np

from controltac_il.lerobot import LeRobotFolder

ds, work = LeRobotFolder(sys.argv[1]), Path(sys.argv[2])
cameras = [k for k in ds.features if k.startswith("observation.images.")]
np.savez(work / "ours.npz", **{f"{k}_{i}": ds[i][k].numpy() for i in range(len(ds)) for k in cameras})
