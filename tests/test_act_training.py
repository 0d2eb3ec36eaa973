"""ACT training: the loss goes down, checkpoints and --resume, episode split, dataset checks, torchrun."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from act_fixtures import SyntheticACTDataset, tiny_config

from controltac_il.datasets import Episode, write_episode
from policies.act import ACTConfig, CheckpointError, load_checkpoint
from policies.act.data import DataSpec, check_compatible, load_training_data
from policies.act.training import ACTTrainConfig, evaluate, resolve_checkpoint, train, train_on_folder
from files import tree_bytes

REPO = Path(__file__).resolve().parents[1]
TINY = dict(camera_size=(24, 32), tactile_size=(24, 32), dim_model=32, n_heads=2, dim_feedforward=64,
            n_encoder_layers=1, n_vae_encoder_layers=1, latent_dim=4, chunk_size=4)


def test_training_lowers_the_validation_error(tmp_path):
    """60 steps at lr 3e-3 bring the held-out L1 to 0.32-0.55x the untrained model's over four seeds and one or two
    torch threads (whose float sums differ): the bound 0.7 holds with margin on either thread count."""
    torch.manual_seed(0)
    ds, val = SyntheticACTDataset(64, seed=0), SyntheticACTDataset(16, seed=1)
    cfg = tiny_config(kl_weight=1.0, lr=3e-3, lr_backbone=3e-3)
    summary = train(cfg, ACTTrainConfig(steps=60, batch_size=8, val_every=60, warmup_steps=10), ds, val,
                    tmp_path / "run", stats=ds.stats(), progress=False)
    log = json.loads((tmp_path / "run" / "train_log.json").read_text())
    first, last = log["log"]["train"][0], log["log"]["train"][-1]
    assert last["l1"] < 0.7 * first["l1"], (first, last)
    untrained = __import__("policies.act.modeling_act", fromlist=["ACT"]).ACT(cfg)
    untrained.set_stats(ds.stats())
    loader = torch.utils.data.DataLoader(val, batch_size=16)
    trained, _, meta = load_checkpoint(tmp_path / "run" / "best")
    assert evaluate(trained, loader, 5)["val_l1"] < 0.7 * evaluate(untrained, loader, 5)["val_l1"]
    assert meta["best_val_l1"] == summary["best_val_l1"] and summary["steps"] == 60


def test_resume_continues_from_last_and_refuses_another_config(tmp_path):
    ds = SyntheticACTDataset(16)
    cfg = tiny_config()
    train(cfg, ACTTrainConfig(steps=3, batch_size=8, save_every=3), ds, None, tmp_path, stats=ds.stats(),
          progress=False)
    _, _, meta = load_checkpoint(tmp_path / "last")
    assert meta["step"] == 3 and (tmp_path / "last" / "optimizer.safetensors").is_file()
    assert resolve_checkpoint(tmp_path) == tmp_path / "last"  # no validation set -> no best
    summary = train(cfg, ACTTrainConfig(steps=5, batch_size=8), ds, None, tmp_path, stats=ds.stats(),
                    resume=True, progress=False)
    assert summary["steps"] == 5 and load_checkpoint(tmp_path / "last")[2]["step"] == 5
    assert [r["step"] for r in load_checkpoint(tmp_path / "last")[2]["log"]["train"]] == [1, 3, 5]
    with pytest.raises(CheckpointError, match="different ACT config"):
        train(tiny_config(dim_model=64), ACTTrainConfig(steps=6), ds, None, tmp_path, stats=ds.stats(), resume=True,
              progress=False)
    with pytest.raises(CheckpointError, match="no checkpoint"):
        train(cfg, ACTTrainConfig(steps=6), ds, None, tmp_path / "fresh", stats=ds.stats(), resume=True)


def test_resume_refuses_another_generator_but_not_another_augment_summary(tmp_path):
    ds = SyntheticACTDataset(16)
    cfg = tiny_config()
    aug = {"kind": "force", "copies": 1, "generator": "shipped", "generator_hash": "aaaa", "seed": 0, "steps": None}
    train(cfg, ACTTrainConfig(steps=2, batch_size=8, save_every=2), ds, None, tmp_path, stats=ds.stats(),
          meta={"augment": {**aug, "summary": {"clamped": 3}}}, progress=False)
    with pytest.raises(CheckpointError, match=r"different augmentation \(generator_hash: 'aaaa' -> 'bbbb'\)"):
        train(cfg, ACTTrainConfig(steps=4, batch_size=8), ds, None, tmp_path, stats=ds.stats(), resume=True,
              meta={"augment": {**aug, "generator_hash": "bbbb"}}, progress=False)
    with pytest.raises(CheckpointError, match=r"augmentation \(copies: 1 -> None"):
        train(cfg, ACTTrainConfig(steps=4, batch_size=8), ds, None, tmp_path, stats=ds.stats(), resume=True,
              progress=False)  # unaugmented now
    assert load_checkpoint(tmp_path / "last")[2]["step"] == 2  # refused runs leave the checkpoint alone
    # the counts of what the augmentation did may differ (e.g. fewer copies cached); the settings may not
    summary = train(cfg, ACTTrainConfig(steps=4, batch_size=8), ds, None, tmp_path, stats=ds.stats(), resume=True,
                    meta={"augment": {**aug, "summary": {"clamped": 5}}}, progress=False)
    assert summary["steps"] == 4


def test_train_config_validation():
    with pytest.raises(ValueError, match="steps"):
        ACTTrainConfig(steps=0)
    with pytest.raises(ValueError, match="batch_size"):
        ACTTrainConfig(batch_size=-1)


def test_every_model_training_and_loop_config_refuses_a_bad_field_in_one_line_naming_it():
    """What a script gets from the Python API, as a command prints it: not pydantic's four-line ValidationError."""
    from controltac_il.app.job_config import PipelineConfig
    from controltac_il.app.press_record import PressPlan
    from controltac_il.estimators import EstimatorConfig, EstimatorTrainConfig
    from controltac_il.generator import AutoencoderConfig, DiffusionConfig, DiTConfig, GeneratorConfig
    from controltac_il.generator.config import PoseAdapterConfig
    from controltac_il.generator.training.config import GeneratorTrainConfig, PoseTrainConfig
    from hardware.control_loop import ControlLoopConfig, LoopTiming

    for make, field in ((lambda: ACTConfig.from_preset("cpu", chunk_size=0), "chunk_size"),
                        (lambda: ACTConfig.from_dict({**tiny_config().to_dict(), "dim_model": "big"}), "dim_model"),
                        (lambda: ACTTrainConfig(lr=-1.0), "lr"), (lambda: EstimatorConfig(hidden=0), "hidden"),
                        (lambda: EstimatorConfig.from_dict({"hidden": 0}), "hidden"),
                        (lambda: EstimatorTrainConfig(batch_size=0), "batch_size"), (lambda: DiTConfig(depth=0), "depth"),
                        (lambda: AutoencoderConfig(latent_channels=0), "latent_channels"),
                        (lambda: DiffusionConfig(default_steps=0), "default_steps"),
                        (lambda: PoseAdapterConfig(head_width=0), "head_width"),
                        (lambda: GeneratorConfig(image_size=(0, 0)), "image_size"),
                        (lambda: GeneratorTrainConfig(data="d", out="o", batch_size=0), "batch_size"),
                        (lambda: PoseTrainConfig(out="o", steps=0), "steps"), (lambda: LoopTiming(rate_hz=0), "rate_hz"),
                        (lambda: ControlLoopConfig(chunk_size=0), "chunk_size"),
                        (lambda: PipelineConfig(demos=0), "demos"), (lambda: PressPlan(presses=0), "presses")):
        with pytest.raises(ValueError) as info:
            make()
        assert str(info.value).startswith(field) and "\n" not in str(info.value), str(info.value)
    import pickle

    from controltac_il.config import one_line

    again = pickle.loads(pickle.dumps(info.value))  # a config refused in a worker process reaches the parent whole
    assert str(again) == str(info.value) and one_line(again, {"presses": "--presses"}).startswith("--presses: ")


def write_tiny_episodes(root: Path, n: int = 3, T: int = 10, cameras=("third_view", "wrist"),
                        sensors=("left", "right"), action_dim: int = 5) -> Path:
    rng = np.random.default_rng(0)
    for i in range(n):
        write_episode(root / f"episode_{i}.hdf5", Episode(
            qpos=rng.normal(size=(T, 5)), action=rng.normal(size=(T, action_dim)),
            images={c: rng.integers(0, 255, (T, 24, 32, 3), dtype=np.uint8) for c in cameras},
            tactile={s: rng.integers(0, 255, (T, 24, 32, 3), dtype=np.uint8) for s in sensors},
            tactile_background={s: np.full((24, 32, 3), 100, np.uint8) for s in sensors}, sim=True))
    return root


def test_split_is_by_episode_and_config_comes_from_the_data(tmp_path):
    root = write_tiny_episodes(tmp_path / "demos", n=5)
    data = load_training_data(root, chunk_size=4, val_fraction=0.2, stats_path=tmp_path / "stats.json")
    assert data.n_episodes == 5 and data.val_episodes == 1
    train_eps = {data.train[i]["episode_index"] for i in range(len(data.train))}
    val_eps = {data.val[i]["episode_index"] for i in range(len(data.val))}
    assert not train_eps & val_eps and len(train_eps | val_eps) == 5
    episodes, frames = data.train.frame_table()  # what ForceAugment reads instead of loading images
    assert [(int(e), int(f)) for e, f in zip(episodes, frames)] == [
        (data.train[i]["episode_index"], data.train[i]["frame_index"]) for i in range(len(data.train))]
    assert data.spec == DataSpec(("third_view", "wrist"), ("left", "right"), 5, 5)
    assert np.array_equal(data.backgrounds["left"], np.full((24, 32, 3), 100, np.uint8))


def test_checkpoint_is_checked_against_the_data(tmp_path):
    cfg = ACTConfig(camera_names=("third_view", "wrist"), tactile_names=("left", "right"))
    check_compatible(cfg, DataSpec(("third_view", "wrist"), ("left", "right"), 5, 5))
    with pytest.raises(ValueError, match=r"images/wrist"):
        check_compatible(cfg, DataSpec(("third_view",), ("left", "right"), 5, 5))
    with pytest.raises(ValueError, match=r"tactile/right"):
        check_compatible(cfg, DataSpec(("third_view", "wrist"), ("left",), 5, 5))
    with pytest.raises(ValueError, match="actions of dimension 7"):
        check_compatible(cfg, DataSpec(("third_view", "wrist"), ("left", "right"), 5, 7))


def test_train_on_folder_end_to_end(tmp_path):
    root = write_tiny_episodes(tmp_path / "demos", n=3)
    summary = train_on_folder(root, tmp_path / "run", preset="cpu", train_config=ACTTrainConfig(steps=4, batch_size=4,
                              val_every=2), val_fraction=0.34, stats_path=tmp_path / "stats.json", progress=False,
                              **TINY)
    assert summary["steps"] == 4 and summary["episodes"] == 3 and summary["val_episodes"] == 1
    model, backgrounds, meta = load_checkpoint(resolve_checkpoint(tmp_path / "run"))
    assert model.config.camera_names == ("third_view", "wrist") and set(backgrounds) == {"left", "right"}
    assert not any(p.name.endswith(".json") for p in root.iterdir())  # the user's data folder is untouched


def test_a_run_without_validation_writes_standard_json_and_resumes(tmp_path):
    """No validation episode: best_val_l1 is null, never Infinity (not JSON), and --resume reads it back."""
    root = write_tiny_episodes(tmp_path / "demos", n=2)
    kwargs = dict(preset="cpu", val_fraction=0.0, stats_path=tmp_path / "stats.json", progress=False, **TINY)
    first = train_on_folder(root, tmp_path / "run", train_config=ACTTrainConfig(steps=2, batch_size=2), **kwargs)
    assert first["best_val_l1"] is None

    def strict(name):
        raise ValueError(f"{name} is not JSON")

    for f in (tmp_path / "run").rglob("*.json"):
        assert json.loads(f.read_text(), parse_constant=strict) is not None, f
    assert json.loads((tmp_path / "run" / "train_log.json").read_text())["best_val_l1"] is None
    again = train_on_folder(root, tmp_path / "run", train_config=ACTTrainConfig(steps=3, batch_size=2), resume=True,
                            **kwargs)
    assert again["steps"] == 3 and again["best_val_l1"] is None


def test_train_cli_reports_bad_input(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("CONTROLTAC_CACHE", str(tmp_path / "cache"))  # normalisation stats go there
    from controltac_il.app import train_cli as train_act

    assert train_act.main(["--dataset", str(tmp_path / "nowhere"), "--out", str(tmp_path / "run")]) == 2
    assert "not found" in capsys.readouterr().err
    root = write_tiny_episodes(tmp_path / "demos", n=2)
    assert train_act.main(["--dataset", str(root), "--out", str(tmp_path / "run"), "--steps", "0"]) == 2
    assert "steps" in capsys.readouterr().err
    assert train_act.main(["--dataset", str(root), "--out", str(tmp_path / "run"), "--resume"]) == 2
    assert "no checkpoint" in capsys.readouterr().err
    # a preset name stays a name (a Path would look for a folder called "quality" here)
    assert train_act.parse_args(["--augment", "force", "--generator", "quality"]).generator == "quality"


@pytest.mark.slow  # two torch processes and gloo (9 s); the data-parallel path with -m slow
@pytest.mark.skipif(sys.platform != "linux", reason="torchrun smoke test runs on Linux")
def test_torchrun_two_process_gloo_smoke(tmp_path):
    root = write_tiny_episodes(tmp_path / "demos", n=4)
    env = dict(os.environ, CONTROLTAC_CACHE=str(tmp_path / "cache"), OMP_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
           str(REPO / "train_act.py"), "--dataset", str(root), "--out", str(tmp_path / "run"), "--steps", "3",
           "--batch-size", "2", "--chunk-size", "4", "--val-every", "3", "--threads", "1"]
    proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    _, _, meta = load_checkpoint(tmp_path / "run" / "last")
    assert meta["world_size"] == 2 and meta["step"] == 3


# -- never destroy what the user owns, never compute on garbage ---------------------------------

def test_out_holding_a_run_is_refused_without_resume_or_overwrite(tmp_path):
    from controltac_il.outputs import OutputInUse

    ds, cfg = SyntheticACTDataset(16), tiny_config()
    train(cfg, ACTTrainConfig(steps=2, batch_size=8, val_every=2), ds, ds, tmp_path / "run", stats=ds.stats(),
          progress=False)
    before = tree_bytes(tmp_path / "run")
    with pytest.raises(OutputInUse, match=r"run.*--resume.*--overwrite"):
        train(cfg, ACTTrainConfig(steps=3, batch_size=8), ds, ds, tmp_path / "run", stats=ds.stats(), progress=False)
    assert tree_bytes(tmp_path / "run") == before
    (tmp_path / "run" / "my_notes.txt").write_text("mine")  # a file of the user's beside the run is kept
    summary = train(cfg, ACTTrainConfig(steps=3, batch_size=8, val_every=3), ds, None, tmp_path / "run",
                    stats=ds.stats(), overwrite=True, progress=False)
    assert summary["steps"] == 3 and load_checkpoint(tmp_path / "run" / "last")[2]["step"] == 3
    assert not (tmp_path / "run" / "best").exists()  # the replaced run's best/ is not passed off as this run's
    assert (tmp_path / "run" / "my_notes.txt").read_text() == "mine"


def test_out_of_the_users_own_is_never_deleted_even_with_overwrite(tmp_path):
    from controltac_il.outputs import OutputInUse

    ds, cfg = SyntheticACTDataset(16), tiny_config()
    out = tmp_path / "mine"
    for sub in ("best", "last"):
        (out / sub).mkdir(parents=True)
        (out / sub / "notes.txt").write_text("my notes")
    (out / "train_log.json").write_text('{"mine": true}')
    before = tree_bytes(out)
    for kwargs in ({}, {"overwrite": True}, {"resume": True}):
        with pytest.raises(ValueError, match=str(out)):
            train(cfg, ACTTrainConfig(steps=2, batch_size=8), ds, None, out, stats=ds.stats(), progress=False, **kwargs)
        assert tree_bytes(out) == before, kwargs
    with pytest.raises(OutputInUse, match="not written by"):
        train(cfg, ACTTrainConfig(steps=2, batch_size=8), ds, None, out, stats=ds.stats(), overwrite=True,
              progress=False)


class _PoisonAfter(torch.utils.data.Dataset):
    """``ds`` whose actions become NaN after ``good`` items were read (a diverging run, deterministically)."""

    def __init__(self, ds, good):
        self.ds, self.good, self.reads = ds, good, 0

    def __len__(self):
        return len(self.ds)

    def __getitem__(self, i):
        item = dict(self.ds[i])
        self.reads += 1
        if self.reads > self.good:
            item["action"] = torch.full_like(item["action"], float("nan"))
        return item


def test_nonfinite_loss_stops_the_run_and_keeps_the_last_good_checkpoint(tmp_path):
    from controltac_il.training import NonFiniteLoss

    ds, cfg = SyntheticACTDataset(16), tiny_config()
    with pytest.raises(NonFiniteLoss, match=r"step 3.*last.*step 2"):
        train(cfg, ACTTrainConfig(steps=10, batch_size=8, save_every=2), _PoisonAfter(ds, 16), None, tmp_path,
              stats=ds.stats(), progress=False)
    model, _, meta = load_checkpoint(tmp_path / "last")  # verified: finite weights
    assert meta["step"] == 2


class _InterruptAt(torch.utils.data.Dataset):
    """``ds`` that sends this process SIGINT (Ctrl-C) while item ``at`` is read."""

    def __init__(self, ds, at):
        self.ds, self.at, self.reads = ds, at, 0

    def __len__(self):
        return len(self.ds)

    def __getitem__(self, i):
        self.reads += 1
        if self.reads == self.at:
            import signal
            os.kill(os.getpid(), signal.SIGINT)
        return self.ds[i]


def test_ctrl_c_saves_the_current_step_before_stopping(tmp_path):
    from controltac_il.training import TrainingInterrupted

    ds, cfg = SyntheticACTDataset(16), tiny_config()
    with pytest.raises(KeyboardInterrupt) as info:  # during step 3 (items 17-24): step 3 is finished and saved
        train(cfg, ACTTrainConfig(steps=100, batch_size=8, save_every=50), _InterruptAt(ds, 20), None, tmp_path,
              stats=ds.stats(), progress=False)
    assert isinstance(info.value, TrainingInterrupted) and "step 3" in str(info.value)
    assert load_checkpoint(tmp_path / "last")[2]["step"] == 3
    assert json.loads((tmp_path / "train_log.json").read_text())["step"] == 3
    summary = train(cfg, ACTTrainConfig(steps=5, batch_size=8, save_every=50), ds, None, tmp_path, stats=ds.stats(),
                    resume=True, progress=False)
    assert summary["steps"] == 5


def test_resume_refuses_another_dataset_naming_what_differs(tmp_path):
    ds, cfg = SyntheticACTDataset(16), tiny_config()
    train(cfg, ACTTrainConfig(steps=2, batch_size=8), ds, None, tmp_path, stats=ds.stats(), progress=False)
    before = tree_bytes(tmp_path)
    other = SyntheticACTDataset(16, seed=5)
    with pytest.raises(CheckpointError, match=r"another dataset.*action mean"):
        train(cfg, ACTTrainConfig(steps=4, batch_size=8), other, None, tmp_path, stats=other.stats(), resume=True,
              progress=False)
    assert tree_bytes(tmp_path) == before  # stats.json is not replaced


def test_chunk_size_longer_than_every_episode_is_refused(tmp_path):
    root = write_tiny_episodes(tmp_path / "demos", n=2, T=10)
    with pytest.raises(ValueError, match=r"chunk_size.*--chunk-size.*10"):
        train_on_folder(root, tmp_path / "run", preset="cpu", train_config=ACTTrainConfig(steps=1, batch_size=2),
                        stats_path=tmp_path / "stats.json", progress=False, **{**TINY, "chunk_size": 11})


@pytest.mark.parametrize("flags, named", [
    (["--steps", "0"], "--steps"), (["--batch-size", "-4"], "--batch-size"), (["--val-fraction", "1.5"], "--val-fraction"),
    (["--checkpoint-every", "0"], "--checkpoint-every"), (["--val-every", "-1"], "--val-every"),
    (["--chunk-size", "0"], "--chunk-size"), (["--workers", "-1"], "--workers"), (["--copies", "0", "--augment", "force"], "--copies"),
    (["--copies", "3"], "--copies 3: ForceAugment's copies per episode, used only with --augment force"),
    (["--generator", "fast"], "--generator fast: ForceAugment's generator, used only with --augment force"),
    (["--seed", "-1"], "--seed"), (["--demos", "5"], "--demos 5: the embedded demos' count, not used with --dataset"),
])
def test_train_cli_validation_errors_are_one_line_naming_the_flag(tmp_path, capsys, monkeypatch, flags, named):
    monkeypatch.setenv("CONTROLTAC_CACHE", str(tmp_path / "cache"))
    from controltac_il.app import train_cli as train_act

    root = write_tiny_episodes(tmp_path / "demos", n=2)
    assert train_act.main(["--dataset", str(root), "--out", str(tmp_path / "run"), *flags]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and named in err[0], err
    assert not (tmp_path / "run").exists()


def test_train_cli_data_errors_are_one_line_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("CONTROLTAC_CACHE", str(tmp_path / "cache"))
    from controltac_il.app import train_cli as train_act

    root = write_tiny_episodes(tmp_path / "demos", n=3)
    (root / "episode_2.hdf5").write_bytes(b"not an hdf5 file")
    assert train_act.main(["--dataset", str(root), "--out", str(tmp_path / "run"), "--steps", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("train_act.py: error:") and "episode_2.hdf5" in err
    out = tmp_path / "mine"
    (out / "best").mkdir(parents=True)
    (out / "best" / "notes.txt").write_text("mine")
    assert train_act.main(["--dataset", str(root), "--out", str(out), "--overwrite"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "notes.txt" in err and (out / "best" / "notes.txt").read_text() == "mine"


def test_a_resumed_run_is_bit_identical_to_the_uninterrupted_one_with_an_augmentation_stage(tmp_path):
    """Batches (StepBatches) and dropout / CVAE noise (seed_update) are functions of the step: stopping at step 3
    and resuming to 7 (crossing an epoch) gives the very weights of a run trained to 7 at once."""
    from controltac_il.augment import ForceAugmentStage
    from policies.act.checkpoint import WEIGHTS_FILE

    root = write_tiny_episodes(tmp_path / "demos", n=3)
    stage = ForceAugmentStage(1, cache_dir=tmp_path / "cache")
    opts = dict(preset="cpu", augment=stage, split_seed=0, progress=False, **{**TINY, "dropout": 0.2})

    def cfg(steps):
        return ACTTrainConfig(steps=steps, batch_size=4, save_every=3, val_every=100, seed=5)

    train_on_folder(root, tmp_path / "once", train_config=cfg(7), **opts)
    train_on_folder(root, tmp_path / "twice", train_config=cfg(3), **opts)
    train_on_folder(root, tmp_path / "twice", train_config=cfg(7), resume=True, **opts)
    once, twice = ((tmp_path / r / "last" / WEIGHTS_FILE).read_bytes() for r in ("once", "twice"))
    assert once == twice
    other = ACTTrainConfig(steps=7, batch_size=4, save_every=3, val_every=100, seed=6)
    train_on_folder(root, tmp_path / "seed6", train_config=other, **opts)
    assert (tmp_path / "seed6" / "last" / WEIGHTS_FILE).read_bytes() != once  # the seed does matter


def test_step_batches_resume_mid_epoch_and_shard_without_overlap():
    from controltac_il.training import StepBatches

    full = StepBatches(10, 3, seed=1)
    it = iter(full)
    first = [next(it) for _ in range(7)]  # 3 batches an epoch (the last, incomplete one dropped)
    epoch = sum(first[:3], [])  # 9 distinct indices of 10: the incomplete last batch is dropped
    assert [len(b) for b in first] == [3] * 7 and len(set(epoch)) == 9 and set(epoch) < set(range(10))
    assert first[:3] != first[3:6]  # a new order each epoch
    resumed = iter(StepBatches(10, 3, seed=1, start=4))
    assert [next(resumed) for _ in range(3)] == first[4:7]
    shards = [next(iter(StepBatches(10, 5, seed=1, rank=r, world=2, drop_last=True))) for r in (0, 1)]
    assert not set(shards[0]) & set(shards[1]) and len(shards[0]) == 5
    with pytest.raises(ValueError, match="StepBatches"):
        StepBatches(0, 3, seed=1)
