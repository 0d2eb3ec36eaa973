"""EpisodeDataset: frame indexing, padded action chunks, stats saved once, read-only, background estimate."""

import hashlib
import json
import os
import warnings

import h5py
import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from controltac_il.datasets import Episode, EpisodeDataset, estimate_background, read_background_image, write_episode
from controltac_il.datasets.background import image_digests

H, W = 12, 16


def synthetic_episode(T, seed, background=True, force=True, contact=range(3, 7)):
    """Tactile frames = flat background + noise, with a bright blob on the frames in ``contact``."""
    rng = np.random.default_rng(seed)
    bg = np.full((H, W, 3), 100, np.uint8)
    tactile = np.repeat(bg[None], T, 0).astype(np.int16) + rng.integers(-2, 3, (T, H, W, 3))
    f = np.zeros((T, 3), np.float32)
    for t in (t for t in contact if t < T):
        tactile[t, 3:9, 4:12] += 60
        f[t] = (0.1, -0.2, 2.0 + t)
    return Episode(
        qpos=np.arange(T * 4, dtype=np.float32).reshape(T, 4) + 1000 * seed,
        action=-np.arange(T * 3, dtype=np.float32).reshape(T, 3) - 1000 * seed,
        images={"wrist": rng.integers(0, 256, (T, 6, 8, 3), dtype=np.uint8)},
        tactile={"left": tactile.clip(0, 255).astype(np.uint8)},
        tactile_background={"left": bg} if background else {},
        force={"left": f} if force else {},
        sim=True,
    )


@pytest.fixture
def folder(tmp_path):
    root = tmp_path / "demos"
    for i, T in enumerate((9, 4)):
        write_episode(root / f"episode_{i}.hdf5", synthetic_episode(T, i))
    return root


def test_a_selection_that_is_not_names_is_refused(folder, tmp_path):
    for field in ("cameras", "tactile_sensors"):
        with pytest.raises(ValueError, match=f"^{field}: expected a name or a list of names, got 5$"):
            EpisodeDataset(folder, stats_path=tmp_path / "s.json", **{field: 5})


def test_chunk_size_is_a_count(folder, tmp_path):
    """A numpy int is a count; a bool or a float is not (True would read as a chunk of 1)."""
    assert type(EpisodeDataset(folder, chunk_size=np.int64(3), stats_path=tmp_path / "s.json").chunk_size) is int
    for bad in (True, 2.0):
        with pytest.raises(ValueError, match=f"^chunk_size: expected an int >= 1, got {bad!r}$"):
            EpisodeDataset(folder, chunk_size=bad, stats_path=tmp_path / "s.json")


def test_items_and_padded_chunks(folder, tmp_path):
    ds = EpisodeDataset(folder, chunk_size=5, stats_path=tmp_path / "s.json")
    assert len(ds) == 13
    it = ds[7]  # episode 0, frame 7 of 9: 2 real actions + 3 padded
    assert it["episode_index"] == 0 and it["frame_index"] == 7
    ep = synthetic_episode(9, 0)
    np.testing.assert_array_equal(it["observation.qpos"].numpy(), ep.qpos[7])
    np.testing.assert_array_equal(it["action"][:2].numpy(), ep.action[7:9])
    np.testing.assert_array_equal(it["action"][2:].numpy(), np.repeat(ep.action[8:9], 3, 0))
    assert it["action_is_pad"].tolist() == [False, False, True, True, True]
    assert it["action"].dtype == torch.float32 and it["action"].shape == (5, 3)
    np.testing.assert_array_equal(it["observation.images.wrist"].permute(1, 2, 0).numpy(), ep.images["wrist"][7])
    np.testing.assert_array_equal(it["observation.tactile.left"].permute(1, 2, 0).numpy(), ep.tactile["left"][7])
    assert it["observation.tactile_background.left"].shape == (3, H, W)
    np.testing.assert_array_equal(it["observation.force.left"].numpy(), ep.force["left"][7])
    it = ds[9]  # episode 1 (4 frames), frame 0: one padded action
    assert (it["episode_index"], it["frame_index"]) == (1, 0)
    assert it["action_is_pad"].tolist() == [False] * 4 + [True]
    assert ds[-1]["frame_index"] == 3
    with pytest.raises(IndexError):
        ds[13]
    assert ds[np.int64(9)]["frame_index"] == 0
    for bad in (1.7, "3", True):  # each would be another item, silently
        with pytest.raises(TypeError, match=f"^EpisodeDataset indices are ints, got {type(bad).__name__}$"):
            ds[bad]
    ep_idx, fr_idx = ds.frame_table()
    assert ep_idx.tolist() == [0] * 9 + [1] * 4 and fr_idx.tolist() == list(range(9)) + list(range(4))


def test_a_constant_state_dimension_and_a_one_frame_episode_give_finite_items(tmp_path):
    """std 0 (a joint that never moved) is floored, never a division by zero; T = 1 pads its whole chunk."""
    from act_fixtures import tiny_config

    from controltac_il.datasets.act_dataset import STD_FLOOR
    from policies.act import ACT

    root = tmp_path / "demos"
    for i, T in enumerate((9, 1)):
        ep = synthetic_episode(T, i)
        ep.qpos[:, 2] = 0.5
        write_episode(root / f"episode_{i}.hdf5", ep)
    ds = EpisodeDataset(root, chunk_size=4, stats_path=tmp_path / "stats.json")
    assert ds.stats["qpos"]["std"][2] == pytest.approx(STD_FLOOR) and len(ds) == 10
    last = ds[9]  # the one-frame episode
    assert last["action_is_pad"].tolist() == [False, True, True, True]
    assert all(torch.isfinite(v).all() for v in last.values() if torch.is_tensor(v) and v.is_floating_point())
    model = ACT(tiny_config(state_dim=4, action_dim=3))
    model.set_stats(ds.stats)
    normalised = (last["observation.qpos"] - model.qpos_mean) / model.qpos_std  # as ACT's forward
    assert torch.isfinite(normalised).all() and normalised[2] == 0


def test_stats_computed_once_and_saved_outside_data(folder, tmp_path, monkeypatch):
    monkeypatch.setenv("CONTROLTAC_CACHE", str(tmp_path / "cache"))
    ds = EpisodeDataset(folder)
    assert ds.stats_path.is_file() and folder not in ds.stats_path.parents
    qpos = np.concatenate([synthetic_episode(9, 0).qpos, synthetic_episode(4, 1).qpos])
    np.testing.assert_allclose(ds.stats["qpos"]["mean"], qpos.mean(0), rtol=1e-6)
    np.testing.assert_allclose(ds.stats["qpos"]["std"], qpos.std(0), rtol=1e-5)
    mtime = ds.stats_path.stat().st_mtime_ns
    ds2 = EpisodeDataset(folder, stats_path=ds.stats_path)
    assert ds.stats_path.stat().st_mtime_ns == mtime  # loaded, not recomputed
    np.testing.assert_array_equal(ds2.stats["action"]["std"], ds.stats["action"]["std"])
    # a changed data folder invalidates the saved stats
    write_episode(folder / "episode_2.hdf5", synthetic_episode(5, 2))
    ds3 = EpisodeDataset(folder, stats_path=ds.stats_path)
    assert json.loads(ds.stats_path.read_text())["fingerprint"]["files"][-1][0] == "episode_2.hdf5"
    assert not np.allclose(ds3.stats["qpos"]["mean"], ds.stats["qpos"]["mean"])
    with pytest.raises(ValueError, match="stats_path: must not be inside"):
        EpisodeDataset(folder, stats_path=folder / "stats.json")


def test_rerecorded_episode_of_same_size_invalidates_stats(folder, tmp_path):
    """A fixed-length task re-recorded into the same folder gives files of the same name, size and
    length; the saved statistics (and ForceAugment caches, keyed by the same fingerprint) must not
    be reused for them."""
    ds = EpisodeDataset(folder, stats_path=tmp_path / "s.json")
    path = folder / "episode_1.hdf5"
    size = path.stat().st_size
    write_episode(path, synthetic_episode(4, 77), overwrite=True)
    assert path.stat().st_size == size
    ds2 = EpisodeDataset(folder, stats_path=tmp_path / "s.json")
    assert ds2.fingerprint() != ds.fingerprint()
    assert not np.allclose(ds2.stats["qpos"]["mean"], ds.stats["qpos"]["mean"])


def test_read_only_folder_is_untouched(folder, tmp_path):
    sums = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.iterdir()}
    for p in folder.iterdir():
        os.chmod(p, 0o444)
    os.chmod(folder, 0o555)
    try:
        ds = EpisodeDataset(folder, chunk_size=3, stats_path=tmp_path / "s.json")
        batches = list(DataLoader(ds, batch_size=4, shuffle=True, num_workers=2))
    finally:
        os.chmod(folder, 0o755)
    assert sum(len(b["episode_index"]) for b in batches) == 13
    assert {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.iterdir()} == sums


def test_missing_background_is_estimated_with_warning(tmp_path):
    root = tmp_path / "d"
    write_episode(root / "episode_0.hdf5", synthetic_episode(10, 0, background=False, force=False))
    with pytest.warns(UserWarning, match=r"no tactile background for sensor 'left'.*6 frame\(s\) of the episode taken"):
        ds = EpisodeDataset(root, stats_path=tmp_path / "s.json")
    bg = ds[0]["observation.tactile_background.left"].permute(1, 2, 0).numpy().astype(int)
    assert np.abs(bg - 100).max() <= 2  # the blob (+60) frames are excluded
    root2 = tmp_path / "d2"
    write_episode(root2 / "episode_0.hdf5", synthetic_episode(10, 0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a recorded background: no estimate, no warning
        EpisodeDataset(root2, stats_path=tmp_path / "s2.json")


def test_a_given_background_image_stands_in_every_episode_and_in_the_datas_identity(tmp_path):
    """Episodes that start in contact: the image of the sensor at rest is every episode's background, in place of
    the estimate, without a warning; the dataset's fingerprint (ForceAugment's caches, the stats) holds its digest."""
    import cv2

    root = tmp_path / "d"
    for i in range(2):
        write_episode(root / f"episode_{i}.hdf5", synthetic_episode(10, i, background=False, contact=range(0, 10)))
    rest = tmp_path / "rest.png"
    cv2.imwrite(str(rest), np.full((H, W, 3), 100, np.uint8))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        given = EpisodeDataset(root, stats_path=tmp_path / "s.json", background_images={"left": rest})
    for i in (0, 10, 19):
        assert (given[i]["observation.tactile_background.left"] == 100).all()
    with pytest.warns(UserWarning, match="no tactile background"):
        estimated = EpisodeDataset(root, stats_path=tmp_path / "s.json")
    assert (estimated[0]["observation.tactile_background.left"] > 150).any()  # the estimate holds the contact
    digest = image_digests({"left": read_background_image(rest)})
    assert given.fingerprint() == {**estimated.fingerprint(), "background_images": digest}
    with pytest.raises(ValueError, match=r"^background_images: 'right' is not a tactile sensor of the data; those "
                                         r"are \['left'\]"):
        EpisodeDataset(root, stats_path=tmp_path / "s.json", background_images={"right": rest})


def test_estimate_background_prefers_force_labels():
    ep = synthetic_episode(10, 0, contact=range(0, 6))  # in contact from the start: only labels can tell
    bg, used = estimate_background(ep.tactile["left"], ep.force["left"])
    assert used.tolist() == [6, 7, 8, 9]
    assert np.abs(bg.astype(int) - 100).max() <= 2
    with pytest.raises(ValueError, match="force: expected shape"):
        estimate_background(ep.tactile["left"], ep.force["left"][:3])
    with pytest.raises(ValueError, match="frames: expected uint8"):
        estimate_background(ep.tactile["left"].astype(np.float32))


def test_labels_that_never_read_no_contact_fall_back_to_the_start_frames_with_a_warning():
    """Every label above the no-contact force (in contact throughout, or an offset sensor): the labels cannot tell,
    so the start frames are taken, and the warning says that they hold the contact if the episode starts in one."""
    ep = synthetic_episode(10, 0, contact=range(4, 10))
    force = ep.force["left"].copy()
    force[:, 2] += 0.4  # a sensor offset: the first four frames are out of contact, no label reads it
    with pytest.warns(UserWarning, match=r"no frame's force label is below 0\.1 N \(lowest 0\.40 N\)"):
        bg, used = estimate_background(ep.tactile["left"], force)
    assert used.tolist() == [0, 1, 2, 3] and np.abs(bg.astype(int) - 100).max() <= 2


def test_bad_input(folder, tmp_path):
    with pytest.raises(ValueError, match="chunk_size"):
        EpisodeDataset(folder, chunk_size=0)
    with pytest.raises(ValueError, match="cameras: unknown name 'top'"):
        EpisodeDataset(folder, cameras=["top"], stats_path=tmp_path / "s.json")
    with pytest.raises(ValueError, match="tactile_sensors: unknown name 'right'"):
        EpisodeDataset(folder, tactile_sensors="right", stats_path=tmp_path / "s.json")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no episode_<i>.hdf5"):
        EpisodeDataset(tmp_path / "empty")
    ep = synthetic_episode(3, 5)
    ep.images = {"top": ep.images["wrist"]}
    write_episode(folder / "episode_5.hdf5", ep)
    with pytest.raises(ValueError, match=r"episode_5.hdf5 lacks images/wrist, unlike episode_0.hdf5"):
        EpisodeDataset(folder, stats_path=tmp_path / "s.json")


def _edit(path, key, value):
    """Replace (or with None remove) one dataset of an episode file, bypassing the writer's checks."""
    import h5py

    with h5py.File(path, "r+") as f:
        del f[key]
        if value is not None:
            f[key] = value


@pytest.mark.parametrize("key, value, message", [
    ("action", np.zeros((5, 3), np.float32), r"episode_0.hdf5: /action has 5 frames, /observations/qpos has 9"),
    ("observations/tactile/left", np.zeros((4, H, W, 3), np.uint8), r"episode_0.hdf5: /observations/tactile/left has 4"),
    ("observations/force/left", np.zeros((8, 3), np.float32), r"episode_0.hdf5: /observations/force/left has 8"),
    ("action", None, r"episode_0.hdf5: no /action"),
    ("observations/qpos", None, r"episode_0.hdf5: no /observations/qpos"),
    ("observations/qpos", np.zeros((0, 4), np.float32), r"episode_0.hdf5: /observations/qpos has 0 frames; an episode"),
])
def test_streams_of_one_episode_must_have_one_length(folder, tmp_path, key, value, message):
    _edit(folder / "episode_0.hdf5", key, value)
    with pytest.raises(ValueError, match=message):
        EpisodeDataset(folder, stats_path=tmp_path / "s.json")


@pytest.mark.parametrize("key, value, message", [
    ("observations/tactile/left", np.zeros((9, H, W), np.uint8), r"/observations/tactile/left has shape \(9, 12, 16\); "
                                                                 r"expected \(T, H, W, 3\)"),
    ("observations/images/wrist", np.zeros((9, H, W, 4), np.uint8), r"/observations/images/wrist has shape"),
    ("observations/qpos", np.zeros(9, np.float32), r"/observations/qpos has shape \(9,\); expected \(T, D\)"),
    ("action", np.float32(0), r"/action has shape \(\); expected \(T, D\)"),
    ("observations/force/left", np.zeros((9, 2), np.float32), r"/observations/force/left has shape \(9, 2\)"),
    ("observations/tactile_background/left", np.zeros((H, W), np.uint8), r"/observations/tactile_background/left has shape"),
])
def test_a_stream_of_the_wrong_shape_is_named_before_anything_reads_it(folder, tmp_path, key, value, message):
    _edit(folder / "episode_0.hdf5", key, value)
    with pytest.raises(ValueError, match=r"episode_0.hdf5: " + message):
        EpisodeDataset(folder, stats_path=tmp_path / "s.json")


def test_a_corrupt_file_is_named(folder, tmp_path):
    (folder / "episode_1.hdf5").write_bytes(b"not hdf5")
    with pytest.raises(ValueError, match=r"episode_1.hdf5: not a readable HDF5 episode file"):
        EpisodeDataset(folder, stats_path=tmp_path / "s.json")


@pytest.mark.parametrize("scale, message", [
    (1000.0, r"episode_0.hdf5: /observations/force/left reaches .* are the labels in mN"),
    (-1.0, r"episode_0.hdf5: /observations/force/left has a negative median Fz"),
    (np.nan, r"episode_0.hdf5: /observations/force/left holds NaN or inf \(first at frame 3\)"),
])
def test_force_labels_in_the_wrong_unit_or_sign_are_reported(folder, tmp_path, scale, message):
    with h5py.File(folder / "episode_0.hdf5", "r+") as f:  # a file written by another tool
        f["observations/force/left"][3:7] *= scale
    with pytest.raises(ValueError, match=message):
        EpisodeDataset(folder, stats_path=tmp_path / "s.json")


def test_nan_actions_are_reported_before_training(folder, tmp_path):
    with h5py.File(folder / "episode_0.hdf5", "r+") as f:  # write_episode itself refuses NaN
        f["action"][2, 1] = np.nan
    with pytest.raises(ValueError, match=r"episode_0.hdf5: /action holds NaN or inf \(first at frame 2\)"):
        EpisodeDataset(folder, stats_path=tmp_path / "s.json")


def _replace(path, key, values):
    """A file of another tool's: ``key`` of ``path`` rewritten as ``values``."""
    with h5py.File(path, "r+") as f:
        del f[key]
        f[key] = values


@pytest.mark.parametrize("key, values, says", [
    ("observations/tactile/left", {"": np.zeros((4, H + 2, W, 3), np.uint8),
                                   "observations/tactile_background/left": np.zeros((H + 2, W, 3), np.uint8)},
     rf"episode_1.hdf5: /observations/tactile/left is \({H + 2}, {W}, 3\) per frame, episode_0.hdf5's is "
     rf"\({H}, {W}, 3\)"),
    ("observations/qpos", np.zeros((4, 7), np.float32), r"episode_1.hdf5: /observations/qpos is \(7,\) per frame"),
    ("observations/tactile/left", np.zeros((4, H, W, 3), np.float32),
     "episode_1.hdf5: /observations/tactile/left is float32; images are stored as uint8 RGB"),
    ("observations/tactile_background/left", np.zeros((H, W + 1, 3), np.uint8),
     rf"episode_1.hdf5: /observations/tactile_background/left has shape \({H}, {W + 1}, 3\); expected its frames'"),
])
def test_an_episode_whose_shapes_differ_from_the_others_is_named(folder, tmp_path, key, values, says):
    """Frames that could not stack into one batch (or a background that does not fit its frames) are refused when
    the folder is opened, naming the file and the stream, not at the first batch."""
    for k, v in (values.items() if isinstance(values, dict) else [("", values)]):
        _replace(folder / "episode_1.hdf5", k or key, v)
    with pytest.raises(ValueError, match=f"^{says}"):
        EpisodeDataset(folder, stats_path=tmp_path / "s.json")


def test_a_camera_nobody_reads_may_change_size_between_episodes(folder, tmp_path):
    for i, size in enumerate((8, 10)):
        with h5py.File(folder / f"episode_{i}.hdf5", "r+") as f:
            f["observations/images/top"] = np.zeros((len(f["action"]), size, size, 3), np.uint8)
    assert EpisodeDataset(folder, cameras=["wrist"], stats_path=tmp_path / "s.json").cameras == ["wrist"]
    with pytest.raises(ValueError, match=r"^episode_1.hdf5: /observations/images/top is \(10, 10, 3\) per frame"):
        EpisodeDataset(folder, stats_path=tmp_path / "s.json")


def test_streams_must_match_across_episodes(folder, tmp_path):
    """A sensor missing from episode 0 (present in the others) is an error, not dropped for every episode."""
    write_episode(folder / "episode_0.hdf5", synthetic_episode(9, 0, force=False), overwrite=True)
    with pytest.raises(ValueError, match=r"episode_1.hdf5 has force/left, unlike episode_0.hdf5"):
        EpisodeDataset(folder, stats_path=tmp_path / "s.json")
    ep = synthetic_episode(9, 0)
    ep.tactile["right"] = ep.tactile["left"]
    write_episode(folder / "episode_0.hdf5", ep, overwrite=True)
    with pytest.raises(ValueError, match=r"episode_1.hdf5 lacks tactile/right"):
        EpisodeDataset(folder, stats_path=tmp_path / "s.json")
    ds = EpisodeDataset(folder, tactile_sensors=["left"], stats_path=tmp_path / "s.json")  # a chosen subset
    assert ds.tactile_sensors == ["left"] and ds.force_sensors == ["left"]


def test_stats_never_overwrite_a_file_of_the_users(folder, tmp_path):
    mine = tmp_path / "notes.json"
    mine.write_text('{"my": "notes"}')
    with pytest.raises(ValueError, match=r"stats_path: .*notes.json exists and is not a stats file"):
        EpisodeDataset(folder, stats_path=mine)
    assert mine.read_text() == '{"my": "notes"}'
    ours = tmp_path / "stats.json"
    EpisodeDataset(folder, stats_path=ours)
    assert json.loads(ours.read_text())["written_by"] == "controltac_il.datasets.EpisodeDataset"
    write_episode(folder / "episode_1.hdf5", synthetic_episode(6, 1), overwrite=True)  # the data changed: its own file is replaced
    assert EpisodeDataset(folder, stats_path=ours).lengths.tolist() == [9, 6]
