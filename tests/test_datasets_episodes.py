"""Episode HDF5 round trip, read-only reads, atomic writes and bad input."""

import hashlib
import os

import h5py
import numpy as np
import pytest

from controltac_il.datasets.episodes import Episode, episode_index, episode_paths, read_episode, write_episode


def make_episode(T=6, seed=0, background=True, force=True):
    rng = np.random.default_rng(seed)
    tactile = rng.integers(0, 256, (T, 12, 16, 3), dtype=np.uint8)
    return Episode(
        qpos=rng.normal(size=(T, 5)).astype(np.float32),
        action=rng.normal(size=(T, 5)).astype(np.float32),
        images={"wrist": rng.integers(0, 256, (T, 8, 10, 3), dtype=np.uint8),
                "third_view": rng.integers(0, 256, (T, 8, 10, 3), dtype=np.uint8)},
        tactile={"left": tactile},
        tactile_background={"left": tactile[0].copy()} if background else {},
        force={"left": np.abs(rng.normal(size=(T, 3))).astype(np.float32)} if force else {},  # Fz > 0 pressing
        sim=True,
        attrs={"task": "peg_in_hole", "control_hz": 10.0},
    )


def sha(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def assert_same(a: Episode, b: Episode):
    np.testing.assert_array_equal(a.qpos, b.qpos)
    np.testing.assert_array_equal(a.action, b.action)
    for group in ("images", "tactile", "tactile_background", "force"):
        ga, gb = getattr(a, group), getattr(b, group)
        assert ga.keys() == gb.keys()
        for k in ga:
            assert ga[k].dtype == gb[k].dtype
            np.testing.assert_array_equal(ga[k], gb[k])
    assert a.sim == b.sim
    assert a.attrs == b.attrs


def test_round_trip_is_exact(tmp_path):
    ep = make_episode()
    write_episode(tmp_path / "episode_0.hdf5", ep)
    back = read_episode(tmp_path / "episode_0.hdf5")
    assert_same(ep, back)
    assert back.qvel is None and len(back) == 6


def test_act_layout_on_disk(tmp_path):
    ep = make_episode(force=False, background=False)
    ep.qvel = None
    write_episode(tmp_path / "episode_3.hdf5", ep)
    with h5py.File(tmp_path / "episode_3.hdf5", "r") as f:
        assert bool(f.attrs["sim"]) is True
        assert f["action"].shape == (6, 5) and f["action"].dtype == np.float32
        assert f["observations/qpos"].dtype == np.float32
        assert f["observations/images/wrist"].shape == (6, 8, 10, 3)
        assert f["observations/tactile/left"].chunks == (1, 12, 16, 3)
        assert len(f["observations/force"]) == 0 and len(f["observations/tactile_background"]) == 0


def test_qvel_round_trip_and_compression(tmp_path):
    ep = make_episode()
    ep2 = Episode(ep.qpos, ep.action, ep.images, ep.tactile, ep.tactile_background, ep.force, False, {},
                  qvel=np.ones_like(ep.qpos))
    write_episode(tmp_path / "episode_0.hdf5", ep2, compression="gzip")
    back = read_episode(tmp_path / "episode_0.hdf5")
    np.testing.assert_array_equal(back.qvel, np.ones_like(ep.qpos))
    assert back.sim is False
    assert_same(ep2, back)


def test_read_does_not_modify_file(tmp_path):
    p = tmp_path / "episode_0.hdf5"
    write_episode(p, make_episode())
    before, mtime = sha(p), os.stat(p).st_mtime_ns
    os.chmod(p, 0o444)  # a read-write open would fail on a read-only file
    read_episode(p)
    assert sha(p) == before and os.stat(p).st_mtime_ns == mtime


def test_failed_write_leaves_old_file_and_no_temp(tmp_path):
    p = tmp_path / "episode_0.hdf5"
    write_episode(p, make_episode(seed=1))
    before = sha(p)
    bad = make_episode(seed=2)
    bad.attrs["not_storable"] = {"a": 1}
    with pytest.raises(ValueError, match="attrs/not_storable"):
        write_episode(p, bad, overwrite=True)
    assert sha(p) == before
    assert sorted(os.listdir(tmp_path)) == ["episode_0.hdf5"]


def test_an_existing_file_or_a_nan_is_refused_before_anything_is_written(tmp_path):
    """Nothing the user has is replaced without overwrite=True, and no number a reader would refuse is written."""
    p = tmp_path / "episode_0.hdf5"
    p.write_bytes(b"USERDATA")
    with pytest.raises(ValueError, match=f"^path: {p} already exists; write_episode replaces a file only with "
                                         "overwrite=True$"):
        write_episode(p, make_episode())
    assert p.read_bytes() == b"USERDATA"
    for field, where in (("action", "action"), ("qpos", "qpos")):
        ep = make_episode()
        getattr(ep, field)[1, 0] = np.inf
        with pytest.raises(ValueError, match=rf"^{where} holds NaN or inf \(first at frame 1\)$"):
            write_episode(tmp_path / f"{field}.hdf5", ep)
    ep = make_episode()
    ep.force = {"left": np.full((len(ep.qpos), 3), np.nan, np.float32)}
    with pytest.raises(ValueError, match=r"^force/left holds NaN or inf \(first at frame 0\)$"):
        write_episode(tmp_path / "force.hdf5", ep)
    for scale, says in ((1000.0, "reaches .*, above 60 N: are the labels in mN"), (-1.0, "has a negative median Fz in contact")):
        ep = make_episode()
        ep.force = {"left": np.tile(np.float32([0.1, 0.0, 5.0]) * scale, (len(ep.qpos), 1))}
        with pytest.raises(ValueError, match=f"^force/left {says}"):  # EpisodeDataset would refuse the file
            write_episode(tmp_path / "force.hdf5", ep)
    with pytest.raises(ValueError, match=r"^compression: expected one of \(None, 'gzip', 'lzf'\), got 'zip'$"):
        write_episode(tmp_path / "zip.hdf5", make_episode(), compression="zip")
    assert sorted(os.listdir(tmp_path)) == ["episode_0.hdf5"]


def test_episode_paths_sorted_numerically(tmp_path):
    for i in (10, 2, 0):
        write_episode(tmp_path / f"episode_{i}.hdf5", make_episode(T=2))
    (tmp_path / "notes.txt").write_text("x")
    assert [episode_index(p) for p in episode_paths(tmp_path)] == [0, 2, 10]
    with pytest.raises(ValueError, match="episode_<i>"):
        episode_index("foo.hdf5")


@pytest.mark.parametrize("change, match", [
    (dict(action=np.zeros((5, 5), np.float32)), "action: expected 6 frames"),
    (dict(images={"wrist": np.zeros((6, 8, 10, 3), np.float32)}), "images/wrist: expected uint8"),
    (dict(tactile={"left": np.zeros((6, 12, 16), np.uint8)}), r"tactile/left: expected uint8 \(T, H, W, 3\)"),
    (dict(force={"left": np.zeros((6, 2), np.float32)}), r"force/left: expected \(T, 3\)"),
    (dict(force={"left": np.zeros((4, 3), np.float32)}), "force/left: expected 6 frames"),
    (dict(tactile_background={"right": np.zeros((12, 16, 3), np.uint8)}), "tactile_background/right: no tactile"),
    (dict(tactile_background={"left": np.zeros((10, 16, 3), np.uint8)}), "tactile_background/left: expected shape"),
    (dict(qpos=np.zeros((0, 5), np.float32), action=np.zeros((0, 5), np.float32)), "at least one frame"),
    (dict(qpos=np.array(["a"] * 6)), "qpos: expected a numeric array"),
    (dict(images={"a/b": np.zeros((6, 8, 10, 3), np.uint8)}), "without '/'"),
    (dict(attrs={"sim": 1}), "'sim' is reserved"),
    (dict(sim="false"), r"^sim: expected True or False, got 'false'$"),  # bool("false") would be True
])
def test_bad_input_names_the_field(change, match):
    ep = make_episode()
    kwargs = dict(qpos=ep.qpos, action=ep.action, images=ep.images, tactile=ep.tactile,
                  tactile_background=ep.tactile_background, force=ep.force, sim=ep.sim, attrs={})
    kwargs.update(change)
    with pytest.raises(ValueError, match=match):
        Episode(**kwargs)


def test_read_missing_or_foreign_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_episode(tmp_path / "episode_9.hdf5")
    with h5py.File(tmp_path / "other.hdf5", "w") as f:
        f["x"] = 1
    with pytest.raises(ValueError, match="not an ACT episode"):
        read_episode(tmp_path / "other.hdf5")
