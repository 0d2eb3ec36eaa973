"""Side env: load the augmented folder with LeRobot 0.4.4 and compare every item with the source / our reader's dump;
the record of the write must reach LeRobot's meta as features['augment.copy']['info']['controltac_il_augment']."""
import os, sys
os.environ.setdefault("HF_HUB_OFFLINE", "1")
import numpy as np, torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset

out, src = sys.argv[1], sys.argv[2]  # argv[3]: the WORK_DIR of dump_ours.py
ds = LeRobotDataset("controltac/peg_aug", root=out, video_backend="pyav",
                    delta_timestamps={"observation.images.gelsight_left": [-0.1, 0.0], "action": [0.0, 0.1]})
s = LeRobotDataset("controltac/peg_src", root=src, video_backend="pyav")
print("episodes", ds.meta.total_episodes, "frames", len(ds), "features", [k for k in ds.meta.features if k.startswith("augment")])
record = ds.meta.features["augment.copy"]["info"]["controltac_il_augment"]
assert not os.path.exists(os.path.join(out, "meta", "controltac_il_augment.json"))
assert record["frames"] == len(ds) and record["episodes"]["written"] == ds.meta.total_episodes, record["episodes"]
print("record in LeRobot's meta.features['augment.copy']['info']:", {k: record[k] for k in (
      "tool", "episodes", "frames", "regenerated_frames", "video_round_trip_mse", "video_round_trip_psnr_db")})
ours = np.load(os.path.join(sys.argv[3], "ours.npz"))
n, worst = len(s), {}
for i in range(len(ds)):
    it = ds[i]
    assert it["episode_index"].item() == i // 36 and it["index"].item() == i, i
    if i < n:
        sit = s[i]
        for k in ("observation.images.gelsight_left", "observation.images.gelsight_right", "observation.images.wrist", "action", "observation.state"):
            a = it[k][-1] if k == "observation.images.gelsight_left" else (it[k][0] if k == "action" else it[k])
            assert torch.equal(a, sit[k]), (i, k)
    for k in ("observation.images.gelsight_left", "observation.images.gelsight_right", "observation.images.wrist"):
        a = (it[k][-1] if k.endswith("left") else it[k]).numpy()
        worst[k] = max(worst.get(k, 0), float(np.abs(a - ours[f"{k}_{i}"]).max()))
    assert int(it["augment.copy"]) == i // n
    assert it["task"] == "insert the peg"
print("originals equal to the source items: yes; max |LeRobot item - our reader's item|:", worst)
stats = ds.meta.stats
print("stats std of gelsight_left:", np.ravel(stats["observation.images.gelsight_left"]["std"]))
