"""ForceAugment's cache: deterministic builds, interrupted and sharded builds equal to a clean one, the source
never touched, and a cache used only when it provably matches (manifest, chunks, settings)."""

import json
import os
import pickle

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from aug_fixtures import H, W, aug, checksums, demo_data, same, synthetic_episode, tiny_generator
from files import tree_bytes
from controltac_il.augment import ForceAugment, StaleCacheError
from controltac_il.datasets import EpisodeDataset, write_episode

data = pytest.fixture(name="data")(demo_data)
gen = pytest.fixture(scope="module", name="gen")(lambda: tiny_generator())


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
from aug_fixtures import tiny_generator
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


def test_settings_the_generator_cannot_run_are_refused_before_the_cache_folder_is_made(data, gen, tmp_path):
    """A stale-looking manifest must never block the corrected run: DDIM steps beyond the generator's training
    steps are refused before anything is written."""
    with pytest.raises(ValueError, match=r"^steps: expected DDIM steps in \[1, \d+\] \(the generator's training steps\)"):
        aug(data, gen, tmp_path, steps=100_000)
    assert not (tmp_path / "cache").exists()
    assert aug(data, gen, tmp_path, steps=1).summary()["tactile_frames"] > 0


def test_the_frames_digest_is_the_same_for_the_same_frames_from_a_source_written_at_another_time(data, gen, tmp_path):
    """Two machines that collect the same demos write them at other times: the manifests differ (the settings'
    digest covers the files' modification times), the frames digest does not; one changed pixel changes it."""
    from controltac_il.augment.provenance import MANIFEST, frames_digest

    first = aug(data, gen, tmp_path, "first", copies=1)
    for path in data.root.iterdir():
        os.utime(path, ns=(path.stat().st_atime_ns, path.stat().st_mtime_ns + 10**9))
    again = EpisodeDataset(data.root, chunk_size=4, stats_path=tmp_path / "stats.json")
    second = aug(again, gen, tmp_path, "second", copies=1)
    assert (first.cache_dir / MANIFEST).read_bytes() != (second.cache_dir / MANIFEST).read_bytes()
    assert frames_digest(first.cache_dir) == frames_digest(second.cache_dir)
    frame = sorted((second.cache_dir / "chunks").glob("*/*.npy"))[0]
    pixels = np.load(frame)
    pixels.flat[0] ^= 1
    np.save(frame, pixels)
    assert frames_digest(first.cache_dir) != frames_digest(second.cache_dir)
