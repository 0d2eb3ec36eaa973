"""``python -m controltac_il.augment``: builds the same cache as the wrapper, resumes, shards by RANK/WORLD_SIZE."""

import shutil

import pytest

pytest.importorskip("controltac_il.generator")
from controltac_il.augment import ForceAugment, main  # noqa: E402
from controltac_il.datasets import EpisodeDataset  # noqa: E402
from controltac_il.generator import ForceGenerator  # noqa: E402
from controltac_il.generator.checkpoint import save_checkpoint  # noqa: E402

from test_aug_force_augment import make_folder, tiny_generator, tree_bytes  # noqa: E402


@pytest.fixture
def setup(tmp_path, monkeypatch):
    monkeypatch.setenv("CONTROLTAC_CACHE", str(tmp_path / "home-cache"))  # stats of the CLI's dataset
    root = make_folder(tmp_path / "demos")
    g = tiny_generator()
    ckpt = save_checkpoint(tmp_path / "gen", g.config, g.autoencoder, g.denoiser)
    return root, ckpt


def run_cli(root, ckpt, out, *extra):
    return main(["--dataset", str(root), "--out", str(out), "--copies", "2", "--generator", str(ckpt),
                 "--steps", "1", *extra])


def test_cli_equals_wrapper_and_resumes(setup, tmp_path, capsys):
    root, ckpt = setup
    assert run_cli(root, ckpt, tmp_path / "cli") == 0
    assert "cache complete" in capsys.readouterr().out
    wrapper = ForceAugment(EpisodeDataset(root, chunk_size=20, stats_path=tmp_path / "s.json"),
                           ForceGenerator.from_pretrained(ckpt), copies=2, steps=1, cache_dir=tmp_path / "cli",
                           build="require", progress=False)  # same settings: the CLI's cache is accepted
    clean = tree_bytes(wrapper.cache_dir)
    shutil.rmtree(tmp_path / "cli" / "chunks" / "e000001_k002")  # as if interrupted before this chunk
    run_cli(root, ckpt, tmp_path / "cli")
    assert tree_bytes(tmp_path / "cli") == clean
    with pytest.raises(ValueError, match="seed: cache has 0, now 3"):
        run_cli(root, ckpt, tmp_path / "cli", "--seed", "3")


def test_cli_shards_by_torchrun_rank(setup, tmp_path, monkeypatch, capsys):
    root, ckpt = setup
    run_cli(root, ckpt, tmp_path / "one")
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("RANK", "1")
    run_cli(root, ckpt, tmp_path / "two")
    assert "left to other ranks" in capsys.readouterr().out
    monkeypatch.setenv("RANK", "0")
    run_cli(root, ckpt, tmp_path / "two")
    assert "cache complete" in capsys.readouterr().out
    assert tree_bytes(tmp_path / "two") == tree_bytes(tmp_path / "one")


def test_cli_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    out = capsys.readouterr().out
    assert exc.value.code == 0 and "--copies" in out and "torchrun" in out


def test_cli_flags_come_from_the_config(capsys):
    import dataclasses

    from controltac_il.augment import ForceAugmentConfig
    from controltac_il.augment.cli import parser

    flags = {f.name: f for f in dataclasses.fields(ForceAugmentConfig) if f.metadata["cli"] is not None}
    assert {"copies", "offset_range", "jitter", "out_of_range", "seed", "steps", "batch_size"} <= set(flags)
    args = parser().parse_args(["--dataset", "d", "--out", "o"])
    for name, f in flags.items():
        value = getattr(args, name)
        assert (tuple(value) if isinstance(value, list) else value) == f.default, name
    with pytest.raises(SystemExit):
        main(["--help"])
    out = " ".join(capsys.readouterr().out.split())
    for name, f in flags.items():
        assert "--" + name.replace("_", "-") in out and " ".join(f.metadata["help"].split())[:30] in out, name
