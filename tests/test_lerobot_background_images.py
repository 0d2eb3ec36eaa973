"""A LeRobot folder records no tactile background: ``--background-image`` gives the one a lab recorded of its sensor
at rest, to the augment command (ForceAugment's ``background_images``) and to train_act.py (``LeRobotEpisodes``,
and ``EpisodeDataset`` for ACT episodes, whose items and checkpoint carry it). The source folder: lerobot_fixtures."""

import json
import warnings

import cv2
import numpy as np
import pytest
import torch

from controltac_il.augment import ForceAugment, main
from controltac_il.lerobot import LeRobotEpisodes, LeRobotFolder, read_record
from aug_fixtures import make_folder
from lerobot_fixtures import FORCES, H, LEFT, RIGHT, W


def write_png(path, rgb):
    assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]))
    return path


@pytest.fixture
def rest(tmp_path):
    """gelsight_left's gel at rest, without the noise of its recorded frames."""
    return write_png(tmp_path / "left_rest.png", np.full((H, W, 3), (100, 110, 120), np.uint8))


def test_the_command_uses_the_image_and_records_its_digest(written, rest, tmp_path, capsys):
    from controltac_il.generator.checkpoint import save_checkpoint

    root, _, _, reference = written
    g = reference.generator
    ckpt = save_checkpoint(tmp_path / "gen", g.config, g.autoencoder, g.denoiser)
    base = ["--dataset", str(root), "--generator", str(ckpt), "--steps", "1", "--copies", "1"]
    assert main([*base, "--out", str(tmp_path / "out"), "--background-image", f"gelsight_left={rest}"]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # gelsight_right's background is estimated
        wrapper = ForceAugment(LeRobotFolder(root), g, tactile_keys=[LEFT, RIGHT], force_keys=FORCES, copies=1,
                               steps=1, background_images={LEFT: rest}, mode="online", progress=False)
    settings = read_record(tmp_path / "out")["settings"]
    assert settings["background_images"] == wrapper.settings()["background_images"]
    assert list(settings["background_images"]) == [LEFT]
    written_copy = LeRobotFolder(tmp_path / "out")
    n = len(LeRobotFolder(root))
    for i in range(n):  # copy 1 of frame i is output row n + i, the wrapper's item n + i
        assert np.array_equal(written_copy[n + i][LEFT].numpy(), wrapper[n + i][LEFT].numpy()), i
    capsys.readouterr()
    wide = write_png(tmp_path / "wide.png", np.full((H, W + 1, 3), 100, np.uint8))
    flag = "--background-image"
    for flags, expected in (([flag, "gelsight_left"], "--background-image: expected TACTILE_KEY=PNG pairs"),
                            ([flag, f"gelsight_left={tmp_path / 'none.png'}"], "--background-image: "),
                            ([flag, f"gelsight_left={wide}"], f"--background-image: the image for '{LEFT}' is 33x32"),
                            ([flag, f"wrist={rest}"],
                             "--background-image: 'wrist' is not a tactile sensor of the data"),
                            ([flag, f"gelsight_left={rest}", f"gelsight_left={wide}"],  # no value silently dropped
                             "--background-image: 'gelsight_left' is given twice"),
                            ([flag, f"gelsight_right={wide}", flag, f"gelsight_left={rest}"],  # the flag twice: both
                             f"--background-image: the image for '{RIGHT}' is 33x32")):
        assert main([*base, "--out", str(tmp_path / "bad"), *flags]) == 2, flags
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and expected in err, err
    assert not (tmp_path / "bad").exists()


def test_train_act_takes_the_image_for_its_items_and_checkpoint(written, rest, tmp_path, monkeypatch, capsys):
    from controltac_il.app import train_cli as train_act
    from policies.act.checkpoint import load_checkpoint

    root = written[0]
    monkeypatch.setenv("CONTROLTAC_CACHE", str(tmp_path / "cache"))
    with pytest.warns(UserWarning, match=r"estimated per episode from its no-contact frames for \['gelsight_right'\]"):
        ds = LeRobotEpisodes(root, chunk_size=4, background_images={"gelsight_left": rest})
    given = cv2.imread(str(rest))[..., ::-1]
    with pytest.warns(UserWarning, match="estimated per episode"):
        estimated = LeRobotEpisodes(root, chunk_size=4)
    for e in (0, 6):  # each episode's item: the given image, or the estimate without it
        assert np.array_equal(ds[e]["observation.tactile_background.gelsight_left"].permute(1, 2, 0).numpy(), given)
        left, right = (f"observation.tactile_background.gelsight_{s}" for s in ("left", "right"))
        assert torch.equal(ds[e][right], estimated[e][right]) and not torch.equal(ds[e][right], ds[e][left])
    flags = ["--steps", "1", "--batch-size", "2", "--chunk-size", "4", "--val-every", "1", "--threads", "1"]
    assert train_act.main(["--dataset", str(root), "--out", str(tmp_path / "run"), *flags,
                           "--background-image", f"{LEFT}={rest}"]) == 0
    _, backgrounds, _ = load_checkpoint(tmp_path / "run" / "last")
    assert np.array_equal(backgrounds["gelsight_left"], given)  # what deployment subtracts
    assert json.loads((tmp_path / "run" / "last" / "config.json").read_text())["act"]["tactile_names"] == [
        "gelsight_left", "gelsight_right"]
    capsys.readouterr()
    episodes = tmp_path / "episodes"
    episodes.mkdir()
    wide = write_png(tmp_path / "wide.png", np.full((H, W + 1, 3), 100, np.uint8))
    for args, expected in ((["--dataset", str(root), "--background-image", f"gelsight_left={tmp_path / 'no.png'}"],
                            "--background-image: "),
                           (["--dataset", str(root), "--background-image", f"gelsight_left={wide}"],
                            f"--background-image: the image for '{LEFT}' is 33x32"),
                           (["--dataset", str(root), "--background-image", f"wrist={rest}"],
                            "--background-image: 'wrist' is not a tactile sensor of the data"),
                           (["--dataset", str(episodes), "--tactile-keys", "left"],
                            "only with a LeRobot v3.0 --dataset")):
        assert train_act.main([*args, "--out", str(tmp_path / "bad"), *flags]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and expected in err, err
    hdf5 = make_folder(tmp_path / "hdf5")  # ACT episodes (sensor "left", 32 x 32) take the flag too
    dark = write_png(tmp_path / "dark.png", np.full((32, 32, 3), 60, np.uint8))
    assert train_act.main(["--dataset", str(hdf5), "--out", str(tmp_path / "run_h5"), *flags,
                           "--background-image", f"left={dark}"]) == 0
    assert (load_checkpoint(tmp_path / "run_h5" / "last")[1]["left"] == 60).all()
    capsys.readouterr()
    grey = write_png(tmp_path / "grey.png", np.full((32, 32, 3), 110, np.uint8))
    for other in (["--background-image", f"left={grey}"], []):  # another image, or none: never one run
        assert train_act.main(["--dataset", str(hdf5), "--out", str(tmp_path / "run_h5"), *flags, "--resume",
                               *other]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "was trained on other tactile backgrounds" in err, err


def test_the_image_is_part_of_the_datas_identity_and_named_once(written, rest, tmp_path):
    """A cache of ForceAugment copies over a training split of LeRobotEpisodes (train_act.py --augment force) is
    another cache when the items' background changes, or the split; a camera named twice is refused."""
    from controltac_il.datasets import EpisodeSubset

    root = written[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        plain = LeRobotEpisodes(root, chunk_size=4)
        given = LeRobotEpisodes(root, chunk_size=4, background_images={"observation.tactile.gelsight_left": rest})
        assert given.backgrounds[(0, "gelsight_left")].mean() != plain.backgrounds[(0, "gelsight_left")].mean()
        assert set(given.fingerprint()) - set(plain.fingerprint()) == {"background_images"}
        generator = written[3].generator
        first, second = list(range(5)), list(range(6, 11))  # five frames of episode 0, of episode 1: one length
        settings = [ForceAugment(EpisodeSubset(d, rows), generator, copies=1, mode="online", progress=False
                                 ).settings()["data"] for d, rows in ((plain, first), (given, first), (plain, second))]
    assert settings[0]["length"] == settings[2]["length"] and "root" not in settings[0]
    assert settings[0] != settings[1] and settings[0]["subset_sha256"] != settings[2]["subset_sha256"]
    with pytest.raises(ValueError, match=r"^background_images: 'gelsight_left' is named twice"):
        LeRobotEpisodes(root, background_images={"gelsight_left": rest, LEFT: rest})


def test_a_run_records_every_episodes_background_so_resume_tells_episode_0s_image_from_the_recorded_ones(
        tmp_path, capsys):
    """Saving episode 0's recorded background as the image and resuming with it changes what episodes 1.. train on:
    the digests cover every episode, so the resume is refused; a run that records only episode 0's digest is still
    checked by it."""
    import json

    from aug_fixtures import synthetic_episode

    from controltac_il.app import train_cli as train_act
    from controltac_il.datasets import write_episode
    from controltac_il.datasets.background import episode_background_digests

    for i, level in enumerate((110, 90)):
        ep = synthetic_episode(10, i, range(3, 8))
        ep.tactile_background["left"] = np.full_like(ep.tactile_background["left"], level)
        write_episode(tmp_path / "demos" / f"episode_{i}.hdf5", ep)
    ep0 = write_png(tmp_path / "ep0.png", np.full((32, 32, 3), 110, np.uint8))
    dark = write_png(tmp_path / "dark.png", np.full((32, 32, 3), 60, np.uint8))
    run = ["--dataset", str(tmp_path / "demos"), "--out", str(tmp_path / "run"), "--steps", "1", "--batch-size", "2",
           "--chunk-size", "4", "--val-every", "1", "--threads", "1"]
    assert train_act.main(run) == 0
    assert train_act.main([*run, "--resume", "--background-image", f"left={ep0}"]) == 2
    assert "was trained on other tactile backgrounds" in capsys.readouterr().err
    config = tmp_path / "run" / "last" / "config.json"  # as a run that records episode 0's digest alone
    doc = json.loads(config.read_text())
    del doc["meta"]["episode_backgrounds"]
    config.write_text(json.dumps(doc))
    assert train_act.main([*run, "--resume", "--background-image", f"left={dark}"]) == 2  # episode 0's digest alone
    assert "was trained on other tactile backgrounds" in capsys.readouterr().err
    a, b = (np.full((2, 2, 3), v, np.uint8) for v in (1, 2))
    digest = episode_background_digests
    assert digest({(0, "s"): a, (1, "s"): b}) == digest({(1, "s"): b, (0, "s"): a})  # in episode order
    assert digest({(0, "s"): a, (1, "s"): b}) != digest({(0, "s"): b, (1, "s"): a})
    with pytest.raises(ValueError, match=r"^backgrounds: episode 1's 's' is NoneType, not a uint8 \(H, W, 3\) image"):
        digest({(0, "s"): a, (1, "s"): None})
