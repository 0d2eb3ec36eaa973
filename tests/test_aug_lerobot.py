"""ForceAugment on LeRobot-convention datasets (``lerobot_like.LeRobotLike``), without LeRobot (it cannot be installed
here); a tiny randomly initialised generator (aug_fixtures).
"""

import warnings

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from aug_fixtures import synthetic_episode, tiny_estimator, tiny_generator  # noqa: E402
from lerobot_like import BG, FORCE, GEL, LeRobotLike, episodes  # noqa: E402

from controltac_il.augment import STATUS, ForceAugment, StaleCacheError  # noqa: E402


@pytest.fixture(scope="module")
def gen():
    return tiny_generator()


@pytest.fixture(scope="module")
def est():
    return tiny_estimator()


def wrap(ds, gen, est, tmp_path=None, name="c", **kw):
    kw.setdefault("copies", 2)
    kw.setdefault("tactile_keys", [GEL])
    if tmp_path is not None:
        kw.setdefault("cache_dir", tmp_path / name)
    else:
        kw["mode"] = "online"
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", ".*background estimated", UserWarning)
        return ForceAugment(ds, gen, estimator=est, progress=False, **kw)


def same(x, y):
    if isinstance(x, torch.Tensor):
        return isinstance(y, torch.Tensor) and x.dtype == y.dtype and x.shape == y.shape and bool(
            ((x == y) | (x.isnan() & y.isnan())).all())
    return type(x) is type(y) and x == y


def assert_same_items(x, y):
    assert x.keys() == y.keys()
    for k in x:
        assert same(x[k], y[k]), k


def by_index(aug, loader_kw):
    """Every item of ``aug`` through a shuffled 2-worker DataLoader, keyed by (copy, index), unbatched."""
    out = {}
    for batch in DataLoader(aug, batch_size=5, shuffle=True, num_workers=2, **loader_kw):
        for b in range(len(batch["index"])):
            item = {k: (v[b] if isinstance(v, torch.Tensor) else v[b]) for k, v in batch.items()}
            out[int(item["augment"][0, 0]), int(item["index"])] = item
    return out


@pytest.mark.parametrize("uint8_hwc", [False, True], ids=["float_chw", "uint8_hwc"])
@pytest.mark.parametrize("labels", [False, True], ids=["no_labels", "labels"])
@pytest.mark.parametrize("backgrounds", [False, True], ids=["no_bg", "bg"])
def test_single_frames_cache_equals_online_and_everything_else_passes_through(
        gen, est, tmp_path, uint8_hwc, labels, backgrounds):
    ds = LeRobotLike(episodes(), uint8_hwc=uint8_hwc, labels=labels, backgrounds=backgrounds)
    maps = dict(force_keys={GEL: FORCE} if labels else None, background_keys={GEL: BG} if backgrounds else None)
    cached, online = wrap(ds, gen, est, tmp_path, **maps), wrap(ds, gen, est, **maps)
    assert cached.settings()["reference_force"] == {GEL: "labels" if labels else "estimator"}
    n, regenerated = len(ds), 0
    for i in range(len(cached)):
        x, y, src = cached[i], online[i], ds[i % n]
        assert_same_items(x, y)  # identical in the two modes
        assert x.keys() == src.keys() | {"augment"}
        for k in src:
            if k not in (GEL, FORCE):
                assert same(x[k], src[k]), k  # passed through unchanged
        assert x[GEL].dtype == src[GEL].dtype and x[GEL].shape == src[GEL].shape  # as it came in
        status = int(cached.info(x)[f"status.{GEL}"])
        if status in (STATUS["regenerated"], STATUS["clamped"]):
            regenerated += 1
            assert i >= n and not torch.equal(x[GEL], src[GEL])
            if not uint8_hwc:
                assert 0.0 <= float(x[GEL].min()) and float(x[GEL].max()) <= 1.0
            if labels:  # the label follows the image
                np.testing.assert_allclose(x[FORCE].numpy(), cached.info(x)[f"target_force.{GEL}"].numpy(), rtol=1e-6)
        else:
            assert torch.equal(x[GEL], src[GEL]) and (not labels or torch.equal(x[FORCE], src[FORCE]))
    assert regenerated > 0


def window_dataset(labels=False, **kw):
    deltas = {GEL: [-0.2, -0.1, 0.0], "action": [0.0, 0.1, 0.2], **({FORCE: [-0.1, 0.0]} if labels else {})}
    return LeRobotLike(episodes(), delta_timestamps=deltas, labels=labels, **kw)


@pytest.mark.parametrize("uint8_hwc, labels", [(False, False), (True, False), (False, True)],
                         ids=["float_chw", "uint8_hwc", "float_chw_label_windows"])
def test_window_frames_equal_the_same_frames_alone(gen, est, tmp_path, uint8_hwc, labels):
    """Each unpadded window position is augmented as that (episode, copy, frame) alone (image, and label
    where the labels come as a window too); padded positions stay as they came."""
    maps = {"force_keys": {GEL: FORCE}} if labels else {}
    single = LeRobotLike(episodes(), uint8_hwc=uint8_hwc, labels=labels)
    windows = window_dataset(labels, uint8_hwc=uint8_hwc)
    alone = wrap(single, gen, est, tmp_path, "alone", **maps)
    for aug in (wrap(windows, gen, est, tmp_path, "win", **maps), wrap(windows, gen, est, **maps)):
        assert aug.keys.offsets[GEL] == (-2, -1, 0)  # from delta_timestamps x the dataset's fps
        n, pads, moved = len(windows), 0, 0
        for i in range(len(aug)):
            x, src = aug[i], windows[i % n]
            copy, (e, t) = i // n, windows.rows[i % n]
            assert x[GEL].shape == src[GEL].shape and x[GEL].dtype == src[GEL].dtype
            for k in ("action", "action_is_pad", f"{GEL}_is_pad", "timestamp", "index", "task"):
                assert same(x[k], src[k]), k
            for p, pad in enumerate(src[f"{GEL}_is_pad"].tolist()):
                if pad:
                    pads += 1
                    assert torch.equal(x[GEL][p], src[GEL][p])
                    continue
                f = t + (p - 2)
                ref = alone[copy * n + single.rows.index((e, f))]
                assert torch.equal(x[GEL][p], ref[GEL]), (i, p)
                moved += p != 2 and not torch.equal(x[GEL][p], src[GEL][p])
                if labels and p >= 1:  # the label window holds frames t - 1, t
                    q = p - 1
                    want = src[FORCE][q] if src[f"{FORCE}_is_pad"][q] else ref[FORCE]
                    assert torch.equal(x[FORCE][q], want), (i, p)
            assert same(x["augment"], alone[i]["augment"])  # what was done to the item's own frame
        assert pads == 2 * 3 * 3  # first two frames of 2 episodes: 2 + 1 pads each, in 3 copies
        assert moved > 0  # earlier frames of the window were regenerated too


@pytest.mark.parametrize("variant", ["windows_no_labels_no_bg", "uint8_labels_bg"])
def test_shuffled_two_worker_loader_is_deterministic(gen, est, tmp_path, variant):
    if variant.startswith("windows"):
        ds, maps = window_dataset(), {}
    else:
        ds, maps = LeRobotLike(episodes(), uint8_hwc=True, labels=True, backgrounds=True), dict(
            force_keys={GEL: FORCE}, background_keys={GEL: BG})
    cached, online = wrap(ds, gen, est, tmp_path, **maps), wrap(ds, gen, est, **maps)
    want = {(i // len(ds), int(ds[i % len(ds)]["index"])): i for i in range(len(cached))}
    for aug, seed in ((cached, 1), (cached, 2), (online, 3)):  # two epochs (other orders), the other mode
        got = by_index(aug, {"generator": torch.Generator().manual_seed(seed)})
        assert set(got) == set(want)
        for key, i in want.items():
            direct = cached[i]
            for k in direct:
                if k != "task":
                    assert same(got[key][k], direct[k]), (key, k)
            assert got[key]["task"] == direct["task"]


def test_episode_order_first_frame_and_index_columns(gen, est, tmp_path):
    """Episodes told apart by episode_index alone, in any row order, frame_index not starting at 0."""
    eps = {7: synthetic_episode(6, 0, range(2, 6), labels=False), 3: synthetic_episode(5, 1, range(1, 4), labels=False)}
    rng = np.random.default_rng(0)
    shuffled = LeRobotLike(eps, first={7: 4}, rows=rng.permutation(11).tolist(), columns=True)
    plain = LeRobotLike(eps, first={7: 4})
    a, b = wrap(shuffled, gen, est, tmp_path, "a"), wrap(plain, gen, est, tmp_path, "b")
    assert list(a._episodes()) == [3, 7] and [t for t, _ in a._episodes()[7]] == list(range(4, 10))
    assert a.chunk_list() == b.chunk_list() and a.summary() == b.summary()
    on = wrap(shuffled, gen, est)
    for i in range(len(a)):
        j = (i // 11) * 11 + plain.rows.index(shuffled.rows[i % 11])
        assert_same_items({k: v for k, v in a[i].items() if k != "index"}, {k: v for k, v in b[j].items() if k != "index"})
        assert_same_items(a[i], on[i])
    calls = {"n": 0}
    real = LeRobotLike.__getitem__

    def counting(self, i):
        calls["n"] += 1
        return real(self, i)

    LeRobotLike.__getitem__ = counting
    try:
        wrap(shuffled, gen, est, tmp_path, "a")  # the cache exists: the hf_dataset columns give the episodes
    finally:
        LeRobotLike.__getitem__ = real
    assert calls["n"] <= 4  # the probe and two spot checks, not a scan
    twice = LeRobotLike(eps, rows=[0, 1, 2, 2, 3, 4])
    with pytest.raises(ValueError, match="dataset: episode 7 has frame_index 2 twice"):
        wrap(twice, gen, est, tmp_path, "d")


def sensor_episodes():
    """Two episodes of GelSight-style frames (the sensor model, 120x160) pressing at a ramp of forces, with
    no-contact frames first: real-looking residuals for the shipped generator."""
    from controltac_il.datasets import Episode
    from controltac_il.tactile import SensorSpec, TactileSensor

    sensor = TactileSensor(SensorSpec.gelsight_mini().scaled(120, 160))
    out = {}
    for e, (obj, pose) in enumerate((("big_sphere", (0.4, -0.3, 0.2)), ("cross", (-0.5, 0.2, 0.9)))):
        frames = [sensor.render_penetration(np.zeros((120, 160)), noise_seed=10 * e + k) for k in (7, 8)]
        frames += [sensor.press(obj, pose, (0.0, 0.0, fz), noise_seed=10 * e + i).image
                   for i, fz in enumerate((2.0, 3.5, 5.0, 6.5))]
        T = len(frames)
        out[e] = Episode(qpos=np.zeros((T, 4), np.float32), action=np.zeros((T, 5), np.float32),
                         images={"wrist": np.zeros((T, 8, 8, 3), np.uint8)}, tactile={"left": np.stack(frames)},
                         tactile_background={}, force={}, sim=True)
    return out


def test_online_equals_cache_exactly_at_any_batch_size_on_real_looking_frames(tmp_path):
    """Online and cache modes give the same bytes, whatever the cache's batch_size (one frame; five, across a
    generation chunk's boundary) and the loader's shuffling, with the shipped generator and estimator on unlabelled sensor-model frames (one torch thread in
    both: the thread count is part of a cache's settings)."""
    from controltac_il.generator import ForceGenerator

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as in DataLoader workers
    try:
        gen, ds = ForceGenerator.from_pretrained(), LeRobotLike(sensor_episodes(), uint8_hwc=True)
        caches = [wrap(ds, gen, None, tmp_path, f"b{bs}", batch_size=bs, copies=2) for bs in (1, 5)]
        assert all(c.settings() == caches[0].settings() for c in caches)  # batch_size is not a setting of the frames
        assert caches[0].summary()["regenerated"] > 0
        online = wrap(ds, gen, None, copies=2)
        got = by_index(online, {"generator": torch.Generator().manual_seed(0)})
        for i in range(len(ds), len(caches[0])):
            key = (i // len(ds), int(ds[i % len(ds)]["index"]))
            want = caches[0][i]
            for c in caches[1:]:
                assert torch.equal(c[i][GEL], want[GEL])
            assert torch.equal(got[key][GEL], want[GEL]) and same(got[key]["augment"], want["augment"])
        torch.set_num_threads(2)  # another thread count is another cache: recorded, and the 1-thread one refused
        assert wrap(ds, gen, None, tmp_path, "t2", build="manual").settings()["numerics"]["intra_op_threads"] == 2
        with pytest.raises(StaleCacheError, match="numerics: cache has .*'intra_op_threads': 1.*now .*: 2"):
            wrap(ds, gen, None, tmp_path, "b1", copies=2)
        assert caches[0].settings()["numerics"] == {"device": "cpu", "dtype": "float32", "intra_op_threads": 1}
    finally:
        torch.set_num_threads(threads)


def test_a_tactile_image_key_is_never_read_as_its_own_force_label(gen, est, tmp_path):
    """tactile_keys=("observation.images.gelsight",) on a dataset without force labels: the image key is the
    tactile stream, not a label, in both modes."""
    ds = LeRobotLike(episodes(labels=False))
    for mode in ("online", "cache"):
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", ".*background estimated", UserWarning)
            aug = ForceAugment(ds, gen, tactile_keys=("observation.images.gelsight",), estimator=est, mode=mode,
                               cache_dir=tmp_path / "c", progress=False, copies=1)
        item = aug[len(ds) + 4]
        assert item[GEL].shape == (3, 32, 32) and item[GEL].dtype == torch.float32


def test_labels_only_under_an_explicit_mapping(gen, est, tmp_path):
    ds = LeRobotLike(episodes(), labels=True)
    plain = wrap(ds, gen, est, tmp_path, "plain")  # without a mapping no key is a force label, not even the image itself
    assert plain.labelled == {GEL: False} and plain.keys.backgrounds == {GEL: None}
    mapped = wrap(ds, gen, est, tmp_path, "mapped", force_keys={GEL: FORCE})
    assert mapped.labelled == {GEL: True} and mapped.settings()["force_keys"] == {GEL: FORCE}
    item = mapped[1]  # copy 0: the reference is the label
    np.testing.assert_allclose(mapped.info(item)[f"reference_force.{GEL}"].numpy(), ds[1][FORCE].numpy())
    for bad, match in (({GEL: GEL}, "never read as its own"), ({GEL: "observation.state"}, "not a force label"),
                       ({GEL: "nope"}, "do not have"), ({"observation.images.wrist": FORCE}, "not tactile keys")):
        with pytest.raises(ValueError, match=f"force_keys: .*{match}"):
            ForceAugment(ds, gen, tactile_keys=[GEL], force_keys=bad, mode="online")
    with pytest.raises(ValueError, match="background_keys: .*not one RGB image"):
        ForceAugment(ds, gen, tactile_keys=[GEL], background_keys={GEL: "observation.state"}, mode="online")


@pytest.mark.parametrize("scale, says", [(-1.0, "has a negative median Fz in contact"),
                                         (1000.0, r"reaches .*, above 60 N: are the labels in mN\?")])
def test_labels_pulling_or_in_millinewtons_are_refused_as_a_recorded_episodes_are(gen, est, tmp_path, scale, says):
    """Else every copy of such an episode is silently no-contact (Fz < 0) or skipped (out of range)."""
    eps = episodes()
    for ep in eps.values():
        ep.force["left"] *= scale
    for cache in (tmp_path, None):  # built at construction; online, at the first augmented item
        with pytest.raises(ValueError, match=rf"^{FORCE} \(episode 0\) {says}"):
            aug = wrap(LeRobotLike(eps, labels=True), gen, est, cache, force_keys={GEL: FORCE})
            aug[len(aug.dataset) + 4]


def test_a_frame_of_another_size_is_named(gen, est):
    eps = episodes()
    eps[1].tactile["left"] = [f for f in eps[1].tactile["left"]]  # one frame of the episode resized, as a bad export
    eps[1].tactile["left"][2] = np.zeros((16, 16, 3), np.uint8)
    with pytest.raises(ValueError, match=rf"^{GEL}: episode 1's frame 2 is \(16, 16\), its first \(32, 32\); every "
                                         "tactile frame of an episode needs one size$"):
        wrap(LeRobotLike(eps, labels=True), gen, est, None, force_keys={GEL: FORCE})[len(eps[0].qpos) + 2 + 16]


def test_auto_detection_error_lists_the_image_keys(gen):
    ds = LeRobotLike(episodes())
    with pytest.raises(ValueError, match=r"tactile_keys: .*\['observation.images.gelsight', 'observation.images.wrist'\]"
                                         r".*ForceAugment\(dataset, tactile_keys=\['observation.images.gelsight'\]\)"):
        ForceAugment(ds, gen, mode="online")
    cameras_only = LeRobotLike(episodes())
    cameras_only.frame = lambda e, t, f=cameras_only.frame: {("observation.images.left_cam" if k == GEL else k): v
                                                              for k, v in f(e, t).items()}
    # the example never names a camera as the tactile stream: a placeholder where no key looks like a sensor
    with pytest.raises(ValueError, match=r"tactile_keys=\['observation.images.<tactile camera>'\]"):
        ForceAugment(cameras_only, gen, mode="online")
    with pytest.raises(ValueError, match="tactile_keys: .*'observation.state' is not an RGB image"):
        ForceAugment(ds, gen, tactile_keys=["observation.state"], mode="online")
    assert ForceAugment(ds, gen, tactile_keys=["gelsight"], estimator=tiny_estimator(), mode="online",
                        progress=False).tactile_keys == (GEL,)


def test_windows_it_cannot_place_are_refused(gen):
    ds = window_dataset()
    ds.fps = None
    with pytest.raises(ValueError, match="fps: .*pass fps="):
        ForceAugment(ds, gen, tactile_keys=[GEL], mode="online")
    with pytest.raises(ValueError, match="fps: .*not whole frames at 7"):
        ForceAugment(ds, gen, tactile_keys=[GEL], mode="online", fps=7)
    ds.delta_timestamps = None
    with pytest.raises(ValueError, match=r"window_offsets: .*holds a window of 3 frames.*window_offsets="):
        ForceAugment(ds, gen, tactile_keys=[GEL], mode="online")
    with pytest.raises(ValueError, match="window_offsets: .*including 0"):
        ForceAugment(ds, gen, tactile_keys=[GEL], mode="online", window_offsets={GEL: [-3, -2, -1]})

    class NoPad(LeRobotLike):
        def __getitem__(self, idx):
            item = super().__getitem__(idx)
            item.pop(f"{GEL}_is_pad")
            return item

    with pytest.raises(ValueError, match="window_offsets: .*_is_pad"):
        ForceAugment(NoPad(episodes(), delta_timestamps={GEL: [-0.1, 0.0]}), gen, tactile_keys=[GEL], mode="online")
    given = ForceAugment(ds, gen, tactile_keys=[GEL], mode="online", window_offsets={GEL: [-2, -1, 0]},
                         estimator=tiny_estimator(), progress=False)
    assert given.keys.offsets[GEL] == (-2, -1, 0)


def test_recorded_backgrounds_that_vary_within_an_episode_give_the_same_frames_in_both_modes(gen, est, tmp_path):
    """The cache uses one background per episode (its first item's): online mode reads them the same way."""

    class Drifting(LeRobotLike):
        def __getitem__(self, idx):
            item = super().__getitem__(idx)
            item[BG] = (item[BG] + 0.02 * (int(item["frame_index"]) % 3)).clamp(0, 1)
            return item

    ds = Drifting(episodes(), labels=True, backgrounds=True)
    maps = dict(force_keys={GEL: FORCE}, background_keys={GEL: BG})
    cached, online = wrap(ds, gen, est, tmp_path, **maps), wrap(ds, gen, est, **maps)
    assert online._online.tables is not None
    for i in range(len(ds), len(cached)):
        assert_same_items(cached[i], online[i])


class OffSensorEstimator:
    """An estimator that reads every frame with 1.5 N of shear, beyond the validated 1 N (as the shipped one
    reads another sensor's frames)."""

    def predict(self, residuals):
        return np.tile(np.float32([1.5, 0.0, 4.0]), (len(residuals), 1))


@pytest.mark.parametrize("policy, fz", [("nominal", 5.5), ("clip", 4.0), ("skip", None)])
def test_estimated_references_outside_the_range_follow_the_policy_said_once(gen, policy, fz):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        a = ForceAugment(LeRobotLike(episodes(labels=False)), gen, copies=2, tactile_keys=[GEL], mode="online",
                         estimator=OffSensorEstimator(), estimated_reference=policy, progress=False)
        s = a.summary()
    said = [str(w.message) for w in caught if "force estimator reads" in str(w.message)]
    assert len(said) == 1 and f"estimated_reference={policy!r}" in said[0] and "[1.5, 0.0, 4.0] N" in said[0]
    contact = s["tactile_frames"] - s["no_contact"]
    if fz is None:  # kept real
        assert s["regenerated"] == s["clamped"] == 0 and s["skipped"] == contact > 0
        return
    assert s["skipped"] == 0 and s["regenerated"] + s["clamped"] == contact > 0
    plans = [r for r in a.plan() if r["status"] != "no_contact"]
    assert {tuple(r["reference_force"]) for r in plans} == {(0.0, 0.0, fz)}  # no shear, Fz by the policy
    assert all(r["target_force"][:2] == [0.0, 0.0] for r in plans)