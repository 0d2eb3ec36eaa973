"""Sensor model: hard cases (numerical stability), monotonicity, conventions and bad input."""

import dataclasses

import numpy as np
import pytest

from controltac_il.tactile import (
    HELDOUT_OBJECTS, INDENTERS, TRAIN_OBJECTS, SensorSpec, TactileSensor, contact_mask, from_residual, to_residual,
)
from controltac_il.tactile import mechanics
from controltac_il.tactile.indenters import get_indenter, procedural_indenter, procedural_objects
from controltac_il.tactile.residual import residual_magnitude

FORCES = [0.0, 1e-6, 1.0, 10.0, 50.0]
SPEC = SensorSpec.gelsight_mini().scaled(120, 160)
QUIET = dataclasses.replace(SPEC, noise_std=0.0)

# (object, pose): contacts that break a naive sensor model, plus one ordinary contact
HARD_CASES = {
    "flat face, area jumps (cube face)": ("cube_face", (0.0, 0.0, 0.2)),
    "object larger than the pad": ("big_sphere", (0.0, 0.0, 0.0)),
    "half off the sensor edge": ("usb_c", (SPEC.pad_size_mm[1] / 2, 0.0, 0.0)),
    "very thin object": ("slim_cylinder", (1.0, -1.0, 0.7)),
    "sharp edge": ("cube_edge", (0.0, 0.0, 0.4)),
}


@pytest.fixture(scope="module")
def quiet_sensor():
    return TactileSensor(QUIET, optics="three_light")


@pytest.mark.parametrize("case", sorted(HARD_CASES))
@pytest.mark.parametrize("optics", ["three_light", "polynomial"])
def test_hard_cases_finite_converged_and_monotone(case, optics):
    obj, pose = HARD_CASES[case]
    sensor = TactileSensor(QUIET, optics=optics)
    areas, magnitudes = [], []
    for fz in FORCES:
        c = sensor.press(obj, pose, (0.0, 0.0, fz))
        for arr in (c.height_mm, c.penetration_mm, c.image):
            assert np.isfinite(arr.astype(np.float64)).all()
        assert abs(c.force[2] - fz) <= mechanics.FORCE_RTOL * fz + mechanics.FORCE_ATOL
        # the reached force is the model's force of the rendered penetration
        assert mechanics.normal_force(c.penetration_mm, QUIET) == pytest.approx(fz, rel=1e-3, abs=1e-6)
        areas.append(c.area_mm2)
        magnitudes.append(float(residual_magnitude(c.residual).mean()))
    assert all(b >= a for a, b in zip(areas, areas[1:])), areas
    assert all(b >= a - 1e-9 for a, b in zip(magnitudes, magnitudes[1:])), magnitudes
    assert areas[0] == 0.0 and areas[-1] > 0.0
    assert magnitudes[-1] > magnitudes[0]


def test_zero_force_is_the_background(quiet_sensor):
    c = quiet_sensor.press("big_sphere", (0, 0, 0), (0, 0, 0))
    assert c.depth_mm == 0.0 and c.iterations == 0 and not c.mask.any()
    np.testing.assert_array_equal(c.image, quiet_sensor.background)
    assert (c.residual == 127).all()


def test_cube_face_contact_area_jumps_to_full_pad(quiet_sensor):
    c = quiet_sensor.press("cube_face", (0, 0, 0.2), (0, 0, 1.0))
    pad_area = np.prod(SPEC.pad_size_mm)
    assert c.area_mm2 > 0.95 * pad_area


def test_every_object_renders_a_visible_contact_at_5n(quiet_sensor):
    for obj in TRAIN_OBJECTS + HELDOUT_OBJECTS:
        c = quiet_sensor.press(obj, (0.5, -0.5, 0.3), (0, 0, 5.0))
        if obj == "cube_face":  # larger than the pad: a faint uniform tint, no edges in view
            assert 0.5 < c.residual.astype(float).mean() - 127 < 12
        else:
            assert contact_mask(c.residual).sum() > 20, obj


def test_depth_grows_with_force_and_solver_is_not_fixed_step(quiet_sensor):
    depths = [quiet_sensor.press("big_sphere", (0, 0, 0), (0, 0, f)).depth_mm for f in (1, 2, 4, 8)]
    assert all(b > a for a, b in zip(depths, depths[1:]))
    # a Winkler sphere: F ∝ d² at small depth, so doubling F multiplies d by about √2
    assert depths[1] / depths[0] == pytest.approx(np.sqrt(2), rel=0.1)


def test_gel_surface_is_smooth_not_hard_imprint(quiet_sensor):
    c = quiet_sensor.press("cross", (0, 0, 0), (0, 0, 5.0))
    outside = ~c.mask
    assert (c.height_mm[outside] > 1e-3).any(), "the gel must slope down around the contact"
    assert c.height_mm.max() < c.penetration_mm.max()


def test_shear_moves_the_imprint_along_the_force(quiet_sensor):
    def centroid_x(fx):
        c = quiet_sensor.press("big_sphere", (0, 0, 0), (fx, 0.0, 5.0))
        w = c.height_mm
        return (w * np.arange(w.shape[1])).sum() / w.sum()

    assert centroid_x(1.0) > centroid_x(0.0) > centroid_x(-1.0)


def test_noise_is_seeded():
    s = TactileSensor(SPEC)
    a = s.press("cross", (0, 0, 0), (0, 0, 3), noise_seed=7).image
    b = s.press("cross", (0, 0, 0), (0, 0, 3), noise_seed=7).image
    c = s.press("cross", (0, 0, 0), (0, 0, 3), noise_seed=8).image
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_no_contact_residual_is_127_plus_noise():
    s = TactileSensor(SPEC)
    res = s.press("big_sphere", (0, 0, 0), (0, 0, 0), noise_seed=1).residual.astype(np.float64) - 127
    assert abs(res.mean()) < 0.3
    assert res.std() == pytest.approx(SPEC.noise_std, rel=0.2)


def test_residual_round_trip():
    rng = np.random.default_rng(0)
    bg = rng.integers(60, 200, size=(8, 10, 3), dtype=np.uint8)
    img = np.clip(bg.astype(int) + rng.integers(-100, 100, size=bg.shape), 0, 255).astype(np.uint8)
    res = to_residual(img, bg)
    assert res.dtype == np.uint8
    np.testing.assert_array_equal(from_residual(res, bg), img)  # exact within the ±127 range


@pytest.mark.parametrize("kwargs, says", [
    ({"threshold": "12"}, "threshold: expected grey levels in [0, 128) (a residual's magnitude is at most 128), "
                          "got '12'"),
    ({"threshold": 128}, "threshold: expected grey levels in [0, 128)"),
    ({"threshold": float("nan")}, "threshold: expected grey levels"),
    ({"threshold": -1.0}, "threshold: expected grey levels"),
    ({"min_pixels": 2.5}, "min_pixels: expected an int >= 0, got 2.5"),
    ({"min_pixels": -1}, "min_pixels: expected an int >= 0")])
def test_contact_mask_refuses_a_threshold_or_count_it_cannot_compare(kwargs, says):
    res = np.full((4, 5, 3), 127, np.uint8)
    assert contact_mask(res, threshold=np.float32(0.5), min_pixels=np.int64(0)).sum() == 0  # numpy scalars are fine
    with pytest.raises(ValueError) as exc:
        contact_mask(res, **kwargs)
    assert str(exc.value).startswith(says)


def test_render_penetration_matches_press(quiet_sensor):
    c = quiet_sensor.press("thin_cylinder", (0, 0, 0.5), (0.3, -0.2, 4.0))
    img = quiet_sensor.render_penetration(c.penetration_mm, shear=(0.3, -0.2))
    np.testing.assert_array_equal(img, c.image)


def test_scaled_keeps_the_pad():
    s = SensorSpec.gelsight_mini()
    half = s.scaled(120, 160)
    assert half.pad_size_mm == pytest.approx(s.pad_size_mm)
    assert half.mm_per_px == pytest.approx(2 * s.mm_per_px)


@pytest.mark.parametrize(
    "force, field",
    [((0, 0, -1.0), "Fz"), ((0, 0, np.nan), "finite"), ((0, 0), "3 components"), ("abc", "force"),
     ((1e38, 0, 5.0), r"within ±60 N per component"), ((0, 0, 4000.0), r"within ±60 N per component \(.*mN\?\)")],
)
def test_bad_force_is_rejected(quiet_sensor, force, field):
    with pytest.raises(ValueError, match=field):
        quiet_sensor.press("cross", (0, 0, 0), force)


def test_bad_object_pose_image_and_spec_are_rejected(quiet_sensor):
    with pytest.raises(ValueError, match="unknown object 'banana'.*cross"):
        quiet_sensor.press("banana")
    with pytest.raises(ValueError, match="pose"):
        quiet_sensor.press("cross", (0, np.inf, 0))
    with pytest.raises(ValueError, match="uint8"):
        to_residual(np.zeros((120, 160, 3), np.float32), quiet_sensor.background)
    with pytest.raises(ValueError, match="shape"):
        to_residual(np.zeros((100, 160, 3), np.uint8), quiet_sensor.background)
    with pytest.raises(ValueError, match="penetration_mm must have shape"):
        quiet_sensor.render_penetration(np.zeros((10, 10)))
    with pytest.raises(ValueError, match="penetration_mm must be finite"):
        quiet_sensor.render_penetration(np.full((120, 160), -1.0))
    with pytest.raises(ValueError, match="within ±60 N"):  # a shear of 1e38 N would make every height NaN
        quiet_sensor.render_penetration(np.zeros((120, 160)), shear=(1e38, 0.0))
    with pytest.raises(ValueError, match="foundation_modulus"):
        SensorSpec(foundation_modulus=0.0)
    with pytest.raises(ValueError, match="aspect ratio"):
        SensorSpec().scaled(128, 160)
    with pytest.raises(ValueError, match="optics"):
        TactileSensor(SPEC, optics="raytrace")


def test_inputs_are_not_modified(quiet_sensor):
    pen = np.zeros((120, 160), np.float32)
    pen[50:60, 70:90] = 0.4
    before = pen.copy()
    quiet_sensor.render_penetration(pen, shear=(0.5, 0.5))
    np.testing.assert_array_equal(pen, before)
    assert set(TRAIN_OBJECTS).isdisjoint(HELDOUT_OBJECTS) and len(INDENTERS) == 12


def test_sensor_instances_differ_in_background_and_stiffness():
    mini = TactileSensor(QUIET)
    digit = TactileSensor(dataclasses.replace(QUIET, background="digit"))
    assert digit.background.shape == mini.background.shape
    assert np.abs(digit.background.astype(int) - mini.background).mean() > 10
    soft = TactileSensor(dataclasses.replace(QUIET, foundation_modulus=0.2))
    assert soft.press("big_sphere", force=(0, 0, 5)).depth_mm > mini.press("big_sphere", force=(0, 0, 5)).depth_mm
    with pytest.raises(ValueError, match="background"):
        TactileSensor(dataclasses.replace(QUIET, background="/nonexistent.png"))


@pytest.mark.parametrize("pose", [(80.0, 80.0, 0.0), (SPEC.pad_size_mm[1] / 2 + 6.5, 0.0, 0.0)])
def test_press_that_misses_the_pad_has_no_contact(quiet_sensor, pose):
    # the Ø16 mm sphere's footprint (radius 6.24 mm) lies entirely beside the pad: nothing touches the gel
    assert not (INDENTERS["big_sphere"].heightmap(QUIET, pose) > 0).any()
    c = quiet_sensor.press("big_sphere", pose, (0.5, -0.5, 5.0))
    assert not c.mask.any() and c.area_mm2 == 0.0 and c.depth_mm == 0.0
    assert not c.penetration_mm.any() and not c.height_mm.any()
    assert c.force == (0.0, 0.0, 0.0)  # the pad carries no load
    np.testing.assert_array_equal(c.image, quiet_sensor.background)
    assert (c.residual == 127).all()


@pytest.mark.parametrize("obj, pose, fz", [
    ("big_sphere", (SPEC.pad_size_mm[1] / 2 + 5.5, 0.0, 0.0), 5.0),  # a 0.7 mm sliver of the sphere over the pad
    ("usb_c", (SPEC.pad_size_mm[1] / 2 + 3.5, 2.0, 0.0), 8.0),  # the plug's end over the pad's edge
    ("slim_cylinder", (0.0, 0.0, 0.3), 11.0),  # pressed deeper than its 1 mm relief
])
def test_contact_lies_only_where_the_object_overlaps_the_pad(quiet_sensor, obj, pose, fz):
    footprint = INDENTERS[obj].heightmap(QUIET, pose) > 0
    c = quiet_sensor.press(obj, pose, (0.0, 0.0, fz))
    assert c.mask.any() and not (c.mask & ~footprint).any(), "contact outside the object's footprint"
    assert c.area_mm2 <= footprint.sum() * QUIET.pixel_area_mm2
    assert abs(c.force[2] - fz) <= mechanics.FORCE_RTOL * fz + mechanics.FORCE_ATOL
    assert mechanics.normal_force(c.penetration_mm, QUIET) == pytest.approx(fz, rel=1e-3)


def test_procedural_shapes_are_pure_functions_of_their_index_and_press_like_any_object(quiet_sensor):
    names = procedural_objects(12)
    assert names[0] == "procedural_0000" and len(set(names)) == 12
    assert set(names).isdisjoint(INDENTERS)  # never one of the named (training or held-out) objects
    maps = [get_indenter(n).heightmap(QUIET, (0.0, 0.0, 0.3)) for n in names]
    np.testing.assert_array_equal(maps[3], procedural_indenter(3).heightmap(QUIET, (0.0, 0.0, 0.3)))
    assert all(np.isfinite(m).all() and m.min() >= 0 and m.max() > 0.5 for m in maps)
    assert len({m.tobytes() for m in maps}) == 12  # twelve different shapes
    c = quiet_sensor.press(names[5], (1.0, -1.0, 0.2), (0.3, -0.2, 6.0))
    assert c.mask.any() and abs(c.force[2] - 6.0) <= mechanics.FORCE_RTOL * 6.0 + mechanics.FORCE_ATOL


@pytest.mark.parametrize("name", ["procedural_", "procedural_x1", "procedural_-1", "sphere"])
def test_unknown_or_malformed_object_names_are_refused(name):
    with pytest.raises(ValueError, match="unknown object"):
        get_indenter(name)


def test_a_negative_procedural_index_is_refused():
    with pytest.raises(ValueError, match="index"):
        procedural_indenter(-1)


def test_no_procedural_shape_is_a_bumpy_cap_the_held_out_beads_family():
    """By construction: bumps are never drawn on a shape with a spherical cap, so no training shape is in
    textured_bead's family (a bumpy cap); procedural_0057's cap (r 2.51 mm) is smooth."""
    shapes = [procedural_indenter(k) for k in range(3000)]
    assert not [s.name for s in shapes if "cap" in s.description and "bumps" in s.description]
    assert sum("bumps" in s.description for s in shapes) > 200  # the other shapes keep their texture
    cap = procedural_indenter(57)
    assert "cap" in cap.description and "bumps" not in cap.description
    u, v = np.meshgrid(np.linspace(-6, 6, 121), np.linspace(-6, 6, 121))
    h = cap.relief(u, v)
    assert np.all(np.diff(h[60, 40:61]) >= -1e-9)  # a smooth cap rises monotonically towards its top


@pytest.mark.parametrize("field, value", [("conformity", "0.5"), ("vignetting", None), ("light_elevation_deg", "30"),
                                          ("contact_tint", 5), ("contact_tint", (1.0, 2.0)), ("noise_std", True)])
def test_a_spec_field_that_is_not_a_number_is_named_never_a_type_error(field, value):
    with pytest.raises(ValueError, match=rf"^SensorSpec.{field} must be"):
        SensorSpec(**{field: value})


def test_a_seed_or_spec_of_the_wrong_kind_is_named():
    for make, says in ((lambda: TactileSensor(seed=-1), "^seed must be an int >= 0, got -1$"),
                       (lambda: TactileSensor(seed=1.5), "^seed must be an int >= 0, got 1.5$"),
                       (lambda: TactileSensor({"height": 8}), "^spec: expected a SensorSpec, got dict$"),
                       (lambda: TactileSensor().press("cross", noise_seed="3"), "^noise_seed must be an int >= 0")):
        with pytest.raises(ValueError, match=says):
            make()
