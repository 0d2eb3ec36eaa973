"""``python -m controltac_il.augment``: builds the same cache as the wrapper, resumes, shards by RANK/WORLD_SIZE."""

import shutil

import pytest

from controltac_il.augment import ForceAugment, main  # noqa: E402
from controltac_il.datasets import EpisodeDataset  # noqa: E402
from controltac_il.generator import ForceGenerator  # noqa: E402
from controltac_il.generator.checkpoint import save_checkpoint  # noqa: E402

from aug_fixtures import make_folder, tiny_generator  # noqa: E402
from files import tree_bytes  # noqa: E402


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
    capsys.readouterr()
    assert run_cli(root, ckpt, tmp_path / "cli", "--seed", "3") == 2  # a stale cache: refused, one line
    err = capsys.readouterr().err
    assert "--out" in err and "seed: cache has 0, now 3" in err and len(err.strip().splitlines()) == 1
    assert tree_bytes(tmp_path / "cli") == clean


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


def one_line_error(capsys, code, *names):
    """A refused command: exit 2, one line on stderr naming ``names``, no traceback."""
    err = capsys.readouterr().err
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for n in names:
        assert n in err, (n, err)
    return err


@pytest.mark.parametrize("extra, names", [
    (["--copies", "0"], ["--copies", ">= 1"]),
    (["--copies", "x"], ["--copies", "int"]),
    (["--offset-range", "5", "1"], ["--offset-range", "low 5"]),
    (["--offset-range", "nan", "1"], ["--offset-range", "finite"]),
    (["--jitter", "inf"], ["--jitter", "finite"]),
    (["--offset-range", "1e9", "2e9"], ["--offset-range", "within +-10 N"]),  # every target would be clamped
    (["--jitter", "0", "1e12"], ["--jitter", "within +-10 N"]),
    (["--target-range", "1e9", "2e9"], ["--target-range", "<= 10 N"]),
    (["--seed", "-1"], ["--seed", ">= 0"]),
    (["--steps", "0"], ["--steps", ">= 1"]),
    (["--batch-size", "0"], ["--batch-size", ">= 1"]),
    (["--contact-force", "-1"], ["--contact-force", ">= 0"]),
    (["--min-contact-area", "2"], ["--min-contact-area", "[0, 1)"]),
    (["--tactile-keys", "right"], ["--tactile-keys", "right"]),
    (["--out-of-range", "wrap"], ["--out-of-range", "clamp"]),
    (["--generator", "nowhere"], ["--generator", "nowhere"]),
    (["--estimator", "nowhere"], ["--estimator", "nowhere"]),
    (["--device", "banana"], ["--device", "banana"]),
    (["--video-round-trip"], ["--video-round-trip", "LeRobot folder's output"]),
    (["--export-workers", "2"], ["--export-workers", "ACT episodes"]),
    (["--pose-adapter", "pose"], ["--pose-adapter", "only with --pose-offset"]),
])
def test_cli_bad_flags_are_one_line_errors(setup, tmp_path, capsys, extra, names):
    root, ckpt = setup
    code = main(["--dataset", str(root), "--out", str(tmp_path / "c"), "--generator", str(ckpt), "--steps", "1",
                 "--copies", "2", *extra])
    one_line_error(capsys, code, *names)
    assert not (tmp_path / "c").exists()  # nothing written


def test_cli_bad_dataset_and_out_are_one_line_errors(setup, tmp_path, capsys):
    root, ckpt = setup
    base = ["--generator", str(ckpt), "--steps", "1", "--copies", "1"]
    one_line_error(capsys, main(["--dataset", str(tmp_path / "nowhere"), "--out", str(tmp_path / "c"), *base]),
                   "--dataset", "nowhere")
    (tmp_path / "empty").mkdir()
    one_line_error(capsys, main(["--dataset", str(tmp_path / "empty"), "--out", str(tmp_path / "c"), *base]),
                   "--dataset", "episode_")
    (tmp_path / "file").write_text("x")
    one_line_error(capsys, main(["--dataset", str(root), "--out", str(tmp_path / "file"), *base]), "--out")
    one_line_error(capsys, main(["--dataset", str(root), *base]), "--out")  # argparse's own errors too
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    one_line_error(capsys, main(["--dataset", str(root), "--out", str(mine), *base]), "--out", "manifest")
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]
    before = tree_bytes(root)
    for out in (root / "cache", root, tmp_path):  # inside the episodes' folder, the folder itself, around it
        one_line_error(capsys, main(["--dataset", str(root), "--out", str(out), *base]), "--out", "inside it or around")
    assert tree_bytes(root) == before


def test_cli_cache_without_manifest_or_with_a_foreign_chunk(setup, tmp_path, capsys):
    root, ckpt = setup
    assert run_cli(root, ckpt, tmp_path / "c") == 0
    chunk = tmp_path / "c" / "chunks" / "e000000_k001" / "provenance.json"
    text = chunk.read_text()
    chunk.write_text(text.replace('"generator_hash": "', '"generator_hash": "0123'))
    capsys.readouterr()
    one_line_error(capsys, run_cli(root, ckpt, tmp_path / "c"), "--out", "e000000_k001", "generator_hash")
    chunk.write_text(text)
    (tmp_path / "c" / "manifest.json").unlink()
    one_line_error(capsys, run_cli(root, ckpt, tmp_path / "c", "--seed", "7"), "--out", "manifest")
    assert not (tmp_path / "c" / "manifest.json").exists()  # not re-stamped


def test_cli_ctrl_c_says_how_to_resume(setup, tmp_path, capsys, monkeypatch):
    root, ckpt = setup
    real = ForceAugment.build_cache

    def interrupted(self, *a, **k):
        real(self, *a, stop_after=1, **k)
        raise KeyboardInterrupt

    monkeypatch.setattr(ForceAugment, "build_cache", interrupted)
    assert run_cli(root, ckpt, tmp_path / "c") == 130
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "interrupted" in err and "re-run the same command to resume" in err
    monkeypatch.setattr(ForceAugment, "build_cache", real)
    assert run_cli(root, ckpt, tmp_path / "c") == 0
    assert run_cli(root, ckpt, tmp_path / "clean") == 0
    assert tree_bytes(tmp_path / "c") == tree_bytes(tmp_path / "clean")


def test_a_generator_whose_output_is_inf_stops_the_build_with_one_line_and_exit_1(setup, tmp_path, capsys,
                                                                                monkeypatch):
    """A fault of the run (the checkpoint decodes inf), not of the input: exit 1, one line, no chunk written."""
    from controltac_il.generator.autoencoder import TactileAutoencoder

    root, ckpt = setup
    decode = TactileAutoencoder.decode
    monkeypatch.setattr(TactileAutoencoder, "decode", lambda self, z: decode(self, z) + float("inf"))
    assert run_cli(root, ckpt, tmp_path / "c") == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("python -m controltac_il.augment: error: the generator's output holds "
                                               "NaN or inf values (float32 on cpu)")
    assert not list((tmp_path / "c").glob("chunks/*"))
