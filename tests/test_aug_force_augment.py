"""ForceAugment: exact augmentation semantics, determinism, cache build/resume/shards, bad input.

A tiny randomly initialised ForceGenerator (the real class) keeps this independent of the shipped
checkpoint's quality; the episodes are synthetic (flat background + a pressed blob on some frames).
"""

import hashlib
import json
import os
import pickle

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader, Dataset

import controltac_il.generator as gen_mod  # noqa: E402 (a broken import fails, never skips)
from controltac_il.augment import (  # noqa: E402
    STATUS, ForceAugment, StaleCacheError, copy_offset, frame_jitter,
)
from controltac_il.augment.draws import requested_target, status_of  # noqa: E402
from controltac_il.datasets import Episode, EpisodeDataset, write_episode  # noqa: E402
from controltac_il.generator.forces import decide_targets  # noqa: E402

H, W = 32, 32
JITTER = (-1.0, -0.5, 0.0, 0.5, 1.0)


def tiny_generator(hash_="tiny-a", seed=0):
    torch.manual_seed(seed)
    cfg = gen_mod.GeneratorConfig(
        autoencoder=gen_mod.AutoencoderConfig(image_size=(H, W), channels=(8, 8), stem_channels=4, latent_channels=4),
        dit=gen_mod.DiTConfig(in_channels=4, hidden_size=16, depth=1, num_heads=2),
        diffusion=gen_mod.DiffusionConfig(default_steps=2),
    )
    from controltac_il.generator.autoencoder import TactileAutoencoder
    from controltac_il.generator.dit import ForceDiT
    return gen_mod.ForceGenerator(cfg, TactileAutoencoder(cfg.autoencoder), ForceDiT(cfg.dit), checkpoint_hash=hash_)


def synthetic_episode(T, seed, contact, labels=True, background=True):
    rng = np.random.default_rng(seed)
    bg = np.full((H, W, 3), 110, np.uint8)
    tactile = np.repeat(bg[None], T, 0).astype(np.int16) + rng.integers(-1, 2, (T, H, W, 3))
    force = np.zeros((T, 3), np.float32)
    for t in contact:
        tactile[t, 8:24, 8:24] += 50
        force[t] = (0.3, -0.2, 1.5 + 0.5 * (t % 10))
    return Episode(
        qpos=rng.normal(size=(T, 4)).astype(np.float32),
        action=rng.normal(size=(T, 5)).astype(np.float32),
        images={"wrist": rng.integers(0, 256, (T, 8, 8, 3), dtype=np.uint8)},
        tactile={"left": tactile.clip(0, 255).astype(np.uint8)},
        tactile_background={"left": bg} if background else {},
        force={"left": force} if labels else {},
        sim=True,
    )


def make_folder(root, labels=True, background=True):
    for i, (T, contact) in enumerate(((12, range(4, 10)), (8, range(2, 8)))):
        write_episode(root / f"episode_{i}.hdf5", synthetic_episode(T, i, contact, labels, background))
    return root


@pytest.fixture
def data(tmp_path):
    root = make_folder(tmp_path / "demos")
    return EpisodeDataset(root, chunk_size=4, stats_path=tmp_path / "stats.json")


@pytest.fixture(scope="module")
def gen():
    return tiny_generator()


def same(x, y):
    """Exactly equal values (NaN equal to NaN) and types."""
    if isinstance(x, torch.Tensor):
        return x.dtype == y.dtype and x.shape == y.shape and bool(((x == y) | (x.isnan() & y.isnan())).all())
    return x == y


def checksums(root):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.iterdir())}


def tree_bytes(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def aug(data, gen, tmp_path, name="cache", **kw):
    kw.setdefault("copies", 3)
    return ForceAugment(data, gen, cache_dir=tmp_path / name, progress=False, **kw)


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


def test_determinism_two_builds_and_online_matches_cache(data, gen, tmp_path):
    a = aug(data, gen, tmp_path, "one")
    b = aug(data, tiny_generator(), tmp_path, "two")
    assert tree_bytes(a.cache_dir) == tree_bytes(b.cache_dir)
    on1 = ForceAugment(data, gen, copies=3, mode="online")
    on2 = ForceAugment(data, tiny_generator(), copies=3, mode="online")
    for i in (len(data) + 5, 2 * len(data) + 13, 3 * len(data) + 3):
        x, y, c = on1[i], on2[i], a[i]
        for k in x:
            assert same(x[k], y[k]), k
        # same draws, same noise: online equals the cache up to batch-size rounding (<= 1 grey level)
        diff = (x["observation.tactile.left"].int() - c["observation.tactile.left"].int()).abs().max()
        assert int(diff) <= 1
        assert float(on1.info(x)["offset"]) == float(a.info(c)["offset"])


def test_interrupted_build_resumes_to_the_clean_result(data, gen, tmp_path):
    clean = aug(data, gen, tmp_path, "clean")
    with pytest.raises(ValueError, match="chunk\\(s\\) missing"):
        aug(data, gen, tmp_path, "part", build="require")
    # 1) a build stopped after two chunks, 2) a build killed inside a chunk (the generator fails)
    first = aug(data, gen, tmp_path, "part", build="manual")
    assert first.build_cache(progress=False, stop_after=2)["chunks"] == 2

    class Crash(Exception):
        pass

    calls = {"n": 0}
    real = gen.generate_at

    def crashing(*args, **kw):
        calls["n"] += 1
        if calls["n"] == 2:
            raise Crash()
        return real(*args, **kw)

    gen.generate_at = crashing
    try:
        with pytest.raises(Crash):
            first.build_cache(progress=False)
    finally:
        del gen.generate_at
    assert not any(p.name.endswith(".tmp") for p in (tmp_path / "part" / "chunks").iterdir())
    assert len(first.missing_chunks()) == 3
    resumed = aug(data, gen, tmp_path, "part")
    assert tree_bytes(resumed.cache_dir) == tree_bytes(clean.cache_dir)


def test_sharded_build_equals_single_build(data, gen, tmp_path):
    clean = aug(data, gen, tmp_path, "clean")
    shard = aug(data, gen, tmp_path, "sharded", build="manual")
    done = [shard.build_cache(rank=r, world_size=3, progress=False)["chunks"] for r in (2, 0, 1)]
    assert sum(done) == 6 and all(d == 2 for d in done)
    assert tree_bytes(shard.cache_dir) == tree_bytes(clean.cache_dir)
    with pytest.raises(ValueError, match="rank"):
        shard.build_cache(rank=3, world_size=3, progress=False)


def test_source_files_unchanged(data, gen, tmp_path):
    before = checksums(data.root)
    a = aug(data, gen, tmp_path)
    list(DataLoader(a, batch_size=8, num_workers=2))
    ForceAugment(data, gen, copies=1, mode="online")[len(data) + 6]
    assert checksums(data.root) == before
    assert not (data.root / "cache").exists() and sorted(os.listdir(data.root)) == ["episode_0.hdf5", "episode_1.hdf5"]


def test_stale_cache_is_never_reused(data, gen, tmp_path):
    aug(data, gen, tmp_path)
    with pytest.raises(StaleCacheError, match="generator_hash: cache has 'tiny-a', now 'tiny-b'"):
        aug(data, tiny_generator("tiny-b", seed=1), tmp_path)
    with pytest.raises(StaleCacheError, match="copies"):
        aug(data, gen, tmp_path, copies=2)
    with pytest.raises(StaleCacheError, match="seed"):
        aug(data, gen, tmp_path, seed=5)
    with pytest.raises(StaleCacheError, match="steps"):
        aug(data, gen, tmp_path, steps=1)
    with pytest.raises(StaleCacheError, match="jitter"):
        aug(data, gen, tmp_path, jitter=(0.0,))
    write_episode(data.root / "episode_2.hdf5", synthetic_episode(5, 2, range(1, 3)))
    grown = EpisodeDataset(data.root, chunk_size=4, stats_path=tmp_path / "stats2.json")
    with pytest.raises(StaleCacheError, match="data"):
        aug(grown, gen, tmp_path)


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


def tiny_estimator():
    from controltac_il.estimators import EstimatorConfig, ForceEstimator
    torch.manual_seed(0)
    return ForceEstimator(EstimatorConfig(input_height=16, input_width=16, widths=(4, 4, 4, 4), hidden=8,
                                          force_mean=(0.0, 0.0, 4.0), force_std=(0.1, 0.1, 0.5)))


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
    (dict(tactile_keys=["right"]), "tactile_keys: unknown tactile key 'right'"),
    (dict(mode="lazy"), "mode"),
    (dict(out_of_range="wrap"), "out_of_range"),
    (dict(seed=-1), "seed"),
    (dict(build="later"), "build: expected one of"),
])
def test_bad_arguments(data, gen, tmp_path, kw, match):
    with pytest.raises(ValueError, match=match):
        ForceAugment(data, gen, cache_dir=tmp_path / "c", progress=False, **kw)


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


# -- a cache is used only when it provably matches --------------------------------------

def test_cache_without_its_manifest_is_refused(data, gen, tmp_path):
    a = aug(data, gen, tmp_path, copies=2)
    (a.cache_dir / "manifest.json").unlink()
    before = tree_bytes(a.cache_dir)
    for kw in (dict(seed=7), dict()):  # other settings, or even the same ones: nothing proves it
        with pytest.raises(StaleCacheError, match=f"{a.cache_dir}.*no manifest.json"):
            aug(data, gen, tmp_path, copies=2, **kw)
    with pytest.raises(StaleCacheError, match="no manifest.json"):
        aug(data, gen, tmp_path, copies=2, build="manual").build_cache(progress=False)
    assert tree_bytes(a.cache_dir) == before  # not re-stamped
    own = tmp_path / "mine"
    own.mkdir()
    (own / "notes.txt").write_text("the user's")
    with pytest.raises(StaleCacheError, match="mine.*not a ForceAugment cache"):
        aug(data, gen, tmp_path, "mine", copies=2)
    assert sorted(p.name for p in own.iterdir()) == ["notes.txt"]
    corrupt = aug(data, gen, tmp_path, "corrupt", copies=1)
    (corrupt.cache_dir / "manifest.json").write_text("{not json")
    with pytest.raises(StaleCacheError, match="manifest.json"):
        aug(data, gen, tmp_path, "corrupt", copies=1)


def tamper_chunk(cache_dir, edit, name="e000001_k002"):
    path = cache_dir / "chunks" / name / "provenance.json"
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))


@pytest.mark.parametrize("edit, match", [
    (lambda d: [r.update(generator_hash="0123456789abcdef") for r in d["frames"]], "generator_hash"),
    (lambda d: d["frames"][0].update(generator_hash="other"), "generator_hash"),
    (lambda d: [r.update(steps=50) for r in d["frames"]], "steps"),
    (lambda d: d.update(settings_sha256="0" * 16), "settings"),
    (lambda d: d.pop("settings_sha256"), "settings"),
    (lambda d: d.update(copy=1), "copy"),
    (lambda d: d["frames"].pop(), "frame"),
])
def test_chunk_that_differs_from_the_manifest_is_refused(data, gen, tmp_path, edit, match):
    a = aug(data, gen, tmp_path, copies=2)
    tamper_chunk(a.cache_dir, edit)
    with pytest.raises(StaleCacheError, match=f"e000001_k002.*{match}"):
        aug(data, gen, tmp_path, copies=2)
    worker = pickle.loads(pickle.dumps(a))  # as a DataLoader worker gets it: chunks not opened yet
    with pytest.raises(StaleCacheError, match=f"e000001_k002.*{match}"):
        worker[2 * len(data) + 12 + 3]  # refused where the chunk is read, too


def test_chunk_copied_from_a_cache_of_other_settings_is_refused(data, gen, tmp_path):
    import shutil

    a = aug(data, gen, tmp_path, "a", copies=2)
    b = aug(data, gen, tmp_path, "b", copies=2, seed=5)
    target = a.cache_dir / "chunks" / "e000000_k001"
    shutil.rmtree(target)
    shutil.copytree(b.cache_dir / "chunks" / "e000000_k001", target)
    with pytest.raises(StaleCacheError, match="e000000_k001.*settings"):
        aug(data, gen, tmp_path, "a", copies=2)


def test_truncated_or_swapped_chunk_images_are_refused(data, gen, tmp_path):
    a = aug(data, gen, tmp_path, copies=2)
    f = a.cache_dir / "chunks" / "e000000_k001" / "tactile_0.npy"
    f.write_bytes(f.read_bytes()[:-10])
    with pytest.raises(StaleCacheError, match="e000000_k001.*tactile_0.npy"):
        aug(data, gen, tmp_path, copies=2)
    b = aug(data, gen, tmp_path, "b", copies=2)
    np.save(b.cache_dir / "chunks" / "e000000_k001" / "tactile_0.npy", np.zeros((1, H, W, 3), np.uint8))
    with pytest.raises(StaleCacheError, match="e000000_k001.*tactile_0.npy"):
        aug(data, gen, tmp_path, "b", copies=2)


KILL_INSIDE_A_CHUNK = """
import os, signal, sys
sys.path.insert(0, sys.argv[1])
import numpy as np
from pathlib import Path
from controltac_il.augment import ForceAugment, writer
from controltac_il.datasets import EpisodeDataset
from test_aug_force_augment import tiny_generator
saved = {"n": 0}
real_save = np.save
def save(path, arr, *a, **k):
    real_save(path, arr, *a, **k)
    saved["n"] += 1
    if saved["n"] == 3:  # inside the third chunk's temporary folder
        os.kill(os.getpid(), signal.SIG%s)
writer.np.save = save
data = EpisodeDataset(sys.argv[2], chunk_size=4, stats_path=Path(sys.argv[3]) / "stats_k.json")
ForceAugment(data, tiny_generator(), copies=3, cache_dir=Path(sys.argv[3]) / "part", progress=False)
"""


@pytest.mark.parametrize("sig", ["KILL", pytest.param("INT", marks=pytest.mark.slow)])  # INT: -m slow (the suite's time)
def test_killed_build_leaves_nothing_and_resumes_to_the_clean_result(data, gen, tmp_path, sig):
    import subprocess
    import sys

    clean = aug(data, gen, tmp_path, "clean")
    tests = os.path.dirname(__file__)
    res = subprocess.run([sys.executable, "-c", KILL_INSIDE_A_CHUNK % sig, tests, str(data.root), str(tmp_path)],
                         cwd=os.path.dirname(tests), capture_output=True, text=True,
                         env={**os.environ, "OMP_NUM_THREADS": str(torch.get_num_threads())})  # the same numerics
    assert res.returncode != 0, res.stdout
    chunks = tmp_path / "part" / "chunks"
    assert len([p for p in chunks.iterdir() if not p.name.startswith(".")]) == 2
    left = [p for p in chunks.iterdir() if p.name.startswith(".")]
    assert len(left) == (1 if sig == "KILL" else 0), left  # SIGINT cleans up itself; SIGKILL cannot
    resumed = aug(data, gen, tmp_path, "part")
    assert sorted(p.name for p in chunks.iterdir() if p.name.startswith(".")) == []  # leftovers cleaned
    assert tree_bytes(resumed.cache_dir) == tree_bytes(clean.cache_dir)


def test_cache_files_get_the_umask_permissions(data, gen, tmp_path):
    old = os.umask(0o022)
    try:
        a = aug(data, gen, tmp_path, copies=1)
    finally:
        os.umask(old)
    modes = {oct(p.stat().st_mode & 0o777) for p in [a.cache_dir, *a.cache_dir.rglob("*")] if p.is_dir()}
    assert modes == {"0o755"}
    modes = {oct(p.stat().st_mode & 0o777) for p in a.cache_dir.rglob("*") if p.is_file()}
    assert modes == {"0o644"}


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
