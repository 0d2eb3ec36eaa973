"""Generator building blocks on random tensors: configs, autoencoder, DiT, DDIM sampler, checkpoints, train states."""

import dataclasses
import hashlib
import json
import math

import numpy as np
import pytest
import torch
from diffusers.training_utils import EMAModel
from safetensors.torch import save_file

from controltac_il.checkpoint import CheckpointError
from controltac_il.generator.autoencoder import TactileAutoencoder
from controltac_il.generator.checkpoint import (AE_FILE, CARD_FILE, CONFIG_FILE, DIT_FILE, checkpoint_hash,
                                                load_checkpoint, save_checkpoint)
from controltac_il.generator.config import AutoencoderConfig, DiffusionConfig, DiTConfig, GeneratorConfig
from controltac_il.generator.dit import ForceDiT
from controltac_il.generator.pipeline import ForceGenerator, residual_to_unit
from controltac_il.generator.sampler import ddim_sample, make_scheduler, seeded_noise
from controltac_il.run_state import load_run_state, save_run_state
from controltac_il.training import lr_schedule

SMALL_AE = AutoencoderConfig(image_size=(32, 40), channels=(8, 8, 8), stem_channels=4, latent_channels=4)
SMALL_DIT = DiTConfig(in_channels=4, patch_size=1, hidden_size=16, depth=1, num_heads=2)


def small_config(**kw) -> GeneratorConfig:
    return GeneratorConfig(autoencoder=SMALL_AE, dit=SMALL_DIT, diffusion=DiffusionConfig(default_steps=3), **kw)


def randomised(module: torch.nn.Module, seed: int = 0) -> torch.nn.Module:
    """Give every parameter random values (zero-initialised gates would hide the conditioning)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in module.parameters():
            p.copy_(torch.randn(p.shape, generator=g) * 0.2)
    return module


# -- configs ---------------------------------------------------------------------------------

def test_config_round_trip_through_json():
    cfg = small_config(latent_scale=(1.0, 2.0, 3.0, 4.0), anchor_to_reference=True)
    again = GeneratorConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert again == cfg
    assert again.autoencoder.latent_size == (4, 5)


@pytest.mark.parametrize("kwargs, field", [
    (dict(image_size=(30, 40)), "image_size"),
    (dict(channels=()), "channels"),
    (dict(latent_channels=0), "latent_channels"),
    (dict(stem_channels=2.5), "stem_channels"),
])
def test_autoencoder_config_rejects_bad_fields(kwargs, field):
    with pytest.raises(ValueError, match=field):
        AutoencoderConfig(**kwargs)


def test_dit_and_generator_config_reject_bad_fields():
    with pytest.raises(ValueError, match="num_heads"):
        DiTConfig(hidden_size=30, num_heads=4)
    with pytest.raises(ValueError, match="mlp_ratio"):
        DiTConfig(mlp_ratio=float("nan"))
    with pytest.raises(ValueError, match="force_scale"):
        DiTConfig(force_scale=(1.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="prediction_type"):
        DiffusionConfig(prediction_type="v")
    with pytest.raises(ValueError, match="in_channels"):
        GeneratorConfig(autoencoder=SMALL_AE, dit=DiTConfig(in_channels=8, patch_size=1))
    with pytest.raises(ValueError, match="patch_size"):
        GeneratorConfig(autoencoder=SMALL_AE, dit=DiTConfig(in_channels=4, patch_size=2))
    with pytest.raises(ValueError, match="delta_scale"):
        small_config(delta_scale=(1.0, 1.0))
    with pytest.raises(ValueError, match=r"^extra: Unexpected keyword argument"):
        GeneratorConfig.from_dict({**small_config().to_dict(), "extra": 1})
    with pytest.raises(ValueError, match="conv_head_width"):
        DiTConfig(conv_head_width=-1)
    with pytest.raises(ValueError, match="detail_gate"):
        small_config(anchor_to_reference=True, detail_gate=-1.0)
    with pytest.raises(ValueError, match="detail_gate > 0 needs anchor_to_reference"):
        small_config(detail_gate=4.0)


def test_a_config_without_the_refinement_head_and_detail_gate_loads_with_both_off():
    d = small_config().to_dict()
    del d["dit"]["conv_head_width"], d["detail_gate"]
    cfg = GeneratorConfig.from_dict(d)
    assert cfg.dit.conv_head_width == 0 and cfg.detail_gate == 0.0


# -- networks ----------------------------------------------------------------------------------

def test_autoencoder_shapes_and_compression_factor():
    ae = TactileAutoencoder(AutoencoderConfig())
    x = torch.randn(2, 3, 128, 160)
    z = ae.encode(x)
    assert z.shape == (2, 8, 16, 20)
    assert ae.decode(z).shape == x.shape


def test_dit_starts_as_zero_predictor_and_uses_force():
    dit = ForceDiT(SMALL_DIT)
    x = torch.randn(3, 4, 4, 5)
    out = dit(x, x, torch.tensor([0, 10, 999]), torch.zeros(3, 3))
    assert out.shape == x.shape and torch.count_nonzero(out) == 0  # adaLN-Zero / zero final layer
    randomised(dit)
    a = dit(x, x, torch.full((3,), 500), torch.zeros(3, 3))
    b = dit(x, x, torch.full((3,), 500), torch.tensor([[0.0, 0.0, 5.0]] * 3))
    c = dit(x, torch.zeros_like(x), torch.full((3,), 500), torch.zeros(3, 3))
    assert not torch.allclose(a, b) and not torch.allclose(a, c)  # ΔF and the reference latent both condition


def test_refinement_head_starts_as_identity_and_acts_locally():
    cfg = dataclasses.replace(SMALL_DIT, patch_size=2)
    plain = randomised(ForceDiT(cfg))
    headed = ForceDiT(dataclasses.replace(cfg, conv_head_width=6))
    missing, unexpected = headed.load_state_dict(plain.state_dict(), strict=False)
    assert unexpected == [] and all(k.startswith("refine.") for k in missing)
    x, z_ref = torch.randn(2, 4, 8, 8), torch.randn(2, 4, 8, 8)
    t, df = torch.tensor([3, 900]), torch.tensor([[0.0, 0.0, 2.0], [0.5, 0.0, -1.0]])
    torch.testing.assert_close(headed(x, z_ref, t, df), plain(x, z_ref, t, df))  # zero-initialised last conv
    head = randomised(headed.refine, 3)
    out = plain(x, z_ref, t, df)
    bumped = z_ref.clone()
    bumped[:, :, 0, 0] += 1.0  # one latent pixel
    diff = head(out, bumped, x) - head(out, z_ref, x)
    assert diff[..., :4, :4].abs().amax(dim=(0, 1)).min() > 0  # three 3x3 convs reach 3 pixels...
    assert torch.count_nonzero(diff[..., 4:, :]) == 0 and torch.count_nonzero(diff[..., :, 4:]) == 0  # ...and no further


def test_residual_scaling():
    r = torch.randint(0, 256, (2, 8, 8, 3), dtype=torch.uint8)
    x = residual_to_unit(r)
    assert x.shape == (2, 3, 8, 8) and float(residual_to_unit(torch.full((1, 1, 1, 3), 127, dtype=torch.uint8)).abs().max()) == 0
    torch.testing.assert_close(x * 128 + 127, r.permute(0, 3, 1, 2).float(), rtol=0, atol=1e-4)


# -- sampler -----------------------------------------------------------------------------------

def test_seeded_noise_rows_depend_only_on_their_seed():
    a = seeded_noise([3, 4, 3], (2, 2))
    assert torch.equal(a[0], a[2]) and not torch.equal(a[0], a[1])
    assert torch.equal(seeded_noise([4], (2, 2))[0], a[1])


@pytest.mark.parametrize("prediction_type", ["epsilon", "sample"])
def test_ddim_any_step_count_is_deterministic_and_finite(prediction_type):
    dit = randomised(ForceDiT(SMALL_DIT)).eval()
    sched = make_scheduler(DiffusionConfig(prediction_type=prediction_type))
    z = torch.randn(2, 4, 4, 5)
    noise = seeded_noise([0, 1], (4, 4, 5))
    for steps in (1, 2, 7):
        a = ddim_sample(dit, sched, z, torch.ones(2, 3), noise, steps)
        b = ddim_sample(dit, sched, z, torch.ones(2, 3), noise, steps)
        assert torch.isfinite(a).all() and torch.equal(a, b)
        assert len(sched.timesteps) == steps and int(sched.timesteps[0]) == 999


def test_one_step_sample_prediction_returns_the_prediction():
    """With x0-prediction and one DDIM step the sampler must return the model's x0 exactly (alpha_prev = 1)."""
    dit = randomised(ForceDiT(SMALL_DIT)).eval()
    sched = make_scheduler(DiffusionConfig(prediction_type="sample"))
    z, noise, f = torch.randn(2, 4, 4, 5), torch.randn(2, 4, 4, 5), torch.randn(2, 3)
    out = ddim_sample(dit, sched, z, f, noise, 1)
    with torch.no_grad():
        direct = dit(noise, z, torch.full((2,), 999), f)
    torch.testing.assert_close(out, direct, rtol=1e-5, atol=1e-5)


# -- checkpoints ---------------------------------------------------------------------------------

def make_checkpoint(tmp_path, **cfg_kw):
    cfg = small_config(**cfg_kw)
    ae = randomised(TactileAutoencoder(cfg.autoencoder), 1)
    dit = randomised(ForceDiT(cfg.dit), 2)
    path = save_checkpoint(tmp_path / "ckpt", cfg, ae, dit, dtype=torch.float16, model_card={"note": "test"})
    return path, cfg, ae, dit


def test_checkpoint_round_trip_fp16(tmp_path):
    path, cfg, ae, dit = make_checkpoint(tmp_path)
    cfg2, ae2, dit2 = load_checkpoint(path)
    assert cfg2 == cfg
    for a, b in zip(ae.state_dict().values(), ae2.state_dict().values()):
        torch.testing.assert_close(b, a.half().float())
    assert all(v.dtype == torch.float32 for v in dit2.state_dict().values())
    h = checkpoint_hash(path)
    assert len(h) == 16 and h == checkpoint_hash(path)
    (path / CONFIG_FILE).write_text((path / CONFIG_FILE).read_text().replace('"default_steps": 3', '"default_steps": 4'))
    assert checkpoint_hash(path) != h


def test_checkpoint_config_mismatch_is_a_clear_error(tmp_path):
    path, cfg, _, _ = make_checkpoint(tmp_path)
    d = cfg.to_dict()
    d["dit"]["hidden_size"] = 32
    (path / CONFIG_FILE).write_text(json.dumps(d))
    with pytest.raises(ValueError, match="shape mismatch.*hidden|does not match"):
        load_checkpoint(path)
    d["dit"]["hidden_size"] = 16
    d["dit"]["depth"] = 2
    (path / CONFIG_FILE).write_text(json.dumps(d))
    with pytest.raises(ValueError, match="missing"):
        load_checkpoint(path)


def test_checkpoint_refuses_pickles_and_missing_files(tmp_path):
    path, _, _, dit = make_checkpoint(tmp_path)
    torch.save(dit.state_dict(), path / DIT_FILE)  # a pickle under the safetensors name, its card re-signed
    card = json.loads((path / CARD_FILE).read_text())
    card["weights_sha256"][DIT_FILE] = hashlib.sha256((path / DIT_FILE).read_bytes()).hexdigest()
    (path / CARD_FILE).write_text(json.dumps(card))
    with pytest.raises(CheckpointError, match=f"{DIT_FILE} is corrupted or not a safetensors file"):
        load_checkpoint(path)  # refused before any byte is unpickled
    (path / AE_FILE).unlink()
    with pytest.raises(FileNotFoundError, match="autoencoder"):
        load_checkpoint(path)
    with pytest.raises(FileNotFoundError, match="not found"):
        ForceGenerator.from_pretrained(tmp_path / "nowhere")


def test_checkpoint_weights_are_verified_against_the_model_card(tmp_path):
    path, cfg, ae, dit = make_checkpoint(tmp_path)
    card = json.loads((path / CARD_FILE).read_text())
    assert card["note"] == "test" and set(card["weights_sha256"]) == {AE_FILE, DIT_FILE}
    bad = {k: v.clone() for k, v in dit.state_dict().items()}
    next(v for v in bad.values() if v.is_floating_point()).view(-1)[0] = float("nan")
    save_file({k: v.contiguous() for k, v in bad.items()}, str(path / DIT_FILE))  # a NaN, and another hash
    with pytest.raises(CheckpointError, match=f"{DIT_FILE} is corrupted or was replaced"):
        load_checkpoint(path)
    card["weights_sha256"][DIT_FILE] = __import__("hashlib").sha256((path / DIT_FILE).read_bytes()).hexdigest()
    (path / CARD_FILE).write_text(json.dumps(card))
    with pytest.raises(CheckpointError, match=f"{DIT_FILE}: tensors .* NaN or inf"):
        load_checkpoint(path)
    (path / CARD_FILE).unlink()
    with pytest.raises(FileNotFoundError, match=CARD_FILE):
        load_checkpoint(path)


def test_generator_on_a_small_random_checkpoint(tmp_path):
    """The API's plumbing (resizing, batching, seeds, anchoring) on a tiny random model."""
    path, _, _, _ = make_checkpoint(tmp_path, anchor_to_reference=True)
    gen = ForceGenerator.from_pretrained(path)
    ref = np.random.default_rng(0).integers(100, 150, size=(5, 30, 40, 3)).astype(np.uint8)
    df = np.tile([[0.0, 0.0, 2.0]], (5, 1))
    out = gen.generate(ref, df, steps=2, seed=1, batch_size=2)
    assert out.shape == ref.shape and out.dtype == np.uint8
    np.testing.assert_array_equal(out[3], gen.generate(ref[3:4], df[3:4], steps=2, seed=1)[0])
    per_sample = gen.generate(ref, df, steps=2, seed=[7, 8, 9, 10, 11])
    np.testing.assert_array_equal(per_sample[2], gen.generate(ref[2:3], df[2:3], steps=2, seed=9)[0])


# -- training states -------------------------------------------------------------------------------

def documented_lr(step: int, total: int, peak: float, warmup: int, min_ratio: float) -> float:
    """``lr_schedule``'s docstring as a formula: update i < warmup gets peak * (i + 1) / warmup, then a cosine
    from peak down to peak * min_ratio at update ``total``."""
    if step < warmup:
        return peak * (step + 1) / warmup
    p = min(1.0, (step - warmup) / max(1, total - warmup))
    return peak * (min_ratio + (1 - min_ratio) * 0.5 * (1 + math.cos(math.pi * p)))


def _adam(lr=1e-3):
    torch.manual_seed(0)
    m = torch.nn.Linear(3, 2)
    return m, torch.optim.AdamW(m.parameters(), lr=lr)


def _train(m, opt, sched, n, x=None):
    lrs = []
    for _ in range(n):
        lrs.append(opt.param_groups[0]["lr"])
        opt.zero_grad()
        m(torch.randn(4, 3) if x is None else x).square().mean().backward()
        opt.step()
        sched.step()
    return lrs


@pytest.mark.parametrize("warmup, total", [(10, 100), (1, 7), (0, 30), (5, 5)])
def test_lr_schedule_is_the_documented_warmup_then_cosine(warmup, total):
    m, opt = _adam()
    lrs = _train(m, opt, lr_schedule(opt, [1e-3], total, warmup, 1e-4), total)
    np.testing.assert_allclose(lrs, [documented_lr(s, total, 1e-3, warmup, 0.1) for s in range(total)], rtol=1e-12)
    if warmup < total:  # the peak right after the warm-up, then never rising, halfway down at the cosine's middle
        assert lrs[warmup] == pytest.approx(1e-3) and all(b <= a for a, b in zip(lrs[warmup:], lrs[warmup + 1:]))
    if (total - warmup) % 2 == 0 and warmup < total:
        assert lrs[warmup + (total - warmup) // 2] == pytest.approx((1e-3 + 1e-4) / 2)
    m, opt = _adam()  # constant after the warm-up (ACT)
    lrs = _train(m, opt, lr_schedule(opt, [1e-3], total, warmup), total)
    np.testing.assert_allclose(lrs, [1e-3 * min(1.0, (s + 1) / warmup) if warmup else 1e-3 for s in range(total)], rtol=1e-12)


def test_run_state_restores_weights_optimizer_and_schedule(tmp_path):
    m, opt = _adam(1e-2)
    sched = lr_schedule(opt, [1e-2], 20, 4, 1e-3)
    _train(m, opt, sched, 6)
    save_run_state(tmp_path / "s", {"m": m}, {"step": 6}, opt, sched)
    m2 = torch.nn.Linear(3, 2)
    opt2 = torch.optim.AdamW(m2.parameters(), lr=1.0)
    meta, _ = load_run_state(tmp_path / "s", {"m": m2}, opt2)
    sched2 = lr_schedule(opt2, [1e-2], 20, 4, 1e-3, meta["lr_schedule"], meta["step"])
    x = torch.randn(4, 3)
    assert _train(m, opt, sched, 5, x) == _train(m2, opt2, sched2, 5, x)
    for a, b in zip(m.parameters(), m2.parameters()):
        torch.testing.assert_close(a, b)
    # a resumed run with a longer budget follows its own (longer) documented schedule from the saved step
    m3 = torch.nn.Linear(3, 2)
    opt3 = torch.optim.AdamW(m3.parameters(), lr=1.0)
    meta, _ = load_run_state(tmp_path / "s", {"m": m3}, opt3)
    lrs = _train(m3, opt3, lr_schedule(opt3, [1e-2], 40, 4, 1e-3, meta["lr_schedule"], meta["step"]), 3)
    np.testing.assert_allclose(lrs, [documented_lr(s, 40, 1e-2, 4, 0.1) for s in (6, 7, 8)], rtol=1e-12)
    with pytest.raises(CheckpointError, match="does not match"):
        load_run_state(tmp_path / "s", {"m": torch.nn.Linear(3, 3)})


def test_ema_model_is_the_warmed_up_exponential_average():
    """diffusers' EMAModel with update_after_step=-1 is an exponential average with decay min(d, (1+n)/(10+n))
    at step n, written out here by hand."""
    m, opt = _adam()
    ema = EMAModel(m.parameters(), decay=0.9, update_after_step=-1)
    by_hand = [p.detach().clone() for p in m.parameters()]
    for n in range(1, 40):
        opt.zero_grad()
        m(torch.randn(4, 3)).square().mean().backward()
        opt.step()
        ema.step(m.parameters())
        for o, p in zip(by_hand, m.parameters()):
            o.lerp_(p.detach(), 1 - min(0.9, (1 + n) / (10 + n)))
    for a, b in zip(ema.shadow_params, by_hand):
        torch.testing.assert_close(a, b)


def test_run_state_without_optimizer_state_is_refused_when_resuming(tmp_path):
    """A state in another layout (e.g. keys ``opt.*`` where AdamW's are expected) must not resume with a reset AdamW."""
    m, opt = _adam()
    save_run_state(tmp_path / "s", {"m": m}, {"step": 3, "param_groups": opt.state_dict()["param_groups"]})
    with pytest.raises(CheckpointError, match="no optimizer state"):
        load_run_state(tmp_path / "s", {"m": m}, opt)
    assert load_run_state(tmp_path / "s", {"m": m})[0]["step"] == 3


@pytest.mark.parametrize("edit, field", [
    (lambda c: c.update(latent_scale=[float("inf")] * len(c["latent_scale"])), "latent_scale"),
    (lambda c: c.update(delta_scale=[0.0] * len(c["delta_scale"])), "delta_scale"),
    (lambda c: c["dit"].update(force_scale=[float("inf")] * 3), "force_scale"),
    (lambda c: c["dit"].update(mlp_ratio=float("nan")), "mlp_ratio"),
    (lambda c: c.update(detail_gate=float("inf")), "detail_gate"),
])
def test_non_finite_or_non_positive_config_values_are_refused_in_one_line(tmp_path, edit, field):
    import shutil
    from pathlib import Path

    from controltac_il.generator import ForceGenerator
    from controltac_il.generator.checkpoint import CheckpointError as GenCheckpointError

    src = Path(__file__).resolve().parents[1] / "controltac_il" / "generator" / "checkpoints" / "fast"
    ckpt = tmp_path / "ckpt"
    shutil.copytree(src, ckpt)
    cfg = json.loads((ckpt / "config.json").read_text())
    edit(cfg)
    (ckpt / "config.json").write_text(json.dumps(cfg))  # json writes Infinity / NaN, as an edited file would hold
    with pytest.raises(GenCheckpointError) as info:
        ForceGenerator.from_pretrained(ckpt)
    msg = str(info.value)
    assert "\n" not in msg and field in msg and str(ckpt / "config.json") in msg


def test_a_dit_conditioned_on_the_reference_force_starts_as_the_dit_it_is_loaded_from():
    """Its reference embedder's last layer starts at zero: loaded from an unconditioned DiT, it predicts exactly
    what that DiT does whatever F_ref; once that layer moves, F_ref changes the prediction; a force condition of the
    other width is refused."""
    from controltac_il.generator.dit import force_condition

    plain = randomised(ForceDiT(SMALL_DIT))
    cond_cfg = dataclasses.replace(SMALL_DIT, reference_force=True)
    conditioned = ForceDiT(cond_cfg)
    missing, unexpected = conditioned.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith("r_embedder.") for k in missing)
    x, z, t = torch.randn(2, 4, 4, 5), torch.randn(2, 4, 4, 5), torch.tensor([10, 900])
    delta, f_ref = np.array([[0, 0, 2.0], [0.5, 0, -1.0]]), np.array([[0, 0, 4.0], [0, 0, 9.0]])
    with torch.no_grad():
        want = plain(x, z, t, torch.from_numpy(force_condition(delta, None, SMALL_DIT)))
        got = conditioned(x, z, t, torch.from_numpy(force_condition(delta, f_ref, cond_cfg)))
        assert torch.equal(want, got)
        randomised(conditioned.r_embedder, seed=1)
        assert not torch.allclose(got, conditioned(x, z, t, torch.from_numpy(force_condition(delta, f_ref, cond_cfg))))
        with pytest.raises(ValueError, match=r"the force condition is \(B, 6\)"):
            conditioned(x, z, t, torch.from_numpy(force_condition(delta, None, SMALL_DIT)))
    with pytest.raises(ValueError, match="reference_force .* is required"):
        force_condition(delta, None, cond_cfg)


def test_a_generator_conditioned_on_the_reference_force_asks_for_it():
    cfg = small_config()
    cfg = dataclasses.replace(cfg, dit=dataclasses.replace(cfg.dit, reference_force=True))
    gen = ForceGenerator(cfg, TactileAutoencoder(cfg.autoencoder), randomised(ForceDiT(cfg.dit)))
    ref = np.full((2, 32, 40, 3), 127, np.uint8)
    with pytest.raises(ValueError, match="reference_force .* is required"):
        gen.generate(ref, np.zeros((2, 3)))
    f_ref = np.array([[0, 0, 3.0], [0, 0, 6.0]])
    out = gen.generate(ref, np.zeros((2, 3)), reference_force=gen.condition_reference(f_ref))
    assert out.shape == ref.shape and not np.array_equal(out[0], out[1])  # the same frame, two reference forces
    plain = ForceGenerator(small_config(), TactileAutoencoder(SMALL_AE), ForceDiT(SMALL_DIT))
    assert gen.condition_reference(f_ref) is f_ref and plain.condition_reference(f_ref) is None


def test_a_reference_force_checkpoint_round_trips_and_generates_at_targets(tmp_path):
    cfg = small_config()
    cfg = dataclasses.replace(cfg, dit=dataclasses.replace(cfg.dit, reference_force=True))
    gen = ForceGenerator(cfg, randomised(TactileAutoencoder(cfg.autoencoder)), randomised(ForceDiT(cfg.dit)))
    loaded = ForceGenerator.from_pretrained(save_checkpoint(tmp_path / "ck", cfg, gen.autoencoder, gen.denoiser))
    assert loaded.config.dit.reference_force and loaded.denoiser.r_embedder is not None
    ref = np.full((2, 32, 40, 3), 127, np.uint8)
    f_ref, f_tgt = np.array([[0, 0, 3.0], [0, 0, 3.0]]), np.array([[0, 0, 6.0], [0, 0, 6.0]])
    res = loaded.generate_at(ref, f_ref, f_tgt)
    assert np.array_equal(res.residuals, loaded.generate(ref, f_tgt - f_ref, reference_force=f_ref))
