"""Shared by the ForceAugment tests: a tiny randomly initialised ForceGenerator (the real class), so that they do
not depend on the shipped checkpoint's quality; synthetic episodes (flat background + a pressed blob on some
frames) written as HDF5 (``demo_data``); ``aug``, a ForceAugment over them."""

import hashlib

import numpy as np
import torch

import controltac_il.generator as gen_mod  # a broken import fails, never skips
from controltac_il.augment import ForceAugment
from controltac_il.datasets import Episode, EpisodeDataset, write_episode

H, W = 32, 32


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


def demo_data(tmp_path):
    """The tests' ``data`` fixture: make_folder's two episodes, read in chunks of 4."""
    root = make_folder(tmp_path / "demos")
    return EpisodeDataset(root, chunk_size=4, stats_path=tmp_path / "stats.json")


def same(x, y):
    """Exactly equal values (NaN equal to NaN) and types."""
    if isinstance(x, torch.Tensor):
        return x.dtype == y.dtype and x.shape == y.shape and bool(((x == y) | (x.isnan() & y.isnan())).all())
    return x == y


def checksums(root):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.iterdir())}


def aug(data, gen, tmp_path, name="cache", **kw):
    kw.setdefault("copies", 3)
    return ForceAugment(data, gen, cache_dir=tmp_path / name, progress=False, **kw)


def tiny_estimator():
    from controltac_il.estimators import EstimatorConfig, ForceEstimator
    torch.manual_seed(0)
    return ForceEstimator(EstimatorConfig(input_height=16, input_width=16, widths=(4, 4, 4, 4), hidden=8,
                                          force_mean=(0.0, 0.0, 4.0), force_std=(0.1, 0.1, 0.5)))
