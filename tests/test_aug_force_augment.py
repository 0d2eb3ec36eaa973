"""ForceAugment: exact augmentation semantics (one offset per trajectory, per-frame jitter, the trajectory plan,
provenance), datasets without labels, indices or backgrounds, and bad input. Its cache: test_aug_cache.py."""

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader, Dataset

from aug_fixtures import aug, demo_data, same, synthetic_episode, tiny_estimator, tiny_generator
from controltac_il.augment import STATUS, ForceAugment, copy_offset, frame_jitter
from controltac_il.augment.draws import requested_target, status_of
from controltac_il.datasets import EpisodeDataset, write_episode
from controltac_il.generator.forces import decide_targets

data = pytest.fixture(name="data")(demo_data)
gen = pytest.fixture(scope="module", name="gen")(lambda: tiny_generator())
JITTER = (-1.0, -0.5, 0.0, 0.5, 1.0)


def test_length_copy0_and_untouched_fields(data, gen, tmp_path):
    a = aug(data, gen, tmp_path)
    n = len(data)
    assert len(a) == 4 * n
    for i in range(len(a)):
        item, src = a[i], data[i % n]
        info = a.info(item)
        assert item["augment"].shape == (1, 10) and item["augment"].dtype == torch.float32
        assert int(info["copy"]) == i // n
        for k in ("observation.qpos", "action", "action_is_pad", "observation.images.wrist",
                  "observation.tactile_background.left"):
            assert torch.equal(item[k], src[k]), k  # byte-identical to the source
        status = int(info["status.observation.tactile.left"])
        if i < n:  # copy 0 is the real data
            assert status == STATUS["real"] and not bool(info["augmented"])
        in_contact = float(src["observation.force.left"][2]) >= 0.2
        if status in (STATUS["real"], STATUS["no_contact"], STATUS["skipped"]):
            assert torch.equal(item["observation.tactile.left"], src["observation.tactile.left"])
            assert torch.equal(item["observation.force.left"], src["observation.force.left"])
        else:
            assert in_contact and bool(info["augmented"])
            assert not torch.equal(item["observation.tactile.left"], src["observation.tactile.left"])
        if i >= n:
            assert (status == STATUS["no_contact"]) == (not in_contact)


def test_one_offset_per_episode_copy_across_shuffled_workers(data, gen, tmp_path):
    a = aug(data, gen, tmp_path)
    seen = {}
    for batch in DataLoader(a, batch_size=5, shuffle=True, num_workers=2,
                            generator=torch.Generator().manual_seed(3)):
        info = a.info(batch)
        for e, k, off, jit, st, ref, tgt in zip(
                batch["episode_index"].tolist(), info["copy"].tolist(), info["offset"].tolist(),
                info["jitter"].tolist(), info["status.observation.tactile.left"].tolist(),
                info["reference_force.observation.tactile.left"], info["target_force.observation.tactile.left"]):
            if k == 0:
                assert off == 0.0 and jit == 0.0
                continue
            seen.setdefault((e, k), set()).add(off)
            assert -3.0 <= off <= 10.0 and jit in JITTER
            if st in (STATUS["regenerated"], STATUS["clamped"]):
                assert 1.0 <= float(tgt[2]) <= 10.0 and float(tgt[0].abs()) <= 1 and float(tgt[1].abs()) <= 1
                if st == STATUS["regenerated"]:  # exactly reference + offset + jitter on Fz
                    assert float(tgt[2]) == pytest.approx(float(ref[2]) + off + jit, abs=1e-5)
    assert set(seen) == {(e, k) for e in (0, 1) for k in (1, 2, 3)}
    assert all(len(v) == 1 for v in seen.values())
    offsets = {v.pop() for v in seen.values()}
    assert len(offsets) == 6  # distinct draws per (episode, copy)


def test_draws_are_pure_functions_and_cover_the_jitter_set():
    a = [copy_offset(7, e, k, (-3.0, 10.0)) for e in range(20) for k in range(1, 5)]
    b = [copy_offset(7, e, k, (-3.0, 10.0)) for e in reversed(range(20)) for k in range(1, 5)]
    assert a == [x for e in range(20) for x in b[(19 - e) * 4:(20 - e) * 4]]
    assert min(a) >= -3 and max(a) <= 10 and np.std(a) > 2
    jit = [frame_jitter(7, 0, 1, t, JITTER) for t in range(200)]
    assert set(jit) == set(JITTER)
    assert copy_offset(8, 0, 1, (-3.0, 10.0)) != copy_offset(7, 0, 1, (-3.0, 10.0))
    assert copy_offset(0, 2, 2, (4.0, 4.0)) == 4.0


def resolve_target(reference, delta_fz, out_of_range):
    """What ForceAugment gets for one frame: the generator's decision on reference + (0, 0, offset + jitter)."""
    decision = decide_targets(requested_target(reference, delta_fz)[None], out_of_range,
                              reference_force=np.asarray(reference, np.float64)[None], reference_out_of_range="skip")
    return decision.target[0], status_of(decision, 0)


def test_resolve_target_clamps_or_skips():
    t, s = resolve_target(np.array([0.2, 0.0, 3.0]), 2.5, "clamp")
    assert s == STATUS["regenerated"] and t.tolist() == [0.2, 0.0, 5.5]
    t, s = resolve_target(np.array([0.2, 0.0, 3.0]), -2.5, "clamp")
    assert s == STATUS["clamped"] and t.tolist() == [0.2, 0.0, 1.0]
    t, s = resolve_target(np.array([0.2, 0.0, 9.0]), 3.0, "clamp")
    assert s == STATUS["clamped"] and t.tolist() == [0.2, 0.0, 10.0]
    # a reference the generator was not validated on (1.5 N shear) cannot be moved: kept real
    t, s = resolve_target(np.array([1.5, 0.0, 3.0]), 0.0, "clamp")
    assert s == STATUS["skipped"] and t.tolist() == [1.5, 0.0, 3.0]
    _, s = resolve_target(np.array([0.0, 0.0, 9.5]), 1.0, "skip")
    assert s == STATUS["skipped"]


def test_skip_keeps_real_frames_and_counts(data, gen, tmp_path):
    clamp = aug(data, gen, tmp_path, "c", copies=4, seed=1)
    skip = aug(data, gen, tmp_path, "s", copies=4, seed=1, out_of_range="skip")
    sc, ss = clamp.summary(), skip.summary()
    assert sc["tactile_frames"] == ss["tactile_frames"] == 4 * len(data)
    assert sc["skipped"] == 0 and ss["clamped"] == 0
    assert sc["clamped"] == ss["skipped"] > 0  # same draws: every clamped target is a skipped one
    assert sc["regenerated"] == ss["regenerated"] and sc["no_contact"] == ss["no_contact"] == 4 * 8
    assert ForceAugment(data, gen, copies=4, seed=1, mode="online", out_of_range="skip").summary() == ss
    for r in skip.provenance():
        if r["status"] == "skipped":
            assert r["row"] == -1 and not 1.0 <= r["target_force"][2] <= 10.0
    n = len(data)
    for i in range(n, len(skip)):
        item = skip[i]
        if int(skip.info(item)["status.observation.tactile.left"]) == STATUS["skipped"]:
            assert torch.equal(item["observation.tactile.left"], data[i % n]["observation.tactile.left"])
            assert not bool(skip.info(item)["augmented"])


def test_provenance_and_regenerated_force_label(data, gen, tmp_path):
    a = aug(data, gen, tmp_path, copies=2, steps=1)
    recs = a.provenance()
    assert len(recs) == 2 * len(data)
    r = next(r for r in recs if r["status"] == "regenerated")
    assert {"episode", "copy", "frame", "offset", "jitter", "reference_force", "target_force",
            "generator_hash", "steps", "noise_seed"} <= set(r)
    assert r["generator_hash"] == "tiny-a" and r["steps"] == 1
    e, k, t = r["episode"], r["copy"], r["frame"]
    idx = k * len(data) + (0 if e == 0 else 12) + t
    item = a[idx]
    assert (int(item["episode_index"]), int(item["frame_index"])) == (e, t)
    np.testing.assert_allclose(item["observation.force.left"].numpy(), r["target_force"], rtol=1e-6)
    np.testing.assert_allclose(a.info(item)["target_force.observation.tactile.left"].numpy(), r["target_force"], rtol=1e-6)
    assert float(a.info(item)["offset"]) == pytest.approx(r["offset"]) and float(a.info(item)["jitter"]) == r["jitter"]


def test_every_cached_frame_records_the_one_trajectory_plan(data, gen, tmp_path):
    from controltac_il.augment.draws import plan_frame

    a = aug(data, gen, tmp_path, copies=2, steps=1)
    for r in a.provenance():
        ref = None if r["reference_force"] is None else np.asarray(r["reference_force"])
        plan = plan_frame(a.config, r["episode"], r["copy"], r["frame"], 0, ref)
        assert (r["offset"], r["jitter"]) == (plan.offset, plan.jitter)
        if r["status"] == "regenerated":  # in range: the target asked is the one generated
            assert r["noise_seed"] == plan.noise_seed
            np.testing.assert_allclose(r["target_force"], plan.target)
        if r["status"] == "clamped":
            assert plan.target[2] > 10.0 or plan.target[2] < 1.0


class NaNLabel(Dataset):
    """An item dataset whose one contact frame carries a NaN Fz label (a LeRobot column, not an HDF5 file)."""

    def __init__(self, data, index):
        self.data, self.index = data, index

    def __len__(self):
        return len(self.data)

    def __getitem__(self, i):
        item = dict(self.data[i])
        if i == self.index:
            item["observation.force.left"] = item["observation.force.left"].clone()
            item["observation.force.left"][2] = float("nan")
        return item


def test_a_nan_force_label_is_refused_naming_the_label_never_read_as_no_contact(data, gen, tmp_path):
    with pytest.raises(ValueError, match=r"^observation.force.left: force label \[0.3\d*, -0.2\d*, nan\] is not finite"):
        aug(NaNLabel(data, 5), gen, tmp_path, copies=1, steps=1).build_cache()


class LeRobotLike(Dataset):
    """Map-style dataset of dict items, float [0, 1] CHW tactile, no background or force keys."""

    def __init__(self, episodes, with_index=True):
        self.rows = [(e, t) for e, ep in enumerate(episodes) for t in range(len(ep))]
        self.eps, self.with_index = episodes, with_index

    def __len__(self):
        return len(self.rows)

    def __getitem__(self, i):
        e, t = self.rows[i]
        ep = self.eps[e]
        item = {"observation.state": torch.from_numpy(ep.qpos[t]),
                "observation.images.tactile_left": torch.from_numpy(ep.tactile["left"][t]).permute(2, 0, 1).float() / 255,
                "observation.images.wrist": torch.from_numpy(ep.images["wrist"][t]).permute(2, 0, 1).float() / 255,
                "action": torch.from_numpy(ep.action[t])}
        if self.with_index:
            item.update(episode_index=torch.tensor(e), frame_index=torch.tensor(t))
        return item


def test_generic_dataset_with_estimator_and_estimated_background(gen, tmp_path):
    eps = [synthetic_episode(12, 0, range(4, 10), labels=False), synthetic_episode(6, 1, range(2, 5), labels=False)]
    ds = LeRobotLike(eps)
    with pytest.warns(UserWarning, match="background estimated"):
        a = ForceAugment(ds, gen, copies=2, cache_dir=tmp_path / "c", estimator=tiny_estimator(), progress=False)
    assert a.tactile_keys == ("observation.images.tactile_left",)
    s = a.summary()
    assert s["no_contact"] == 2 * 9 and s["regenerated"] + s["clamped"] + s["skipped"] == 2 * 9
    for i in range(len(a)):
        item, src = a[i], ds[i % len(ds)]
        assert item["observation.images.tactile_left"].dtype == torch.float32
        assert torch.equal(item["observation.images.wrist"], src["observation.images.wrist"])
        assert torch.equal(item["action"], src["action"]) and torch.equal(item["observation.state"], src["observation.state"])
        info = a.info(item)
        if int(info["status.observation.images.tactile_left"]) == STATUS["no_contact"]:
            assert torch.equal(item["observation.images.tactile_left"], src["observation.images.tactile_left"])
        elif i >= len(ds):
            ref = info["reference_force.observation.images.tactile_left"]
            assert torch.isfinite(ref).all()  # from the estimator


class Scaled(LeRobotLike):
    """LeRobotLike whose tactile images are float in [0, 255] (``scale`` 255) or hold a NaN (``scale`` NaN)."""

    def __init__(self, episodes, scale):
        super().__init__(episodes)
        self.scale = scale

    def __getitem__(self, i):
        item = super().__getitem__(i)
        image = item["observation.images.tactile_left"].clone()
        image[0, 0, 0] = float("nan") if self.scale != self.scale else image[0, 0, 0]
        item["observation.images.tactile_left"] = image * (1.0 if self.scale != self.scale else self.scale)
        return item


@pytest.mark.parametrize("scale, says", [(255.0, r"float image values must lie in \[0, 1\], got \[\d+, \d+\] \(images in \[0, 255\] are uint8\)"),
                                         (float("nan"), "the float image holds NaN or inf")])
def test_a_float_tactile_image_outside_0_1_is_refused_never_rounded_to_white(gen, tmp_path, scale, says):
    eps = [synthetic_episode(6, 0, range(1, 4), labels=False)]
    with pytest.raises(ValueError, match=f"^observation.images.tactile_left: {says}"):
        ForceAugment(Scaled(eps, scale), gen, copies=1, cache_dir=tmp_path / "c", estimator=tiny_estimator(),
                     progress=False)
    assert not (tmp_path / "c").exists()


class BFloat16(LeRobotLike):
    """LeRobotLike whose tactile images are bfloat16 tensors in [0, 1] (a dtype NumPy has none of)."""

    def __getitem__(self, i):
        item = super().__getitem__(i)
        item["observation.images.tactile_left"] = item["observation.images.tactile_left"].to(torch.bfloat16)
        return item


def test_a_bfloat16_tactile_image_is_augmented_and_written_back_in_bfloat16(gen, tmp_path):
    ds = BFloat16([synthetic_episode(6, 0, range(1, 4), labels=False)])
    with pytest.warns(UserWarning, match="background estimated"):
        a = aug(ds, gen, tmp_path, copies=1, steps=1, estimator=tiny_estimator())
    assert a.summary()["regenerated"] + a.summary()["clamped"] > 0
    for i in range(len(a)):
        item, src = a[i], ds[i % len(ds)]
        assert item["observation.images.tactile_left"].dtype == torch.bfloat16
        if int(a.info(item)["status.observation.images.tactile_left"]) == STATUS["no_contact"]:
            assert torch.equal(item["observation.images.tactile_left"], src["observation.images.tactile_left"])


def test_an_estimator_is_taken_as_a_folder_too_and_anything_else_is_refused(gen, tmp_path):
    """As generator= is: a checkpoint folder loads; a string that is no folder or another object is one line."""
    ds = LeRobotLike([synthetic_episode(6, 0, range(1, 4), labels=False)])
    saved = tiny_estimator().save(tmp_path / "est")
    with pytest.warns(UserWarning, match="background estimated"):
        a = ForceAugment(ds, gen, copies=1, mode="online", estimator=str(saved))
    from controltac_il.estimators import ForceEstimator

    assert a.estimator.checkpoint_hash == ForceEstimator.from_pretrained(saved).checkpoint_hash is not None
    with pytest.raises(ValueError, match=r"^estimator: expected a ForceEstimator, a checkpoint folder or a "
                                         r"calibration bundle, got dict$"):
        ForceAugment(ds, gen, copies=1, mode="online", estimator={"path": str(saved)})
    with pytest.raises((ValueError, OSError), match="nowhere"):
        ForceAugment(ds, gen, copies=1, mode="online", estimator=tmp_path / "nowhere")


def test_missing_estimator_is_a_clear_error(gen, tmp_path, monkeypatch):
    from controltac_il.estimators import ForceEstimator

    def unavailable(*a, **k):
        raise FileNotFoundError("no shipped checkpoint")

    monkeypatch.setattr(ForceEstimator, "from_pretrained", classmethod(lambda cls, *a, **k: unavailable()))
    ds = LeRobotLike([synthetic_episode(6, 0, range(1, 4), labels=False)])
    with pytest.raises(RuntimeError, match="no force labels.*force estimator"):
        ForceAugment(ds, gen, copies=1, cache_dir=tmp_path / "c", progress=False)


@pytest.mark.parametrize("kw, match", [
    (dict(copies=-1), "copies: expected an int >= 0"),
    (dict(offset_range=()), "offset_range"),
    (dict(offset_range=(5.0, 1.0)), "offset_range: inverted"),
    (dict(jitter=()), "jitter: expected a non-empty"),
    (dict(jitter="12"), "jitter: expected a non-empty"),  # never read as (1, 2)
    (dict(tactile_keys=["right"]), "tactile_keys: unknown tactile key 'right'"),
    (dict(tactile_keys=5), "tactile_keys: expected non-empty key names"),
    (dict(mode="lazy"), "mode"),
    (dict(out_of_range="wrap"), "out_of_range"),
    (dict(seed=-1), "seed"),
    (dict(build="later"), "build: expected one of"),
])
def test_bad_arguments(data, gen, tmp_path, kw, match):
    with pytest.raises(ValueError, match=match):
        ForceAugment(data, gen, cache_dir=tmp_path / "c", progress=False, **kw)


def test_an_index_copies_or_item_of_the_wrong_kind_is_named(data, gen, tmp_path):
    a = aug(data, gen, tmp_path, copies=1, steps=1)
    assert torch.equal(a[np.int64(3)]["action"], a[3]["action"])
    with pytest.raises(TypeError, match="^ForceAugment indices are ints, got str$"):
        a["3"]
    with pytest.raises(ValueError, match="^copies: expected None or an int >= 0, got 'x'$"):
        a.summary(copies="x")
    with pytest.raises(ValueError, match="^item: has no 'augment' record"):
        a.info({})


def test_a_dataset_or_generator_of_the_wrong_kind_is_named(data, gen, tmp_path):
    for dataset, generator, says in ((5, gen, "^dataset: expected a map-style dataset"),
                                     (data, 5, "^generator: expected a ForceGenerator")):
        with pytest.raises(ValueError, match=says):
            ForceAugment(dataset, generator, cache_dir=tmp_path / "c", progress=False)


def test_items_without_indices_or_background(gen, tmp_path):
    eps = [synthetic_episode(6, 0, range(1, 4), labels=False)]
    with pytest.raises(ValueError, match="episode_index"):
        ForceAugment(LeRobotLike(eps, with_index=False), gen, copies=1, cache_dir=tmp_path / "c")
    # online mode needs no background key: the background is estimated per episode, as the cache does
    with pytest.warns(UserWarning, match="background estimated"):
        on = ForceAugment(LeRobotLike(eps), gen, copies=1, mode="online", estimator=tiny_estimator(), progress=False)
    assert on[len(on) - 1]["observation.images.tactile_left"].dtype == torch.float32


class Opaque(Dataset):
    """The same items through a plain dataset (ForceAugment's generic read path)."""

    def __init__(self, ds):
        self.ds = ds

    def __len__(self):
        return len(self.ds)

    def __getitem__(self, i):
        return self.ds[i]


def test_subset_direct_reads_equal_generic_reads(data, gen, tmp_path):
    from controltac_il.datasets import EpisodeSubset

    sub = EpisodeSubset(data, list(range(12, 20)))  # episode 1 only, as the ACT trainer splits
    fast = aug(sub, gen, tmp_path, "fast", copies=2)
    slow = aug(Opaque(sub), gen, tmp_path, "slow", copies=2)
    assert fast._source is data and slow._source is None
    assert len(fast) == 3 * 8 and fast.summary() == slow.summary()
    assert fast.settings()["data"]["subset_sha256"]
    for i in range(len(fast)):
        x, y = fast[i], slow[i]
        assert x.keys() == y.keys()
        for k in x:
            assert same(x[k], y[k]), k


def test_zero_copies_is_the_real_data(data, gen, tmp_path):
    a = aug(data, gen, tmp_path, copies=0)
    assert len(a) == len(data) and a.chunk_list() == [] and a.summary()["tactile_frames"] == 0
    item = a[3]
    assert int(a.info(item)["copy"]) == 0 and not bool(a.info(item)["augmented"])
    assert torch.equal(item["observation.tactile.left"], data[3]["observation.tactile.left"])
    with pytest.raises(IndexError):
        a[len(a)]


def test_the_generator_alone_decides_out_of_range_targets(data, gen, tmp_path):
    """ForceAugment asks for reference + offset + jitter unclamped; what the generator did is recorded."""
    asked = []
    real = gen.generate_at

    def spy(residuals, reference_force, target_force, **kw):
        asked.append((np.array(reference_force), np.array(target_force), kw["out_of_range"]))
        return real(residuals, reference_force, target_force, **kw)

    gen.generate_at = spy
    try:
        a = aug(data, gen, tmp_path, copies=4, seed=1)
    finally:
        del gen.generate_at
    targets = np.concatenate([t for _, t, _ in asked])
    assert (targets[:, 2] > 10.0).any() and {p for *_, p in asked} == {"clamp"}  # unclamped on the way in
    recs = [r for r in a.provenance() if r["status"] != "no_contact"]
    assert len(recs) == len(targets)
    for r, want in zip(recs, targets):
        used = np.clip(want, [-1, -1, 1], [1, 1, 10])
        assert r["target_force"] == used.tolist()
        assert (r["status"] == "clamped") == bool((used != want).any())
        np.testing.assert_allclose(want[2], r["reference_force"][2] + r["offset"] + r["jitter"])


def test_reference_outside_the_validated_range_is_kept_real(tmp_path, gen):
    """A frame in contact whose reference force the generator was not validated on (0.5 N, 12 N, a 1.5 N
    shear) is not regenerated: kept real and counted as skipped, in cache and online mode alike."""
    ep = synthetic_episode(8, 0, range(2, 8))
    ep.force["left"][2] = (0.0, 0.0, 0.5)
    ep.force["left"][3] = (0.0, 0.0, 12.0)
    ep.force["left"][4] = (1.5, 0.0, 4.0)
    write_episode(tmp_path / "d" / "episode_0.hdf5", ep)
    ds = EpisodeDataset(tmp_path / "d", chunk_size=4, stats_path=tmp_path / "s.json")
    for a in (aug(ds, gen, tmp_path, copies=2, seed=3),
              ForceAugment(ds, gen, copies=2, seed=3, mode="online")):
        for i in range(len(ds), len(a)):
            item, src = a[i], ds[i % len(ds)]
            status = int(a.info(item)["status.observation.tactile.left"])
            if i % len(ds) in (2, 3, 4):
                assert status == STATUS["skipped"]
                assert torch.equal(item["observation.tactile.left"], src["observation.tactile.left"])
            elif i % len(ds) > 4:
                assert status in (STATUS["regenerated"], STATUS["clamped"])
    assert aug(ds, gen, tmp_path, copies=2, seed=3).summary()["skipped"] == 6


def test_target_range_spreads_each_copy_around_its_draw_and_online_matches_cache(data, gen, tmp_path):
    """target_range: offset = U[low, high] - the episode's median contact Fz, so each copy's median requested
    target is its draw (jitter is symmetric); online mode (episode tables) asks the generator the same."""
    from controltac_il.augment.draws import draw_stream

    a = aug(data, gen, tmp_path, copies=4, steps=1, target_range=(1.0, 10.0), out_of_range="skip")
    assert list(a.settings()["target_range"]) == [1.0, 10.0]  # a setting of the cache
    recs = [r for r in a.provenance() if r["reference_force"] is not None]
    for e in (0, 1):
        contact = [1.5 + 0.5 * (t % 10) for t in (range(4, 10) if e == 0 else range(2, 8))]
        median = float(np.median(contact))
        for k in range(1, 5):
            mine = [r for r in recs if (r["episode"], r["copy"]) == (e, k)]
            draw = float(draw_stream(0, e, k, 0).uniform(1.0, 10.0))
            offsets = {r["offset"] for r in mine}
            assert len(offsets) == 1 and offsets.pop() == pytest.approx(draw - median)
            asked = [r["reference_force"][2] + r["offset"] + r["jitter"] for r in mine]
            assert abs(np.median(asked) - draw) <= 1.5  # the references' own spread (1.5 N) plus jitter
    assert len({round(r["offset"], 6) for r in recs}) == 8  # one offset per (episode, copy)
    online = ForceAugment(data, gen, copies=4, steps=1, target_range=(1.0, 10.0), out_of_range="skip", mode="online")
    for i in (len(data) + 5, 3 * len(data) + 14, 4 * len(data) + 7):
        x, c = online[i], a[i]
        assert torch.equal(x["observation.tactile.left"], c["observation.tactile.left"])
        assert torch.equal(x["augment"], c["augment"])
    with pytest.raises(ValueError, match="target_range"):
        ForceAugment(data, gen, copies=1, target_range=(5.0, 2.0), mode="online")


def test_an_unlabelled_frames_contact_needs_its_area_and_a_blank_frame_never_has_one():
    """min_contact_area at its edges: a frame with exactly that share of contact pixels is in contact, one pixel
    fewer is not, and at min_contact_area 0 a blank frame is still no contact (no reference force to read)."""
    from controltac_il.augment.keys import KeyMap
    from controltac_il.augment.reference import ReferenceForces

    keys = KeyMap(("t",), {"t": None}, {"t": None}, {"t": None}, {})
    frames = np.full((3, 10, 20, 3), 127, np.uint8)  # 200 pixels; frame 1: 10 contact pixels, frame 2: 9
    frames[1, 0, :10] = frames[2, 0, :9] = 160
    assert ReferenceForces(keys, 0.5, 10 / 200).in_contact(frames, frames, None).tolist() == [False, True, False]
    assert ReferenceForces(keys, 0.5, 0.0).in_contact(frames, frames, None).tolist() == [False, True, True]


@pytest.mark.parametrize("mode, value", [("cache", 0), ("online", 255)])
def test_a_blank_camera_frame_in_contact_is_kept_real_and_never_asked_of_the_generator(tmp_path, gen, mode, value):
    """A dropped or overexposed frame (every value 0 or 255) inside a labelled grasp: its label says contact, but
    it has nothing to generate from, so every copy keeps it real (no_contact) with a warning; its neighbours
    are still regenerated."""

    ep = synthetic_episode(12, 0, range(4, 10))
    ep.tactile["left"][6] = value
    write_episode(tmp_path / "demos" / "episode_0.hdf5", ep)
    data = EpisodeDataset(tmp_path / "demos", chunk_size=1, stats_path=tmp_path / "stats.json")
    with pytest.warns(UserWarning, match="every value 0 or 255"):
        a = aug(data, gen, tmp_path, copies=2, mode=mode, out_of_range="clamp")
        items = [a[len(data) + t] for t in range(12)]
    status = [int(a.info(x)["status.observation.tactile.left"]) for x in items]
    assert status[6] == STATUS["no_contact"]
    assert torch.equal(items[6]["observation.tactile.left"], data[6]["observation.tactile.left"])
    assert all(s in (STATUS["regenerated"], STATUS["clamped"]) for s in status[4:6] + status[7:10])
