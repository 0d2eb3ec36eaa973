"""ForceAugment's stage-2 pose augmentation: off by default, one rigid move per copy, recorded, deterministic."""

import numpy as np
import pytest
import torch

from controltac_il.augment import ForceAugment
from controltac_il.augment.config import ForceAugmentConfig
from controltac_il.augment.draws import copy_pose_offset, moved_contact
from controltac_il.datasets import EpisodeDataset
from controltac_il.generator.adapter import PoseAdapter
from controltac_il.generator.config import PoseAdapterConfig
from aug_fixtures import make_folder, tiny_generator

MAX = (3.0, 2.0, 10.0)


def posed_generator():
    """The tiny generator with a pose adapter whose output layer is not zero (so a mask changes the frames)."""
    gen = tiny_generator()
    adapter = PoseAdapter(PoseAdapterConfig(base=gen.config, mask_channels=4, head_width=4), gen.denoiser)
    torch.manual_seed(3)
    torch.nn.init.normal_(adapter.out[-1].weight, std=0.5)
    gen.pose_adapter, gen.pose_adapter_hash = adapter.eval(), "tiny-pose"
    return gen


@pytest.fixture
def data(tmp_path):
    return EpisodeDataset(make_folder(tmp_path / "demos"), chunk_size=4, stats_path=tmp_path / "stats.json")


def test_pose_augmentation_is_off_by_default_and_leaves_settings_as_before(data, tmp_path):
    a = ForceAugment(data, tiny_generator(), copies=1, cache_dir=tmp_path / "c", progress=False)
    assert a.config.pose_offset is None and "pose_offset" not in a.settings()
    assert all(r["pose_offset"] is None for r in a.provenance())


def test_pose_offset_needs_the_adapter_and_valid_bounds(data):
    with pytest.raises(ValueError, match="pose_offset: needs a generator with the stage-2 pose adapter"):
        ForceAugment(data, tiny_generator(), copies=1, mode="online", pose_offset=MAX)
    for bad in ((1, 2), (1, -1, 0), (np.nan, 0, 0)):
        with pytest.raises(ValueError, match="pose_offset"):
            ForceAugmentConfig(pose_offset=bad)


def test_copy_pose_offset_is_a_pure_bounded_draw():
    draws = np.array([copy_pose_offset(0, e, k, MAX) for e in range(20) for k in range(5)])
    assert np.array_equal(draws, [copy_pose_offset(0, e, k, MAX) for e in range(20) for k in range(5)])
    assert (np.abs(draws) <= [3.0, 2.0, np.radians(10.0)]).all() and len(np.unique(draws[:, 0])) == 100
    assert copy_pose_offset(0, 1, 1, None) is None


def test_moved_contact_moves_the_contact_pixels_or_gives_none():
    res = np.full((32, 32, 3), 127, np.uint8)
    assert moved_contact(res, (1.0, 0.0, 0.0)) is None  # no contact pixel
    res[8:16, 8:16] = 200
    m = moved_contact(res, (4.0, 2.0, 0.0))
    assert m.sum() == 64 and np.argwhere(m).min(0).tolist() == [10, 12]
    assert moved_contact(res, (100.0, 0.0, 0.0)) is None  # moved off the pad
    assert moved_contact(res, None) is None


def test_each_copy_moves_its_contacts_by_its_own_recorded_offset(data, tmp_path):
    gen = posed_generator()
    posed = ForceAugment(data, gen, copies=2, cache_dir=tmp_path / "p", progress=False, pose_offset=MAX)
    plain = ForceAugment(data, gen, copies=2, cache_dir=tmp_path / "f", progress=False)
    assert posed.cache_dir != plain.cache_dir and posed.settings()["pose_adapter_hash"] == "tiny-pose"
    moved = [r for r in posed.provenance() if r["pose_offset"] is not None]
    assert moved and all(r["status"] in ("regenerated", "clamped") for r in moved)
    for r in moved:
        assert r["pose_offset"] == list(copy_pose_offset(0, r["episode"], r["copy"], MAX))
    key = lambda r: (r["episode"], r["copy"], r["frame"], r["key"])  # noqa: E731
    assert {key(r): r["pose_offset"] for r in posed.plan()} == {key(r): r["pose_offset"] for r in posed.provenance()}
    i = next(k for k in range(len(posed)) if k >= len(data) and posed.info(posed[k])["augmented"])
    assert not torch.equal(posed[i]["observation.tactile.left"], plain[i]["observation.tactile.left"])
    online = ForceAugment(data, gen, copies=2, mode="online", pose_offset=MAX)
    diff = (online[i]["observation.tactile.left"].int() - posed[i]["observation.tactile.left"].int()).abs().max()
    assert int(diff) <= 1  # online equals the cache up to batch rounding
