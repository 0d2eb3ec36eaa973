"""Training CLI on a tiny real sensor-model dataset: stages, resume, reuse of an autoencoder, torchrun."""

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from controltac_il.generator import ForceGenerator
from controltac_il.generator.training.cli import main, parse_args
from controltac_il.generator.training.data import load_pair_data, sample_pairs
from controltac_il.tactile import TRAIN_OBJECTS, SensorSpec
from controltac_il.tactile.dataset import write_dataset
from files import tree_bytes

TINY = ["--ae-steps", "3", "--dit-steps", "3", "--ae-batch", "2", "--dit-batch", "4", "--ae-crop", "32", "40",
        "--checkpoint-every", "2", "--warmup-steps", "1", "--no-contact-frames", "2", "--threads", "1"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("gen") / "data"
    write_dataset(root, TRAIN_OBJECTS[:2], poses_per_object=2, forces_per_pose=3, seed=0,
                  spec=SensorSpec.gelsight_mini().scaled(60, 80), progress=False)
    return root


def test_pairs_stay_within_a_contact_pose(dataset):
    data = load_pair_data(dataset, (64, 80), no_contact_frames=2, progress=False)
    assert data.residuals.shape == (12 + 2, 64, 80, 3)
    group_of = {int(i): g for g, idx in enumerate(data.groups) for i in idx}
    ref, tgt, df = sample_pairs(data, 200, np.random.default_rng(0), no_contact_prob=0.2)
    contact = ~np.isin(ref, data.no_contact)
    assert all(group_of[r] == group_of[t] for r, t in zip(ref[contact], tgt[contact]))
    np.testing.assert_allclose(df[contact], data.forces[tgt[contact]] - data.forces[ref[contact]], rtol=1e-6)
    assert np.isin(tgt[~contact], data.no_contact).all() and (~contact).sum() > 10


def test_train_resume_and_reuse_autoencoder(dataset, tmp_path, capsys):
    run = tmp_path / "run"
    main(["stage1", "--data", str(dataset), "--out", str(run), "--image-size", "64", "80", *TINY])
    final = run / "final"
    card = json.loads((final / "model_card.json").read_text())
    assert card["denoiser"]["steps"] == 3 and card["data"]["images"] == 12 and card["data"]["seed"] == 0
    gen = ForceGenerator.from_pretrained(final)
    assert gen.generate(np.full((1, 60, 80, 3), 127, np.uint8), [[0, 0, 1]], steps=1).shape == (1, 60, 80, 3)

    with pytest.raises(SystemExit):  # states present: refuses to start over silently
        parse_args(["stage1", "--data", str(dataset), "--out", str(run), "--image-size", "64", "80", *TINY])
    more = [a if a != "3" else "5" for a in TINY]
    main(["stage1", "--data", str(dataset), "--out", str(run), "--image-size", "64", "80", "--resume", *more])
    assert json.loads((run / "denoiser_state.json").read_text())["step"] == 5
    assert json.loads((run / "autoencoder_state.json").read_text())["step"] == 5

    fast = tmp_path / "fast"
    main(["stage1", "--data", str(dataset), "--out", str(fast), "--image-size", "64", "80", "--autoencoder-from", str(run),
          "--stage", "denoiser", "--dit-preset", "tiny", "--prediction-type", "sample", "--default-steps", "2",
          "--dit-conv-head", "8", "--one-step-fraction", "0.5", *TINY])
    g2 = ForceGenerator.from_pretrained(fast / "final")
    assert g2.config.diffusion.prediction_type == "sample" and g2.config.dit.depth == 2
    assert g2.config.dit.conv_head_width == 8
    card = json.loads((fast / "final" / "model_card.json").read_text())
    assert "--dit-conv-head 8 " in card["command"] and "--one-step-fraction 0.5 " in card["command"]
    assert card["denoiser"]["history"][-1]["one_step_fraction"] == 0.5
    assert not (fast / "autoencoder_state.json").exists()
    # the reused autoencoder's own training (the resumed run's arguments) is in the card
    ae_made_by = {"command": json.loads((final / "model_card.json").read_text())["command"],
                  "data": {"path": str(dataset), "seed": 0, "images": 12}}
    assert "--ae-steps 5 " in ae_made_by["command"] and card["autoencoder"]["trained_by"] == ae_made_by
    _fine_tunes_of(dataset, tmp_path, run, fast, ae_made_by, capsys)


def _fine_tunes_of(dataset, tmp_path, run, fast, ae_made_by, capsys):
    """Fine-tunes of ``fast`` (a run folder, its autoencoder from ``run``): 0 steps reproduce its DiT and keep its
    latent scales, the card's history and lineage say where each started, mismatched configs are refused."""
    g2 = ForceGenerator.from_pretrained(fast / "final")
    tune = ["--data", str(dataset), "--image-size", "64", "80", "--autoencoder-from", str(run), "--stage", "denoiser",
            "--dit-preset", "tiny", "--prediction-type", "sample", "--dit-conv-head", "8"]
    main(["stage1", *tune, "--out", str(tmp_path / "tune0"), "--denoiser-from", str(fast / "final"), *TINY[:2], "--dit-steps", "0",
          "--anchor-to-reference", "--detail-gate", "2"])
    g3 = ForceGenerator.from_pretrained(tmp_path / "tune0" / "final")
    assert g3.config.anchor_to_reference and g3.config.detail_gate == 2.0
    assert g3.config.latent_scale == g2.config.latent_scale and g3.config.delta_scale == g2.config.delta_scale
    a, b = g2.denoiser.state_dict(), g3.denoiser.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    # from a run folder's state, then trained on: the history says where it started
    main(["stage1", *tune, "--out", str(tmp_path / "tune2"), "--denoiser-from", str(fast), *TINY])
    card = json.loads((tmp_path / "tune2" / "final" / "model_card.json").read_text())
    assert card["denoiser"]["from"] == str(fast) and f"--denoiser-from {fast}" in card["command"]
    assert card["denoiser"]["history"][0]["denoiser_from"] == str(fast)
    # the lineage carries every earlier training, oldest first, so a chain of fine-tunes stays reproducible
    fast_card = json.loads((fast / "final" / "model_card.json").read_text())
    assert card["denoiser"]["lineage"] == [{"command": fast_card["command"], "data": {"path": str(dataset), "seed": 0, "images": 12},
                                            "steps": 3, "wall_s": fast_card["denoiser"]["wall_s"]}]
    from_checkpoint = [a if a != str(run) else str(fast / "final") for a in tune]  # autoencoder of a checkpoint
    main(["stage1", *from_checkpoint, "--out", str(tmp_path / "tune5"), "--denoiser-from", str(tmp_path / "tune2" / "final"), *TINY])
    card5 = json.loads((tmp_path / "tune5" / "final" / "model_card.json").read_text())
    assert card5["autoencoder"]["trained_by"] == ae_made_by and card5["autoencoder"]["steps"] == 5
    chain = card5["denoiser"]["lineage"]
    assert [e["command"] for e in chain] == [fast_card["command"], card["command"]]
    assert fast_card["denoiser"]["lineage"] == []
    capsys.readouterr()
    assert main(["stage1", *tune[:-2], "--out", str(tmp_path / "tune3"), "--denoiser-from", str(fast), *TINY]) == 2
    assert re.search("another dit config.*conv_head_width", capsys.readouterr().err)
    assert main(["stage1", *tune, "--out", str(tmp_path / "tune4"), "--denoiser-from", str(tmp_path), *TINY]) == 2
    assert "denoiser_from" in capsys.readouterr().err


def test_autoencoder_fine_tune_starts_from_the_reused_one_and_the_dit_follows(dataset, tmp_path):
    base = tmp_path / "base"
    main(["stage1", "--data", str(dataset), "--out", str(base), "--image-size", "64", "80", *TINY])
    tune = ["--data", str(dataset), "--image-size", "64", "80", "--autoencoder-from", str(base / "final"),
            "--denoiser-from", str(base / "final"), "--stage", "denoiser", "--ae-finetune-steps", "3", "--ae-lr", "1e-3",
            *TINY]
    main(["stage1", *tune, "--out", str(tmp_path / "tuned")])
    g0, g1 = (ForceGenerator.from_pretrained(p) for p in (base / "final", tmp_path / "tuned" / "final"))
    a0, a1 = g0.autoencoder.state_dict(), g1.autoencoder.state_dict()
    moved = [k for k in a0 if not torch.equal(a0[k], a1[k])]
    assert any(k.startswith("encoder.") for k in moved) and any(k.startswith("decoder.") for k in moved)
    # small steps from the reused weights, not a fresh start (a fresh init would differ by O(1))
    assert max(float((a0[k].float() - a1[k].float()).abs().max()) for k in a0) < 0.05
    assert g1.config.latent_scale == g0.config.latent_scale and g1.config.delta_scale == g0.config.delta_scale
    card = json.loads((tmp_path / "tuned" / "final" / "model_card.json").read_text())
    assert card["autoencoder"]["finetune"]["step"] == 3 and "--ae-finetune-steps 3" in card["command"]
    main(["stage1", *[a if a != "3" else "5" for a in tune], "--out", str(tmp_path / "tuned"), "--resume"])
    assert json.loads((tmp_path / "tuned" / "autoencoder_finetune_state.json").read_text())["step"] == 5


def _exit(argv) -> int:
    try:
        return main(["stage1", *argv])
    except SystemExit as e:
        return e.code


@pytest.mark.parametrize("flags, named", [
    (["--ae-crop", "200", "40"], "ae_crop"), (["--one-step-fraction", "1.5"], "--one-step-fraction"),
    (["--detail-gate", "4"], "anchor-to-reference"), (["--anchor-to-reference", "--detail-gate", "-1"], "--detail-gate"),
    (["--dit-conv-head", "-2"], "--dit-conv-head"), (["--ema-decay", "1.5"], "--ema-decay"),
    (["--dit-steps", "0"], "--dit-steps"), (["--ae-steps", "0"], "--ae-steps"), (["--dit-lr", "inf"], "--dit-lr"),
    (["--stage", "denoiser"], "stage 'denoiser'"), (["--checkpoint-every", "0"], "--checkpoint-every"),
    (["--ae-finetune-steps", "5"], "--autoencoder-from"),
    (["--ae-finetune-steps", "5", "--autoencoder-from", "x", "--denoiser-from", "x", "--dit-steps", "0"], "--dit-steps"),
    (["--device", "abacus"], "--device"), (["--device", "mps"], "--device"),
    (["--autoencoder-from", "no_such_ae"], "--autoencoder-from no_such_ae: no such checkpoint folder"),
    (["--denoiser-from", "no_such_run"], "--denoiser-from no_such_run: no such checkpoint folder"),
    pytest.param(["--device", "cuda"], "--device: 'cuda', but this machine has 0 CUDA device(s)", marks=pytest.mark.skipif(
        __import__("torch").cuda.is_available(), reason="this machine has CUDA: the refusal is for machines without")),
])
def test_bad_training_arguments_are_one_line_naming_the_flag(dataset, tmp_path, capsys, flags, named):
    assert _exit(["--data", str(dataset), "--out", str(tmp_path / "x"), *flags]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and named in err[0], err
    assert not (tmp_path / "x").exists()


def test_missing_data_is_one_line(tmp_path, capsys):
    assert _exit(["--data", str(tmp_path / "nowhere"), "--out", str(tmp_path / "g")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nowhere" in err[0] and "--data" in err[0]


def test_out_of_the_users_own_is_never_replaced(dataset, tmp_path, capsys):
    out = tmp_path / "mine"
    (out / "final").mkdir(parents=True)
    (out / "final" / "notes.txt").write_text("mine")
    (out / "train_config.json").write_text('{"mine": true}')
    before = tree_bytes(out)
    for extra in ([], ["--overwrite"], ["--resume"]):
        assert _exit(["--data", str(dataset), "--out", str(out), "--image-size", "64", "80", *TINY, *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(out) in err[0], (extra, err)
        assert tree_bytes(out) == before


def test_data_refused_leaves_out_unwritten_so_the_corrected_command_runs_as_given(tmp_path):
    (tmp_path / "empty").mkdir()
    out = tmp_path / "run"
    assert main(["stage1", "--data", str(tmp_path / "empty"), "--out", str(out), "--image-size", "64", "80", *TINY]) == 2
    assert not out.exists()


def test_a_previous_run_needs_resume_or_overwrite(dataset, tmp_path, capsys):
    run = tmp_path / "run"
    args = ["--data", str(dataset), "--out", str(run), "--image-size", "64", "80", *TINY[:2], "--dit-steps", "1",
            *TINY[4:]]
    assert main(["stage1", *args]) == 0
    (run / "my_notes.txt").write_text("mine")
    before = tree_bytes(run)
    capsys.readouterr()
    assert _exit(args) == 2
    err = capsys.readouterr().err
    assert "--resume" in err and "--overwrite" in err and tree_bytes(run) == before
    assert main(["stage1", *args, "--overwrite"]) == 0
    assert json.loads((run / "denoiser_state.json").read_text())["step"] == 1 and (run / "my_notes.txt").is_file()


def test_nonfinite_loss_stops_before_updating_and_ctrl_c_saves_the_step(tmp_path):
    from controltac_il.training import NonFiniteLoss, TrainingInterrupted, lr_schedule, optimise

    module = torch.nn.Linear(2, 1)
    opt = torch.optim.AdamW(module.parameters(), lr=1e-2)
    saved = []

    def loss_at(bad_step, action):
        def batch_loss(step):
            if step == bad_step:
                action()
            loss = module(torch.ones(4, 2)).pow(2).mean()
            return loss * float("nan") if step == bad_step and action is _nothing else loss
        return batch_loss

    sched = lr_schedule(opt, [1e-2], 10, 0, 1e-3)
    with pytest.raises(NonFiniteLoss, match=r"step 3.*holds step 2"):
        optimise(0, 10, loss_at(2, _nothing), opt, sched, list(module.parameters()), lambda s, l: saved.append(s), 1,
                 "t", state=str(tmp_path / "t_state"))
    assert saved == [1, 2] and all(torch.isfinite(p).all() for p in module.parameters())
    saved.clear()
    with pytest.raises(TrainingInterrupted, match="holds step 3 of 10"):
        optimise(0, 10, loss_at(2, lambda: os.kill(os.getpid(), signal.SIGINT)), opt, sched, list(module.parameters()),
                 lambda s, l: saved.append(s), 100, "t", state=str(tmp_path / "t_state"))
    assert saved == [3]


@pytest.mark.parametrize("grad_clip", [1.0, 0.0])
def test_a_finite_loss_with_nan_gradients_stops_before_updating(grad_clip):
    """sqrt(w * 0) at w = 0: the loss is 0, its gradient 0 * inf = NaN."""
    from controltac_il.training import NonFiniteLoss, lr_schedule, optimise

    w = torch.nn.Parameter(torch.tensor([0.5, 0.5]))
    opt = torch.optim.AdamW([w], lr=1e-2)

    before = []

    def batch_loss(step):
        before.append(w.detach().clone())
        return (w - 1.0).pow(2).sum() if step < 2 else (w * 0).sqrt().sum()

    with pytest.raises(NonFiniteLoss, match=r"step 3: the loss is 0 but its gradients' norm is nan; no update"):
        optimise(0, 5, batch_loss, opt, lr_schedule(opt, [1e-2], 5, 0, 1e-3), [w], None, 0, "t", grad_clip=grad_clip)
    assert len(before) == 3 and not torch.equal(before[2], before[0]) and torch.equal(w.detach(), before[2])


def test_weights_that_are_not_finite_are_never_saved(tmp_path):
    from controltac_il.checkpoint import CheckpointError, save_folder

    for weights, dtype, says in (({"w": torch.tensor([1.0, float("nan")])}, None, "hold NaN or inf$"),
                                 ({"w": torch.tensor([1e5])}, torch.float16, "hold NaN or inf as float16$")):
        with pytest.raises(CheckpointError, match="not saved: m.safetensors tensors \\['w'\\] " + says):
            save_folder(tmp_path / "ckpt", {}, {"m.safetensors": weights}, dtype=dtype)
        assert not (tmp_path / "ckpt").exists() and list(tmp_path.iterdir()) == []


def _nothing():
    pass


@pytest.mark.slow
def test_torchrun_two_processes_gloo(dataset, tmp_path):
    run = tmp_path / "ddp"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
           "-m", "controltac_il.generator.training", "stage1", "--data", str(dataset), "--out", str(run), "--image-size", "64", "80", *TINY]
    subprocess.run(cmd, check=True, env=env, cwd=Path(__file__).resolve().parents[1], timeout=600)
    card = json.loads((run / "final" / "model_card.json").read_text())
    assert card["world_size"] == 2 and card["denoiser"]["steps"] == 3


def test_shipped_checkpoints_are_named_as_fine_tuning_sources(tmp_path):
    from controltac_il.generator.shipped import CHECKPOINT_ROOT

    (tmp_path / "presses").mkdir()
    cfg = parse_args(["stage1", "--data", str(tmp_path / "presses"), "--out", str(tmp_path / "tuned"), "--stage", "denoiser",
                      "--autoencoder-from", "default", "--denoiser-from", "default"])
    assert cfg.autoencoder_from == cfg.denoiser_from == str(CHECKPOINT_ROOT / "default")


def test_distinct_pairs_never_pair_a_frame_with_itself():
    from controltac_il.generator.training.data import PairData, sample_pairs

    data = PairData(np.zeros((7, 8, 8, 3), np.uint8), np.arange(21, dtype=np.float32).reshape(7, 3),
                    [np.array([0, 1, 2]), np.array([3, 4]), np.array([5]), np.array([6])], np.zeros(0, np.int64))
    ref, tgt, df = sample_pairs(data, 2000, np.random.default_rng(0), no_contact_prob=0.0, distinct=True)
    grouped = ref <= 4  # groups of two or more never give a self-pair; singletons can only pair with themselves
    assert (ref[grouped] != tgt[grouped]).all() and (ref[~grouped] == tgt[~grouped]).all()
    assert {(a, b) for a, b in zip(ref, tgt) if a <= 2} == {(a, b) for a in range(3) for b in range(3) if a != b}
    np.testing.assert_array_equal(df, data.forces[tgt] - data.forces[ref])
    r, t, _ = sample_pairs(data, 2000, np.random.default_rng(0), no_contact_prob=0.0)
    assert (r == t).mean() > 0.3  # by default self-pairs occur (the shipped checkpoints were trained so)


def test_increase_prob_orders_that_share_of_pairs_to_press_harder_and_zero_draws_the_same_pairs():
    """ForceAugment's targets mostly press harder: ``increase_prob`` P swaps a pair whose target presses less with
    probability P (so P = 1 gives ΔFz >= 0 everywhere, P = 0.5 three in four), keeping every pair within its pose
    group; P = 0 draws nothing extra, so training without the lever is unchanged."""
    from controltac_il.generator.training.data import PairData

    forces = np.zeros((6, 3), np.float32)
    forces[:, 2] = [1, 4, 7, 2, 5, 9]
    data = PairData(np.zeros((6, 8, 8, 3), np.uint8), forces, [np.arange(3), np.arange(3, 6)], np.zeros(0, np.int64))
    base = sample_pairs(data, 4000, np.random.default_rng(1), no_contact_prob=0.0, distinct=True)
    same = sample_pairs(data, 4000, np.random.default_rng(1), no_contact_prob=0.0, distinct=True, increase_prob=0.0)
    for a, b in zip(base, same):
        np.testing.assert_array_equal(a, b)
    ref, tgt, df = sample_pairs(data, 4000, np.random.default_rng(1), no_contact_prob=0.0, distinct=True, increase_prob=1.0)
    assert (df[:, 2] > 0).all() and ((ref < 3) == (tgt < 3)).all()
    np.testing.assert_array_equal(df, forces[tgt] - forces[ref])
    _, _, half = sample_pairs(data, 4000, np.random.default_rng(1), no_contact_prob=0.0, distinct=True, increase_prob=0.5)
    assert (base[2][:, 2] > 0).mean() == pytest.approx(0.5, abs=0.03)
    assert (half[:, 2] > 0).mean() == pytest.approx(0.75, abs=0.03)


def test_new_contact_marks_the_cells_a_harder_press_adds_and_the_weighted_loss_counts_them_more():
    """A reference disc of radius 3 px and a target disc of radius 6 px centred in 16 × 16 px: the new contact is
    the ring between them, marked per 4 × 4 cell (every cell but the corners, whose nearest pixel lies 6.4 px out);
    a weight of 1 + w on it makes an error there cost (1 + w) times one elsewhere."""
    from controltac_il.generator.training.data import PairData, new_contact
    from controltac_il.generator.training.objectives import prediction_loss

    yy, xx = np.mgrid[:16, :16]
    disc = [128 + (np.hypot(yy - 7.5, xx - 7.5) < r)[..., None] * np.full(3, 40) for r in (3, 6)]  # 128: no residual
    data = PairData(np.stack(disc).astype(np.uint8), np.zeros((2, 3), np.float32), [np.arange(2)], np.zeros(0, np.int64))
    new = new_contact(data, np.array([0]), np.array([1]), 4)
    corners = np.zeros((4, 4), bool)
    corners[::3, ::3] = True
    assert new.shape == (1, 1, 4, 4) and (new[0, 0] == ~corners).all()
    assert new_contact(data, np.array([1]), np.array([0]), 4).sum() == 0  # easing off adds no contact
    weight = 1.0 + 3.0 * torch.from_numpy(new)
    target, pred = torch.zeros(1, 2, 4, 4), torch.zeros(1, 2, 4, 4)
    pred[0, :, 1, 1] = 1.0  # an error of 1 on one new-contact cell (both channels)
    inside = prediction_loss(pred, target, weight)
    pred = torch.zeros(1, 2, 4, 4)
    pred[0, :, 0, 0] = 1.0  # the same error outside it
    assert inside.item() == pytest.approx(4 * prediction_loss(pred, target, weight).item())
    assert prediction_loss(pred, target).item() == pytest.approx(prediction_loss(pred, target, torch.ones(1, 1, 4, 4)).item())


def test_every_training_flag_says_what_it_sets():
    """``--help`` of both stages explains each flag, not only its default."""
    import argparse

    from controltac_il.generator.training.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    bare = [(stage, a.option_strings[0]) for stage, p in sub.choices.items() for a in p._actions
            if a.option_strings and a.help != argparse.SUPPRESS
            and (not a.help or a.help.startswith("(default"))]
    assert bare == []


def test_a_run_may_add_the_reference_force_condition_to_its_source_but_not_drop_it(tmp_path):
    import dataclasses

    from controltac_il.generator.config import GeneratorConfig
    from controltac_il.generator.training.stage1 import check_same_models

    plain = GeneratorConfig()
    conditioned = dataclasses.replace(plain, dit=dataclasses.replace(plain.dit, reference_force=True))
    check_same_models(tmp_path, plain, conditioned)  # its embedder starts at zero
    with pytest.raises(ValueError, match="reference_force"):
        check_same_models(tmp_path, conditioned, plain)


def test_a_calibration_fine_tune_keeps_its_bases_reference_force_condition(tmp_path):
    from controltac_il.generator.training.finetune import base_flags

    card = {"command": "python -m controltac_il.generator.training stage1 --data d --out o --dit-preset tiny "
                       "--anchor-to-reference --reference-force --dit-steps 10"}
    (tmp_path / "model_card.json").write_text(json.dumps(card))
    assert base_flags(tmp_path) == ["--dit-preset", "tiny", "--anchor-to-reference", "--reference-force"]


def test_a_fine_tune_adds_the_reference_force_condition_and_its_resume_keeps_it(dataset, tmp_path, capsys):
    """From an unconditioned run, --reference-force trains a conditioned DiT (the source's weights, a new embedder);
    resuming it without the flag is refused naming it, in one line, the run left as it was."""
    base = tmp_path / "base"
    main(["stage1", "--data", str(dataset), "--out", str(base), "--image-size", "64", "80", *TINY])
    run, common = tmp_path / "cond", ["--data", str(dataset), "--image-size", "64", "80", "--stage", "denoiser",
                                      "--autoencoder-from", str(base), "--denoiser-from", str(base / "final"), *TINY]
    main(["stage1", *common, "--out", str(run), "--reference-force"])
    gen = ForceGenerator.from_pretrained(run / "final")
    assert gen.config.dit.reference_force
    card = json.loads((run / "final" / "model_card.json").read_text())
    assert card["denoiser"]["history"][-1]["reference_force"] is True
    before = (run / "denoiser_state.json").read_text()
    capsys.readouterr()
    assert main(["stage1", *common, "--out", str(run), "--resume"]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "was trained with --reference-force" in err, err
    assert (run / "denoiser_state.json").read_text() == before
