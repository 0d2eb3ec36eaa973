"""Sensor randomisation: the instance families and datasets rendered across instances."""

import numpy as np
import pytest

from controltac_il.generator.training.data import load_pair_data
from controltac_il.tactile import SensorSpec, TactileSensor
from controltac_il.tactile import dataset as tds
from controltac_il.tactile.instances import instance_by_name, sensor_instance

SIZE = (60, 80)


def test_families_are_deterministic_and_hold_out_the_unseen_look():
    assert sensor_instance("train", 0).spec == SensorSpec.gelsight_mini()  # the nominal sensor is in the family
    assert sensor_instance("train", 5) == sensor_instance("train", 5)
    train = [sensor_instance("train", i) for i in range(24)]
    unseen = [sensor_instance("unseen", i) for i in range(8)]
    looks = {(i.optics, i.spec.background) for i in train}
    assert looks == {("three_light", "gelsight_mini"), ("three_light", "digit"), ("polynomial", "gelsight_mini")}
    assert {(i.optics, i.spec.background) for i in unseen} == {("polynomial", "digit")}
    assert max(i.spec.optics_gain for i in train) <= 1.3 < 1.35 <= min(i.spec.optics_gain for i in unseen)
    assert len({i.spec for i in train}) == 24
    assert instance_by_name("unseen_03", SIZE) == sensor_instance("unseen", 3, SIZE)
    with pytest.raises(ValueError, match="sensor family"):
        sensor_instance("lab", 0)
    with pytest.raises(ValueError, match="not a sensor instance name"):
        instance_by_name("train-3")


def test_randomised_dataset_renders_each_pose_with_its_instance(tmp_path):
    spec = SensorSpec.gelsight_mini().scaled(*SIZE)
    root = tds.write_dataset(tmp_path / "r", objects=("cross", "big_sphere"), poses_per_object=4, forces_per_pose=2,
                             seed=1, spec=spec, progress=False, sensors="train", instances=3)
    ds = tds.load_dataset(root)
    assert ds.background is None and set(ds.backgrounds) == set(ds.meta["sensor_names"])
    for group in ds.pose_groups().values():
        assert len({ds.records[i].sensor for i in group}) == 1  # one sensor per contact pose: pairs share it
    r = ds.records[0]
    name, _, pose, forces, noise = next(tds.sample_contacts(("cross", "big_sphere"), 4, 2, 1, spec))
    inst = instance_by_name(r.sensor, SIZE)
    again = TactileSensor(inst.spec, optics=inst.optics).press(name, pose, forces[0], noise_seed=noise[0]).image
    np.testing.assert_array_equal(ds.image(0), again)  # the stored frame is exactly that instance's rendering
    np.testing.assert_array_equal(ds.background_of(0), ds.backgrounds[r.sensor])
    pairs = load_pair_data(root, (64, 80), no_contact_frames=3, seed=0, progress=False)
    assert pairs.residuals.shape == (len(ds) + 3, 64, 80, 3)
    (root / "backgrounds" / f"{r.sensor}.png").unlink()
    with pytest.raises(ValueError, match="without backgrounds/<sensor>.png"):
        tds.load_dataset(root)
    with pytest.raises(ValueError, match="sensors must be None or one of"):
        tds.write_dataset(tmp_path / "x", spec=spec, sensors="lab", progress=False)
