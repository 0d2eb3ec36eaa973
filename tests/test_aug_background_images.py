"""A no-contact background given to ForceAugment as an image file (``background_images``): what a lab records of
its sensor at rest when its dataset holds no background (a LeRobot folder) or its episodes start in contact."""

import shutil

import cv2
import numpy as np
import pytest

from aug_fixtures import make_folder, synthetic_episode, tiny_estimator, tiny_generator
from lerobot_like import BG, FORCE, GEL, LeRobotLike, episodes

from controltac_il.augment import ForceAugment
from controltac_il.datasets import EpisodeDataset, read_background_image


@pytest.fixture(scope="module")
def gen():
    return tiny_generator()


def write_png(path, rgb):
    assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]))
    return path


@pytest.fixture
def rest(tmp_path):
    """The synthetic sensor's no-contact image (every episode's recorded background) as a PNG."""
    return write_png(tmp_path / "gelsight_rest.png", synthetic_episode(2, 0, ()).tactile_background["left"])


def wrap(ds, gen, **kw):
    return ForceAugment(ds, gen, copies=1, tactile_keys=[GEL], force_keys={GEL: FORCE}, progress=False, **kw)


@pytest.mark.parametrize("mode", ["cache", "online"])
def test_the_image_file_gives_the_frames_the_items_own_background_gives(gen, rest, tmp_path, mode):
    where = (lambda name: {"cache_dir": tmp_path / name}) if mode == "cache" else (lambda name: {"mode": "online"})
    items = wrap(LeRobotLike(episodes(), labels=True, backgrounds=True), gen, background_keys={GEL: BG}, **where("a"))
    given = wrap(LeRobotLike(episodes(), labels=True), gen, background_images={"gelsight": rest}, **where("b"))
    assert given.keys.images.keys() == {GEL}  # the sensor's name is taken for its key
    n = items.n_base
    assert len(given) == len(items) == 2 * n
    for i in range(n, len(items)):
        assert np.array_equal(given[i][GEL].numpy(), items[i][GEL].numpy()), i
    assert {r["background"] for r in given.plan()} == {"recorded"}


def test_the_cache_records_the_images_pixels_not_their_path(gen, rest, tmp_path):
    ds = LeRobotLike(episodes(), labels=True)
    moved = tmp_path / "moved.png"
    shutil.copy(rest, moved)
    first = wrap(ds, gen, background_images={GEL: rest}, mode="online").settings()["background_images"]
    assert wrap(ds, gen, background_images={GEL: moved}, mode="online").settings()["background_images"] == first
    edited = read_background_image(rest).copy()
    edited[0, 0, 0] += 1
    write_png(moved, edited)
    assert wrap(ds, gen, background_images={GEL: moved}, mode="online").settings()["background_images"] != first
    with pytest.warns(UserWarning, match="background estimated"):
        assert "background_images" not in wrap(ds, gen, mode="online").settings()


@pytest.mark.parametrize("mode", ["cache", "online"])
def test_an_image_beside_the_items_own_background_takes_its_place_in_the_frames_and_the_items(gen, tmp_path, mode):
    """Our episodes carry a recorded background (found by the naming rule): a given image replaces it in every
    item served, copy 0 included, so a policy subtracts the background the frames were generated on."""
    root = make_folder(tmp_path / "demos")
    dark = write_png(tmp_path / "dark.png", np.full((32, 32, 3), 60, np.uint8))
    ds = EpisodeDataset(root, chunk_size=2, stats_path=tmp_path / "stats.json")
    aug = ForceAugment(ds, gen, copies=1, background_images={"left": dark}, progress=False,
                       **({"cache_dir": tmp_path / "cache"} if mode == "cache" else {"mode": mode}))
    key = "observation.tactile_background.left"
    assert aug.keys.backgrounds["observation.tactile.left"] == key
    assert ds[0][key].float().mean() == 110  # the recorded one, left alone in the wrapped dataset
    for i in range(len(aug)):
        assert (aug[i][key] == 60).all() and aug[i][key].dtype == ds[0][key].dtype, i
    with pytest.raises(ValueError, match=r"^background_images: 'observation.tactile.left' also has background_keys"):
        ForceAugment(ds, gen, background_images={"left": dark}, background_keys={"observation.tactile.left": key},
                     mode="online")


def test_windows_take_the_image_as_they_take_the_items_background(gen, rest):
    deltas = {GEL: [-0.2, -0.1, 0.0]}
    items = wrap(LeRobotLike(episodes(), labels=True, backgrounds=True, delta_timestamps=deltas), gen,
                 background_keys={GEL: BG}, mode="online")
    given = wrap(LeRobotLike(episodes(), labels=True, delta_timestamps=deltas), gen,
                 background_images={GEL: rest}, mode="online")
    assert given.keys.offsets[GEL] == (-2, -1, 0) and given.keys.images.keys() == {GEL}
    for i in range(items.n_base + 2, items.n_base + 7):  # episode 0's contact frames, each window in contact
        assert np.array_equal(given[i][GEL].numpy(), items[i][GEL].numpy()), i


def test_a_jpeg_reads_as_rgb(tmp_path):
    rgb = np.zeros((16, 24, 3), np.uint8)
    rgb[..., 0] = 200  # red
    assert cv2.imwrite(str(tmp_path / "rest.jpg"), rgb[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 100])
    image = read_background_image(tmp_path / "rest.jpg")
    assert image.shape == (16, 24, 3) and np.abs(image.astype(int) - rgb).max() <= 2


def test_a_truncated_png_or_an_empty_path_is_refused_in_one_line_and_nothing_else_on_stderr(tmp_path, capfd):
    """OpenCV warns about a truncated PNG on the process's stderr itself; the refusal must be the only line."""
    ok, encoded = cv2.imencode(".png", np.full((16, 24, 3), 110, np.uint8))
    (tmp_path / "cut.png").write_bytes(encoded.tobytes()[: len(encoded) // 2])
    with pytest.raises(ValueError, match=r"^background_images: .*cut.png is not a readable image file"):
        read_background_image(tmp_path / "cut.png")
    with pytest.raises(ValueError, match=r"^--background-image: the image file's path is empty"):
        read_background_image("", "--background-image")
    assert capfd.readouterr().err == ""


@pytest.mark.parametrize("case, match", [
    ("missing", r"^background_images: .*nowhere.png is not a file"),
    ("not_an_image", r"^background_images: .*notes.png is not a readable image file"),
    ("empty", r"^background_images: .*empty.png is not a readable image file"),
    ("not_a_path", r"^background_images: 'observation.images.gelsight': expected an image file path, got 3"),
    ("empty_path", r"^background_images: 'observation.images.gelsight': expected an image file path, got ''"),
    ("empty_key", r"^background_images: expected \{tactile sensor: image file path\}, got the key ''"),
    ("grey", r"^background_images: .*grey.png is uint8 with 1 channel\(s\); expected an 8-bit RGB image"),
    ("sixteen_bit", r"^background_images: .*deep.png is uint16 with 3 channel\(s\)"),
    ("wrong_size", r"^background_images: the image for 'observation.images.gelsight' is 33x32 \(W x H\); its frames "
                   r"are 32x32"),
    ("unknown_key", r"^background_images: 'wrist' is not a tactile sensor of the data; those are "
                    r"\['observation.images.gelsight'\]"),
    ("not_a_dict", r"^background_images: expected \{tactile sensor: image file path\}, got list"),
])
def test_a_bad_background_image_is_refused_naming_the_setting_and_the_file(gen, rest, tmp_path, case, match):
    (tmp_path / "notes.png").write_text("not an image")
    (tmp_path / "empty.png").write_bytes(b"")
    write_png(tmp_path / "wide.png", np.full((32, 33, 3), 110, np.uint8))
    cv2.imwrite(str(tmp_path / "grey.png"), np.full((32, 32), 110, np.uint8))
    cv2.imwrite(str(tmp_path / "deep.png"), np.full((32, 32, 3), 110 * 256, np.uint16))
    given = {"missing": {GEL: tmp_path / "nowhere.png"}, "not_an_image": {GEL: tmp_path / "notes.png"},
             "grey": {GEL: tmp_path / "grey.png"}, "sixteen_bit": {GEL: tmp_path / "deep.png"},
             "wrong_size": {GEL: tmp_path / "wide.png"}, "unknown_key": {"wrist": rest},
             "not_a_dict": [rest], "empty": {GEL: tmp_path / "empty.png"}, "not_a_path": {GEL: 3},
             "empty_path": {GEL: ""}, "empty_key": {"": rest}}[case]
    with pytest.raises(ValueError, match=match):
        wrap(LeRobotLike(episodes(), labels=True), gen, background_images=given, mode="online")


def test_frames_without_labels_use_the_given_background_for_contact_and_the_estimator(gen, tmp_path):
    """An episode that starts in contact has no frame to estimate a background from; the given one finds
    its contact where the estimate (taken from contact frames) finds almost none."""
    always = {0: synthetic_episode(6, 0, range(0, 6), labels=False)}
    rest = write_png(tmp_path / "rest.png", always[0].tactile_background["left"])
    kw = dict(copies=1, tactile_keys=[GEL], mode="online", estimator=tiny_estimator(), progress=False)
    with pytest.warns(UserWarning, match="background estimated"):
        estimated = ForceAugment(LeRobotLike(always), gen, **kw).summary()
    given = ForceAugment(LeRobotLike(always), gen, background_images={GEL: rest}, **kw).summary()
    assert given["no_contact"] == 0 < estimated["no_contact"] == estimated["tactile_frames"] == 6


def test_the_command_on_episodes_without_backgrounds_takes_the_image_with_no_estimate(gen, tmp_path, monkeypatch):
    """ACT episodes recorded without a background: the image stands for it in the dataset the command opens, so no
    episode is estimated (nor warned about), and the cache records the image."""
    import warnings

    from controltac_il.augment import main
    from controltac_il.generator.checkpoint import save_checkpoint

    monkeypatch.setenv("CONTROLTAC_CACHE", str(tmp_path / "home-cache"))
    root = make_folder(tmp_path / "demos", background=False)
    rest = write_png(tmp_path / "rest.png", synthetic_episode(2, 0, ()).tactile_background["left"])
    ckpt = save_checkpoint(tmp_path / "gen", gen.config, gen.autoencoder, gen.denoiser)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an estimate would warn
        assert main(["--dataset", str(root), "--out", str(tmp_path / "cache"), "--copies", "1", "--generator",
                     str(ckpt), "--steps", "1", "--background-image", f"left={rest}"]) == 0
    manifest = next((tmp_path / "cache").glob("*.json"))
    assert "background_images" in manifest.read_text()
