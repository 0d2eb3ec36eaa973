"""controltac_il.streams: the stream names of each vocabulary (file formats: they must never change) and the
mappings between them."""

import re

import pytest

from controltac_il import streams
from controltac_il.streams import (HDF5, HDF5_STATE, LEROBOT, LEROBOT_STATE, LOOP, LOOP_STATE, background_key,
                                   force_key, image_key, lerobot_name, lerobot_to_hdf5, looks_tactile, loop_to_hdf5,
                                   parse, rule_key, sensor_of, tactile_key)

NAMES = ("left", "gelsight_left", "gs.mini.left")


def test_the_names_of_each_vocabulary():
    assert [LOOP_STATE, HDF5_STATE, LEROBOT_STATE] == ["qpos", "observation.qpos", "observation.state"]
    assert [image_key("wrist", v) for v in (LOOP, HDF5, LEROBOT)] == [
        "images/wrist", "observation.images.wrist", "observation.images.wrist"]
    assert [tactile_key("left", v) for v in (LOOP, HDF5, LEROBOT)] == [
        "tactile/left", "observation.tactile.left", "observation.images.left"]
    assert [background_key("left", v) for v in (LOOP, HDF5)] == [
        "tactile_background/left", "observation.tactile_background.left"]
    assert [force_key("left", v) for v in (LOOP, HDF5, LEROBOT)] == [
        "force/left", "observation.force.left", "observation.left.force"]


def test_loop_and_hdf5_keys_map_to_each_other_exactly():
    pairs = {"qpos": "observation.qpos", "images/third_view": "observation.images.third_view",
             "tactile/gelsight_left": "observation.tactile.gelsight_left",
             "tactile_background/gs.mini.left": "observation.tactile_background.gs.mini.left",
             "force/left": "observation.force.left"}
    for loop, hdf5 in pairs.items():
        assert loop_to_hdf5(loop) == hdf5


@pytest.mark.parametrize("name", NAMES)
def test_round_trips_keep_a_name_with_dots_or_underscores(name):
    for key_of in (image_key, tactile_key, background_key, force_key):
        assert loop_to_hdf5(key_of(name, LOOP)) == key_of(name, HDF5)
        assert sensor_of(key_of(name, LOOP)) == sensor_of(key_of(name, HDF5)) == name
    assert parse(tactile_key(name, LOOP)) == (LOOP, streams.TACTILE, name)
    assert parse(background_key(name, HDF5)) == (HDF5, streams.BACKGROUND, name)


def test_lerobot_features_map_to_hdf5_keys_exactly():
    assert lerobot_to_hdf5("observation.state") == "observation.qpos"
    assert lerobot_to_hdf5("observation.images.wrist") == "observation.images.wrist"
    assert lerobot_to_hdf5("observation.images.gelsight_left", tactile=True) == "observation.tactile.gelsight_left"
    assert lerobot_to_hdf5(tactile_key("gelsight_left", LEROBOT), tactile=True) == tactile_key("gelsight_left", HDF5)


def test_a_lerobot_feature_is_named_by_its_last_dotted_part():
    assert lerobot_name("observation.images.gelsight_left") == "gelsight_left"
    assert lerobot_name("observation.images.gs.mini.left") == "left"
    assert lerobot_to_hdf5("observation.images.gs.mini.left", tactile=True) == "observation.tactile.left"
    assert lerobot_to_hdf5("observation.gelsight") == "observation.images.gelsight"  # any camera feature


def test_the_naming_rule_of_force_labels_and_backgrounds():
    assert rule_key("observation.tactile.gs.left", "force") == "observation.force.gs.left"
    assert rule_key("observation.tactile.gs.left", "background") == "observation.tactile_background.gs.left"
    assert rule_key("tactile/left", "force") == "force/left"
    assert rule_key("observation.images.tactile_left", "force") == "observation.images.force_left"
    assert rule_key("observation.images.gelsight_left", "force") is None
    assert rule_key("observation.tactile_background.left", "force") is None
    assert looks_tactile("observation.tactile.left") and not looks_tactile("observation.tactile_background.left")
    with pytest.raises(ValueError, match="'label'"):
        rule_key("observation.tactile.left", "label")


@pytest.mark.parametrize("key", ["observation.imagesX", "images", "tactile/", "action", "observation.tactile"])
def test_an_unknown_key_is_refused_naming_it(key):
    for fn in (parse, sensor_of, loop_to_hdf5):
        with pytest.raises(ValueError, match=re.escape(repr(key))):
            fn(key)


def test_a_key_of_the_other_vocabulary_or_without_a_sensor_is_refused():
    with pytest.raises(ValueError, match="'observation.tactile.left' is not a loop key"):
        loop_to_hdf5("observation.tactile.left")
    with pytest.raises(ValueError, match="'qpos' is the arm's state"):
        sensor_of("qpos")
    with pytest.raises(ValueError, match="no tactile background"):
        background_key("left", LEROBOT)
    with pytest.raises(ValueError, match="'hdf'"):
        image_key("wrist", "hdf")
