"""Stage 2: rigid mask moves, the zero-initialised adapter, the pose API and its bad input, the shipped adapter."""

import json
import shutil

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from controltac_il.checkpoint import CheckpointError
from controltac_il.generator import ForceGenerator
from controltac_il.generator.adapter import PoseAdapter, masks_to_model
from controltac_il.generator.checkpoint import ADAPTER_FILE, CARD_FILE, load_adapter, save_adapter
from controltac_il.generator.config import PoseAdapterConfig
from controltac_il.generator.shipped import CHECKPOINT_ROOT
from controltac_il.generator.training.pose_data import render_scenes, sample_pose_pairs, target_mask
from controltac_il.metrics import mse
from controltac_il.tactile import SensorSpec, TactileSensor
from controltac_il.tactile.pose import check_mask, move_mask, transform_between


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


@pytest.fixture(scope="module")
def sensor():
    return TactileSensor(SensorSpec.gelsight_mini().scaled(120, 160))


@pytest.fixture(scope="module")
def gen():
    return ForceGenerator.from_pretrained(pose_adapter="pose")


@pytest.fixture(scope="module")
def pair(sensor):
    """A t_shape (held-out object) pressed at two poses and forces: (reference contact, target contact, poses)."""
    a, b = (1.0, -1.5, 0.2), (-2.0, 2.0, 1.3)
    return sensor.press("t_shape", a, (0.0, 0.0, 4.0), noise_seed=1), sensor.press("t_shape", b, (0.0, 0.0, 6.0), noise_seed=2), a, b


# -- tactile.pose ---------------------------------------------------------------------------------

@pytest.mark.parametrize("obj", ["t_shape", "usb_c", "triple_cylinder"])
def test_transform_between_carries_the_contact_to_the_new_pose_and_its_sign_matters(sensor, obj):
    a, b = (1.0, -1.5, 0.2), (-2.0, 2.5, 1.3)
    ma, mb = (sensor.press(obj, p, (0, 0, 4)).mask for p in (a, b))
    dx, dy, dth = transform_between(a, b, ma, sensor.spec.mm_per_px)
    assert dth == pytest.approx(1.1)
    assert iou(move_mask(ma, (dx, dy, dth)), mb) > 0.9
    assert iou(move_mask(ma, (dx, dy, -dth)), mb) < 0.6  # rotation sense: counter-clockwise as displayed


def test_move_mask_shifts_right_and_down_and_scales_about_the_centroid():
    m = np.zeros((40, 50), bool)
    m[10:20, 10:16] = True
    moved = move_mask(m, (5, 3, 0.0))
    assert np.array_equal(np.argwhere(moved), np.argwhere(m) + [3, 5])  # rows down by dy, columns right by dx
    big = move_mask(m, (0, 0, 0.0), scale=2.0)
    assert big.sum() == pytest.approx(4 * m.sum(), rel=0.1)
    assert np.allclose(np.argwhere(big).mean(0), np.argwhere(m).mean(0), atol=0.6)


@pytest.mark.parametrize("mask, shape, match", [
    (np.zeros((8, 8), bool), None, "empty"),
    (np.ones((8, 8), bool), (8, 9), "size 8x8"),
    (np.full((8, 8), 2), None, "only 0 and 1"),
    (np.ones((8,), bool), None, "2-D"),
])
def test_check_mask_refuses_bad_masks(mask, shape, match):
    with pytest.raises(ValueError, match=match):
        check_mask(mask, shape)


def test_move_mask_refuses_moving_everything_off_the_pad_and_bad_transforms():
    m = np.zeros((20, 20), bool)
    m[5:8, 5:8] = True
    with pytest.raises(ValueError, match="entirely off the pad"):
        move_mask(m, (100, 0, 0))
    with pytest.raises(ValueError, match="finite"):
        move_mask(m, (np.nan, 0, 0))
    with pytest.raises(ValueError, match="dx_px, dy_px, dtheta"):
        move_mask(m, (1, 2))


# -- the adapter ----------------------------------------------------------------------------------

def test_an_untrained_adapter_is_exactly_stage_1():
    base = ForceGenerator.from_pretrained()
    adapter = PoseAdapter(PoseAdapterConfig(base=base.config), base.denoiser)
    g = torch.Generator().manual_seed(0)
    x, z = (torch.randn(3, 8, 32, 40, generator=g) for _ in range(2))
    t, df = torch.tensor([999, 10, 500]), torch.randn(3, 2 + 1, generator=g)
    mask = (torch.rand(3, 1, 128, 160, generator=g) > 0.5).float()
    with torch.no_grad():
        assert torch.equal(adapter(base.denoiser, x, z, t, df, mask), base.denoiser(x, z, t, df))


def test_masks_to_model_keeps_coverage():
    m = np.zeros((1, 120, 160), bool)
    m[0, 30:90, 40:120] = True
    out = masks_to_model(m, (128, 160))
    assert out.shape == (1, 1, 128, 160) and out.min() >= 0 and out.max() <= 1
    assert out.mean() == pytest.approx(m.mean(), rel=0.02)


def test_adapter_checkpoint_round_trip_and_tamper_detection(tmp_path):
    base = ForceGenerator.from_pretrained()
    cfg = PoseAdapterConfig(base=base.config, base_hash=base.checkpoint_hash, mask_channels=8, head_width=8)
    adapter = PoseAdapter(cfg, base.denoiser)
    folder = save_adapter(tmp_path / "a", cfg, adapter, dtype=torch.float16, model_card={"note": "test"})
    cfg2, loaded = load_adapter(folder)
    assert cfg2 == cfg
    for k, v in adapter.state_dict().items():
        assert torch.allclose(loaded.state_dict()[k], v.half().float())
    data = bytearray((folder / ADAPTER_FILE).read_bytes())
    data[-1] ^= 1
    (folder / ADAPTER_FILE).write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match="corrupted or was replaced"):
        load_adapter(folder)


# -- the pose API -----------------------------------------------------------------------------------

def test_without_a_mask_the_generator_is_exactly_stage_1(gen, pair):
    ref = pair[0].residual[None]
    plain = ForceGenerator.from_pretrained()
    assert np.array_equal(gen.generate(ref, [[0, 0, 2.0]]), plain.generate(ref, [[0, 0, 2.0]]))


def test_pose_control_moves_the_contact_where_stage_1_cannot(gen, pair, sensor):
    ref, tgt, a, b = pair
    t = transform_between(a, b, ref.mask, sensor.spec.mm_per_px)
    df = [[0.0, 0.0, 2.0]]
    out = gen.generate(ref.residual[None], df, object_mask=ref.mask, transform=t)
    via_mask = gen.generate(ref.residual[None], df, mask=move_mask(ref.mask, t))
    assert np.array_equal(out, via_mask)  # object_mask + transform is the moved mask
    stage1 = gen.generate(ref.residual[None], df)
    assert mse(out, tgt.residual[None])[0] < 0.6 * mse(stage1, tgt.residual[None])[0]
    assert mse(out, tgt.residual[None])[0] < 0.6 * mse(ref.residual[None], tgt.residual[None])[0]


def test_generate_at_takes_the_mask_too(gen, pair, sensor):
    ref, _, a, b = pair
    m = move_mask(ref.mask, transform_between(a, b, ref.mask, sensor.spec.mm_per_px))
    res = gen.generate_at(ref.residual[None], [[0, 0, 4.0]], [[0, 0, 6.0]], mask=m)
    assert np.array_equal(res.residuals, gen.generate(ref.residual[None], [[0, 0, 2.0]], mask=m))


@pytest.mark.parametrize("kwargs, match", [
    ({"mask": np.zeros((120, 160), bool)}, "empty"),
    ({"mask": np.ones((60, 80), bool)}, "size 60x80"),
    ({"mask": np.ones((2, 120, 160), bool)}, r"\(1, H, W\)"),
    ({"object_mask": "m"}, "go together"),
    ({"transform": (1, 2, 0)}, "go together"),
    ({"mask": "m", "object_mask": "m", "transform": (0, 0, 0)}, "either mask"),
    ({"object_mask": "m", "transform": (400, 0, 0)}, "entirely off the pad"),
    ({"object_mask": "m", "transform": (np.nan, 0, 0)}, "finite"),
    ({"object_mask": "m", "transform": (1, 2)}, "finite"),
])
def test_bad_masks_and_transforms_are_refused(gen, pair, kwargs, match):
    ref = pair[0]
    kwargs = {k: ref.mask if isinstance(v, str) else v for k, v in kwargs.items()}
    with pytest.raises(ValueError, match=match):
        gen.generate(ref.residual[None], [[0, 0, 1.0]], **kwargs)


def test_a_mask_without_the_adapter_and_an_adapter_of_another_base_are_refused(pair):
    plain = ForceGenerator.from_pretrained()
    with pytest.raises(ValueError, match="needs the stage-2 pose adapter"):
        plain.generate(pair[0].residual[None], [[0, 0, 1.0]], mask=pair[0].mask)
    with pytest.raises(ValueError, match="trained on stage-1 checkpoint"):
        ForceGenerator.from_pretrained("fast", pose_adapter="pose")


def test_the_shipped_adapter_is_small_fp16_and_names_its_base():
    folder = CHECKPOINT_ROOT / "pose"
    assert sum(p.stat().st_size for p in folder.iterdir()) < 25e6
    base = ForceGenerator.from_pretrained()
    cfg, _ = load_adapter(folder)
    assert cfg.base_hash == base.checkpoint_hash and cfg.base == base.config
    assert json.loads((folder / CARD_FILE).read_text())["base_hash"] == base.checkpoint_hash
    from safetensors import safe_open
    with safe_open(str(folder / ADAPTER_FILE), "pt") as f:
        assert {f.get_tensor(k).dtype for k in f.keys()} == {torch.float16}


def test_an_adapter_built_for_another_generator_is_refused_at_construction():
    base, fast = ForceGenerator.from_pretrained(), ForceGenerator.from_pretrained("fast")
    alien = PoseAdapter(PoseAdapterConfig(base=fast.config), fast.denoiser)
    with pytest.raises(ValueError, match="another stage-1 configuration"):
        ForceGenerator(base.config, base.autoencoder, base.denoiser, pose_adapter=alien)


def test_transform_between_refuses_bad_poses(pair, sensor):
    with pytest.raises(ValueError, match="pose must be"):
        transform_between((0, 0), (1, 1, 0), pair[0].mask, sensor.spec.mm_per_px)
    with pytest.raises(ValueError, match="finite"):
        transform_between((0, 0, 0), (np.nan, 1, 0), pair[0].mask, sensor.spec.mm_per_px)


# -- training data -------------------------------------------------------------------------------

def test_pose_pairs_are_within_scenes_and_deterministic():
    scenes = render_scenes(["t_shape", "cross"], 2, 3, 2, seed=5, progress=False)
    assert len(scenes.objects) == 4 and scenes.masks.shape[0] == len(scenes.residuals)
    members = scenes.members()
    draw = [sample_pose_pairs(scenes, members, 16, np.random.default_rng(1), 3.0, 1.0) for _ in range(2)]
    ref, tgt, df, masks = draw[0]
    assert np.array_equal(ref, draw[1][0]) and np.array_equal(masks, draw[1][3])
    assert np.array_equal(scenes.scene[ref], scenes.scene[tgt])
    assert np.allclose(df, scenes.forces[tgt] - scenes.forces[ref])
    # without noise, the moved reference mask covers the target's own contact footprint
    pressing_less = [(i, j) for i, j in zip(ref, tgt) if scenes.forces[i][2] >= scenes.forces[j][2]]
    assert pressing_less  # the draw holds pairs whose target presses no harder than its reference
    for i, j in pressing_less:
        assert iou(target_mask(scenes, i, j), scenes.masks[j]) > 0.6


def test_stage2_cli_trains_resumes_and_guards_its_folder(tmp_path, capsys):
    from controltac_il.generator.training.cli import main

    out = tmp_path / "run"
    args = ["--out", str(out), "--procedural", "0", "--scenes", "1", "--poses", "2", "--forces", "1", "--batch", "4",
            "--mask-channels", "8", "--head-width", "8", "--checkpoint-every", "2", "--val-objects", "1"]
    assert main(["stage2", *args, "--steps", "2"]) == 0
    assert json.loads((out / "adapter_state.json").read_text())["step"] == 2
    assert main(["stage2", *args, "--steps", "3", "--resume"]) == 0
    assert json.loads((out / "adapter_state.json").read_text())["step"] == 3
    # its own validation split (procedural_0000, never trained on with --procedural 0), measured at each save and
    # across the resume; the best step's EMA weights are what ships
    val = json.loads((out / "final" / CARD_FILE).read_text())["validation"]
    assert val["objects"] == ["procedural_0000"] and [h["step"] for h in val["history"]] == [2, 3]
    ratios = [h["ratio_to_copy"] for h in val["history"]]
    assert np.isfinite(ratios).all() and val["best_step"] == [2, 3][int(np.argmin(ratios))]
    best = load_file(str(out / "adapter_best.safetensors"))
    shipped = load_file(str(out / "final" / "adapter.safetensors"))
    assert all(torch.equal(shipped[k], best["best." + k].to(torch.float16)) for k in shipped)
    cfg, _ = load_adapter(out / "final")
    assert cfg.base_hash == ForceGenerator.from_pretrained().checkpoint_hash
    # a longer run from a trained adapter: same widths only (the shipped one is 32 / 48 wide, these runs 8 / 8)
    assert main(["stage2", *args, "--out", str(tmp_path / "more"), "--steps", "1", "--adapter-from", str(out / "final")]) == 0
    card = json.loads((tmp_path / "more" / "final" / CARD_FILE).read_text())
    assert card["adapter_from"]["path"] == str(out / "final") and card["adapter_from"]["training"]["steps"] == 3
    assert main(["stage2", *args, "--out", str(tmp_path / "wide"), "--steps", "1", "--adapter-from", "pose"]) == 2
    assert "other widths" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["stage2", *args, "--steps", "3"])
    assert e.value.code == 2 and "--resume" in capsys.readouterr().err
    capsys.readouterr()
    assert main(["stage2", *args, "--steps", "4", "--resume", "--alignment-px", "5"]) == 2  # another run's data: refused
    assert "--alignment-px" in capsys.readouterr().err
    assert json.loads((out / "adapter_state.json").read_text())["step"] == 3
    foreign = tmp_path / "mine"
    (foreign / "final").mkdir(parents=True)
    (foreign / "final" / "notes.txt").write_text("mine")
    with pytest.raises(SystemExit):
        main(["stage2", "--out", str(foreign), "--overwrite", "--steps", "1"])
    assert (foreign / "final" / "notes.txt").read_text() == "mine"
    with pytest.raises(SystemExit) as e:
        main(["stage2", "--out", str(tmp_path / "x"), "--batch", "0"])
    assert e.value.code == 2 and "--batch" in capsys.readouterr().err
    shutil.rmtree(out)
