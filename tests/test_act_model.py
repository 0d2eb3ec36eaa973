"""ACT config, network and checkpoints: shapes, gradients, loss semantics, round trip, bad input."""

import json

import numpy as np
import pytest
import torch
from torch.utils.data import default_collate

from act_fixtures import SyntheticACTDataset, tiny_config
from policies.act import ACT, ACTConfig, ACTPolicy, CheckpointError, load_checkpoint, save_checkpoint
from policies.act.backbone import ResNet18, SmallCNN


def _batch(n=4, seed=0):
    ds = SyntheticACTDataset(n=n, seed=seed)
    return default_collate([ds[i] for i in range(n)]), ds


def test_presets_follow_paper_defaults():
    gpu, cpu = ACTConfig.from_preset("gpu"), ACTConfig.from_preset("cpu")
    assert (gpu.backbone, gpu.dim_model) == ("resnet18", 512)
    for c in (gpu, cpu):
        assert (c.chunk_size, c.kl_weight, c.n_decoder_layers, c.temporal_ensemble_coeff) == (20, 10.0, 1, 0.01)
    assert cpu.backbone == "small_cnn" and cpu.dim_model < gpu.dim_model
    assert ACTConfig.from_preset("cpu", chunk_size=10).chunk_size == 10


@pytest.mark.parametrize("kwargs, field", [
    (dict(chunk_size=0), "chunk_size"), (dict(dim_model=30, n_heads=4), "dim_model"),
    (dict(backbone="vgg"), "backbone"), (dict(camera_size=(0, 5)), "camera_size"),
    (dict(camera_names=(), tactile_names=()), "image stream"), (dict(camera_names=("a.b",)), "camera_names"),
    (dict(kl_weight=-1.0), "kl_weight"), (dict(dropout=1.0), "dropout"), (dict(tactile_names=("l", "l")), "duplicates"),
])
def test_config_rejects_bad_values(kwargs, field):
    with pytest.raises(ValueError, match=field):
        ACTConfig(**kwargs)


def test_an_unknown_preset_is_refused_by_name():
    with pytest.raises(ValueError, match="preset"):
        ACTConfig.from_preset("tpu")


def test_backbone_feature_shapes():
    x = torch.randn(2, 3, 64, 96)
    assert SmallCNN()(x).shape == (2, 128, 4, 6)
    assert ResNet18()(x).shape == (2, 512, 2, 3)
    assert sum(p.numel() for p in ResNet18().parameters()) == pytest.approx(11.17e6, rel=0.01)


def test_forward_backward_shapes_and_gradients():
    torch.manual_seed(0)
    cfg = tiny_config()
    model = ACT(cfg)
    batch, ds = _batch()
    model.set_stats(ds.stats())
    out = model(batch)
    assert set(out) == {"loss", "l1", "kl"} and all(v.ndim == 0 for v in out.values())
    assert torch.allclose(out["loss"], out["l1"] + cfg.kl_weight * out["kl"])
    out["loss"].backward()
    no_grad = [n for n, p in model.named_parameters() if p.grad is None or not torch.isfinite(p.grad).all()]
    assert not no_grad, f"parameters without a finite gradient: {no_grad}"
    model.eval()
    pred = model.predict(batch)
    assert pred.shape == (4, cfg.chunk_size, cfg.action_dim) and pred.dtype == torch.float32


def test_padded_actions_do_not_change_the_l1():
    torch.manual_seed(0)
    model = ACT(tiny_config()).eval()
    batch, _ = _batch()
    batch["action_is_pad"][:, -2:] = True
    torch.manual_seed(1)
    a = model(batch)["l1"]
    batch["action"][:, -2:] += 100.0  # garbage after the episode end must be ignored by the L1 ...
    torch.manual_seed(1)
    b = model(batch)["l1"]
    assert torch.allclose(a, b)
    batch["action"][:, 0] += 1.0  # ... while a real action error counts
    torch.manual_seed(1)
    assert model(batch)["l1"] > b


def test_prediction_uses_the_latent_prior_mean_and_the_stats():
    torch.manual_seed(0)
    model = ACT(tiny_config()).eval()
    batch, ds = _batch()
    p1 = model.predict(batch)
    assert torch.equal(p1, model.predict(batch))  # z = 0: deterministic
    identity = {"mean": [0.0] * 5, "std": [1.0] * 5}
    model.set_stats({"qpos": identity, "action": {"mean": [10.0] * 5, "std": [1.0] * 5}})
    p2 = model.predict(batch)
    assert torch.allclose(p2 - 10.0, p1, atol=1e-5)  # outputs are denormalised with the action stats


def test_bad_batches_are_named():
    model = ACT(tiny_config())
    batch, _ = _batch()
    del batch["observation.images.wrist"]
    with pytest.raises(ValueError, match="observation.images.wrist"):
        model(batch)
    batch, _ = _batch()
    batch["action"] = batch["action"][..., :4]
    with pytest.raises(ValueError, match="action must be"):
        model(batch)
    batch, _ = _batch()
    batch["observation.qpos"] = batch["observation.qpos"][:, :3]
    with pytest.raises(ValueError, match="qpos"):
        model.predict(batch)
    # inf would zero that input; 1e-30 (or a denormal) overflows the normalised input and every action is NaN
    for bad in ([0] * 5, [1, 1, float("inf"), 1, 1], [1, float("nan"), 1, 1, 1], [1, 1e-30, 1, 1, 1], [9e-7] * 5):
        with pytest.raises(ValueError, match=r"^normalisation stats 'qpos': mean must be finite and std finite and "
                                             r">= 1e-06 \(a smaller one overflows the normalised input\)$"):
            model.set_stats({"qpos": {"mean": [0] * 5, "std": bad}, "action": {"mean": [0] * 5, "std": [1] * 5}})
    with pytest.raises(ValueError, match="expected 5"):
        model.set_stats({"qpos": {"mean": [0] * 4, "std": [1] * 4}, "action": {"mean": [0] * 5, "std": [1] * 5}})


def _observation(ds, i=0, with_background=True):
    item = ds[i]
    obs = {"qpos": item["observation.qpos"].numpy()}
    for k, v in item.items():
        for group in ("images", "tactile", "tactile_background"):
            if k.startswith(f"observation.{group}."):
                if group == "tactile_background" and not with_background:
                    continue
                obs[f"{group}/{k.rsplit('.', 1)[1]}"] = v.numpy().transpose(1, 2, 0).copy()
    return obs


def test_checkpoint_round_trip(tmp_path):
    torch.manual_seed(0)
    model = ACT(tiny_config())
    batch, ds = _batch()
    model.set_stats(ds.stats())
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
    model(batch)["loss"].backward()
    opt.step()
    model.eval()
    bg = {s: ds.background.numpy().transpose(1, 2, 0).copy() for s in ("left", "right")}
    save_checkpoint(tmp_path / "ckpt", model, backgrounds=bg, meta={"step": 1}, optimizer=opt)
    assert sorted(p.name for p in (tmp_path / "ckpt").iterdir()) == [
        "config.json", "model.safetensors", "model_card.json", "optimizer.json", "optimizer.safetensors", "stats.json",
        "tactile_background.safetensors"]
    loaded, backgrounds, meta = load_checkpoint(tmp_path / "ckpt")
    assert meta == {"step": 1} and loaded.config == model.config
    for device, says in (("gpu", "expected a torch device"), (f"cuda:{torch.cuda.device_count()}", "CUDA device")):
        with pytest.raises(ValueError, match=f"^device: .*{says}"):  # torch's own errors are tracebacks
            load_checkpoint(tmp_path / "ckpt", device=device)
    assert all(np.array_equal(backgrounds[s], bg[s]) for s in bg)
    assert torch.equal(loaded.predict(batch), model.predict(batch))
    # the policy wrapper gives the same chunk from a numpy observation, with the stored background
    policy = ACTPolicy.from_pretrained(tmp_path / "ckpt")
    chunk = policy.predict_chunk(_observation(ds, 0, with_background=False))
    assert chunk.shape == (6, 5) and chunk.dtype == np.float32
    assert np.allclose(chunk, model.predict({k: v[:1] for k, v in batch.items()})[0].numpy(), atol=1e-5)


def test_corrupted_or_mismatched_checkpoints_are_refused(tmp_path):
    model = ACT(tiny_config())
    ckpt = save_checkpoint(tmp_path / "ckpt", model)
    (ckpt / "model.safetensors").write_bytes(b"\x00" * 64)
    with pytest.raises(CheckpointError, match="corrupted"):
        load_checkpoint(ckpt)
    save_checkpoint(ckpt, model)
    doc = json.loads((ckpt / "config.json").read_text())
    doc["act"]["dim_model"] = 64
    (ckpt / "config.json").write_text(json.dumps(doc))
    with pytest.raises(CheckpointError, match="shape"):
        load_checkpoint(ckpt)
    (ckpt / "config.json").write_text("{not json")
    with pytest.raises(CheckpointError, match="not valid JSON"):
        load_checkpoint(ckpt)
    with pytest.raises(CheckpointError, match="not found"):
        load_checkpoint(tmp_path / "nowhere")
    save_checkpoint(ckpt, model)
    (ckpt / "stats.json").unlink()
    with pytest.raises(CheckpointError, match="stats.json"):
        load_checkpoint(ckpt)
    save_checkpoint(ckpt, model)
    (ckpt / "model_card.json").unlink()
    with pytest.raises(CheckpointError, match="model_card.json"):
        load_checkpoint(ckpt)
    with pytest.raises(ValueError, match="is not a checkpoint folder"):  # without its card it may be anyone's
        save_checkpoint(ckpt, model)
    with torch.no_grad():
        model.action_head.bias.fill_(float("nan"))
    with pytest.raises(CheckpointError, match=r"not saved: model.safetensors tensors \['action_head.bias'\] hold NaN"):
        save_checkpoint(tmp_path / "nan", model)
    assert not (tmp_path / "nan").exists()
    from safetensors.torch import save_file

    from controltac_il.checkpoint import sign

    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(ckpt / "model.safetensors"))
    sign(ckpt)  # NaN weights written by another tool, and signed
    with pytest.raises(CheckpointError, match=r"model.safetensors: tensors \['action_head.bias'\] contain NaN"):
        load_checkpoint(ckpt)


def test_policy_checks_observations_before_predicting(tmp_path):
    model = ACT(tiny_config())
    policy = ACTPolicy(model)  # no stored backgrounds
    ds = SyntheticACTDataset(n=2)
    obs = _observation(ds)
    assert policy.predict_chunk(obs).shape == (6, 5)
    for key in ("images/wrist", "tactile/left", "tactile_background/right"):
        bad = dict(obs)
        del bad[key]
        with pytest.raises(ValueError, match=key):
            policy.predict_chunk(bad)
    bad = dict(obs, qpos=np.zeros(7, np.float32))
    with pytest.raises(ValueError, match="qpos"):
        policy.predict_chunk(bad)
    bad = dict(obs, **{"images/wrist": obs["images/wrist"].astype(np.float32)})
    with pytest.raises(ValueError, match="uint8"):
        policy.predict_chunk(bad)


def test_a_checkpoint_config_with_bad_values_is_refused_in_one_line(tmp_path):
    import json

    from policies.act import ACT, CheckpointError, load_checkpoint, save_checkpoint
    from act_fixtures import tiny_config

    ckpt = save_checkpoint(tmp_path / "ckpt", ACT(tiny_config()))
    doc = json.loads((ckpt / "config.json").read_text())
    for field, value in (("lr", float("inf")), ("kl_weight", float("nan")), ("chunk_size", 0)):
        (ckpt / "config.json").write_text(json.dumps({**doc, "act": {**doc["act"], field: value}}))
        with pytest.raises(CheckpointError) as info:
            load_checkpoint(ckpt)
        assert "\n" not in str(info.value) and field in str(info.value) and "config.json" in str(info.value)
