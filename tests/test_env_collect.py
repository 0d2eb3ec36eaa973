"""The demonstration recorder: files that the episode reader and the ACT dataset load."""

import json
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest

from controltac_il.datasets.episodes import episode_paths, read_episode
from envs import collect


def test_recorded_episodes_load_with_the_episode_reader(tmp_path):
    out = tmp_path / "demos"
    rc = collect.main(["--episodes", "2", "--out", str(out), "--camera-size", "48", "64",
                       "--tactile-size", "60", "80", "--seed", "10"])
    assert rc == 0
    paths = episode_paths(out)
    assert [p.name for p in paths] == ["episode_0.hdf5", "episode_1.hdf5"]
    info = json.loads((out / "collect_info.json").read_text())
    assert info["episodes"] == 2 and info["attempts"] == 2 + len(info["failed_seeds"])
    seeds = []
    for p in paths:
        ep = read_episode(p)
        T = len(ep)
        assert ep.sim and ep.attrs["success"] and ep.attrs["task"] == "peg_in_hole"
        seeds.append(int(ep.attrs["seed"]))
        assert ep.qpos.shape == (T, 5) and ep.action.shape == (T, 5)
        assert set(ep.images) == {"third_view", "wrist"}
        assert ep.images["wrist"].shape == (T, 48, 64, 3)
        assert set(ep.tactile) == set(ep.tactile_background) == set(ep.force) == {"left", "right"}
        assert ep.tactile["left"].shape == (T, 60, 80, 3)
        assert ep.tactile_background["right"].shape == (60, 80, 3)
        # force labels: zero before the grasp, the episode's grip force while holding
        fz = ep.force["left"][:, 2]
        assert fz[0] == 0.0
        assert fz[-1] == pytest.approx(float(ep.attrs["grip_force_n"]), rel=0.1)
        # frames in contact differ from the no-contact background far more than frames without
        res = np.abs(ep.tactile["left"].astype(int) - ep.tactile_background["left"]).mean(axis=(1, 2, 3))
        assert res[fz > 1.0].min() > res[fz == 0.0].max()
        # frame t holds the observation before action t: the gripper closes after it is commanded
        closing = int(np.argmax(ep.action[:, 4] > 0.0))
        assert ep.qpos[closing, 4] < 0.02 and ep.qpos[closing + 1, 4] > 0.02 and ep.qpos[-1, 4] > 0.5
        assert ep.action[:, 4].min() >= 0.0 and ep.action[:, 4].max() <= 1.0
    assert seeds[0] >= 10 and seeds[1] > seeds[0]


def test_recorded_episodes_feed_the_act_dataset(tmp_path):
    from controltac_il.datasets.act_dataset import EpisodeDataset

    out = tmp_path / "demos"
    assert collect.main(["--episodes", "1", "--out", str(out), "--cameras", "wrist", "--camera-size", "48", "64",
                         "--tactile-size", "60", "80"]) == 0
    ds = EpisodeDataset(out, chunk_size=20, stats_path=tmp_path / "stats.json")
    item = ds[0]
    assert item["observation.qpos"].shape == (5,)
    assert item["action"].shape == (20, 5)
    assert tuple(item["observation.tactile.left"].shape) == (3, 60, 80)
    assert tuple(item["observation.images.wrist"].shape) == (3, 48, 64)


def test_an_earlier_collection_is_kept_unless_overwrite_and_files_of_the_users_never(tmp_path):
    """--overwrite replaces only what this tool wrote; a file of the user's under its names (an episode_7.hdf5 that is
    not a simulated episode, a collect_info.json of another tool) is refused with or without it, nothing changed."""
    out = tmp_path / "demos"
    args = ["--episodes", "1", "--out", str(out), "--cameras", "--camera-size", "48", "64", "--tactile-size", "60", "80"]
    assert collect.main(args[:1] + ["2"] + args[2:]) == 0  # a larger earlier collection
    first = (out / "episode_0.hdf5").read_bytes()
    assert collect.main(args) == 2
    assert (out / "episode_0.hdf5").read_bytes() == first
    assert collect.main(args + ["--overwrite", "--seed", "5"]) == 0
    assert [p.name for p in episode_paths(out)] == ["episode_0.hdf5"]
    assert int(read_episode(out / "episode_0.hdf5").attrs["seed"]) >= 5
    (out / "episode_7.hdf5").write_bytes(b"mine")
    now = (out / "episode_0.hdf5").read_bytes()
    assert collect.main(args + ["--overwrite"]) == 2
    assert (out / "episode_7.hdf5").read_bytes() == b"mine" and (out / "episode_0.hdf5").read_bytes() == now
    alone = tmp_path / "info_only"  # a record another tool wrote under the same name
    alone.mkdir()
    (alone / "collect_info.json").write_text("{}")
    for extra in ([], ["--overwrite"]):
        assert collect.main(["--episodes", "1", "--out", str(alone), *extra]) == 2
        assert (alone / "collect_info.json").read_text() == "{}" and not episode_paths(alone)


def test_grip_force_range_and_no_tactile(tmp_path):
    out = tmp_path / "demos"
    assert collect.main(["--episodes", "1", "--out", str(out), "--cameras", "--no-tactile",
                         "--grip-force", "7.5", "7.5"]) == 0
    ep = read_episode(out / "episode_0.hdf5")
    assert ep.tactile == {} and ep.tactile_background == {} and ep.images == {}
    assert float(ep.attrs["grip_force_n"]) == 7.5
    assert ep.force["right"][-1, 2] == pytest.approx(7.5, rel=0.03)


@pytest.mark.parametrize("argv, flag", [
    (["--episodes", "0"], "--episodes"),
    (["--episodes", "-3"], "--episodes"),
    (["--seed", "-1"], "--seed"),
    (["--max-attempts", "0"], "--max-attempts"),
    (["--episodes", "5", "--max-attempts", "2"], "--max-attempts"),
    (["--hold-steps", "-1"], "--hold-steps"),
    (["--tactile-size", "60", "60"], "--tactile-size"),
    (["--camera-size", "0", "0"], "--camera-size"),
    (["--grip-force", "9", "3"], "--grip-force"),
    (["--grip-force", "nan", "3"], "--grip-force"),
    (["--hole-diameter", "inf"], "--hole-diameter"),
    (["--hole-diameter", "20"], "--hole-diameter"),
    (["--scene", "kitchen"], "--scene"),
    (["--episodes", "two"], "--episodes"),
    (["--no-tactile", "--optics", "polynomial"], "--optics: sets the tactile images, which --no-tactile leaves out"),
    (["--no-tactile", "--tactile-size", "60", "80"], "--tactile-size: sets the tactile images"),
])
def test_bad_arguments_are_one_line_naming_the_flag(tmp_path, capsys, argv, flag):
    out = tmp_path / "demos"
    with pytest.raises(SystemExit) as exit_:
        collect.main(["--out", str(out), "--cameras", *argv])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in err and flag in err and "Traceback" not in err, err
    assert not out.exists(), "nothing is created for a refused command"


def test_out_that_is_a_file_is_refused_by_name(tmp_path, capsys):
    mine = tmp_path / "notes.txt"
    mine.write_text("mine")
    with pytest.raises(SystemExit) as exit_:
        collect.main(["--episodes", "1", "--out", str(mine), "--cameras"])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in err and "--out" in err and str(mine) in err, err
    assert mine.read_text() == "mine"


def test_command_line_exits_2_with_one_line_and_no_traceback(tmp_path):
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "envs.collect", "--episodes", "-3", "--out", str(tmp_path / "d")],
                         capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=120)
    assert res.returncode == 2 and res.stderr.strip().count("\n") == 0 and "--episodes" in res.stderr, res.stderr
