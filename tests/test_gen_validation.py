"""The generator's own validation split: whole held-out objects, never trained on, and the shipped weights are
those of the best periodic save on them."""

import json

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from controltac_il.generator.forces import VALIDATED_RANGE
from controltac_il.generator.training.cli import main
from controltac_il.generator.training.data import load_pair_data
from controltac_il.generator.training.validation import hold_out_objects
from controltac_il.tactile import TRAIN_OBJECTS, SensorSpec
from controltac_il.tactile.dataset import load_dataset, write_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("genval") / "data"
    write_dataset(root, TRAIN_OBJECTS[:3], poses_per_object=2, forces_per_pose=3, seed=0,
                  spec=SensorSpec.gelsight_mini().scaled(60, 80), progress=False)
    return root


def test_held_out_objects_are_never_trained_on_and_pairs_stay_within_their_poses(dataset):
    data = load_pair_data(dataset, (64, 80), no_contact_frames=2, progress=False)
    train, split = hold_out_objects(data, 1, seed=4, pairs=10)
    assert len(split.objects) == 1 and split.objects[0] in TRAIN_OBJECTS[:3]
    objects = [r.object for r in load_dataset(dataset).records]
    held = {i for i, o in enumerate(objects) if o == split.objects[0]}
    assert len(held) == 6 and split.objects[0] not in train.group_objects and len(train.groups) == 4
    assert not held & set(train.images.tolist())  # no pair and no autoencoder crop draws from them
    assert set(train.images.tolist()) == set(range(len(data.residuals))) - held
    pose = {int(i): g for g, idx in enumerate(data.groups) for i in idx}
    assert all(int(r) in held and pose[int(r)] == pose[int(t)] and r != t for r, t in zip(split.ref, split.tgt))
    np.testing.assert_allclose(split.delta, data.forces[split.tgt] - data.forces[split.ref])
    assert not VALIDATED_RANGE.outside(data.forces[np.r_[split.ref, split.tgt]]).any()
    again = hold_out_objects(data, 1, seed=4, pairs=10)[1]
    assert len(hold_out_objects(data, 1, seed=4, pairs=10_000)[1].ref) <= 2 * 3 * 2
    assert again.objects == split.objects and (again.ref == split.ref).all() and (again.tgt == split.tgt).all()
    assert hold_out_objects(data, 0, seed=4) == (data, None)
    with pytest.raises(ValueError, match="val_objects=3"):
        hold_out_objects(data, 3, seed=4)


def test_the_shipped_weights_are_the_best_validation_step(dataset, tmp_path):
    run = tmp_path / "run"
    main(["stage1", "--data", str(dataset), "--out", str(run), "--image-size", "64", "80", "--ae-steps", "2", "--dit-steps", "4",
          "--ae-batch", "2", "--dit-batch", "4", "--ae-crop", "32", "40", "--checkpoint-every", "1", "--warmup-steps", "1",
          "--no-contact-frames", "2", "--threads", "1", "--dit-lr", "0.05", "--val-objects", "1", "--default-steps", "1"])
    card = json.loads((run / "final" / "model_card.json").read_text())
    val = card["denoiser"]["validation"]
    assert [h["step"] for h in val["history"]] == [1, 2, 3, 4] and len(val["objects"]) == 1
    assert 2 <= val["pairs"] <= 2 * 3 * 2  # capped at the held-out object's distinct pairs (2 poses x 3 forces)
    ratios = [h["ratio_to_copy"] for h in val["history"]]
    assert all(np.isfinite(ratios)) and val["best_step"] == 1 + int(np.argmin(ratios))
    assert card["data"]["pose_groups"] == 4  # the held-out object's two poses are not training data
    best = {k[len("best."):]: v for k, v in load_file(str(run / "denoiser_best.safetensors")).items()}
    shipped = load_file(str(run / "final" / "denoiser.safetensors"))
    assert shipped.keys() == best.keys()
    assert all(torch.equal(shipped[k], best[k].to(torch.float16)) for k in best)
    state = load_file(str(run / "denoiser_state.safetensors"))
    last = {k[len("ema."):]: v for k, v in state.items() if k.startswith("ema.")}
    if val["best_step"] != 4:  # then the last step's EMA weights are not what ships
        assert not all(torch.equal(last[k], best[k]) for k in best)
