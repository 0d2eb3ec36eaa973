"""The shipped generator presets (fast, default, quality): each loads with its pinned hash, grows the
contact monotonically with Fz on real GelSight Mini frames and on sensor-model frames at 240×320, and returns a
240×320 reference at ΔF = 0."""

import numpy as np
import pytest

import benchmarks.response as bench
from controltac_il.generator import ForceGenerator
from controltac_il.generator.checkpoint import checkpoint_hash
from controltac_il.generator.shipped import FRONTIER_SIZES, SHIPPED, locate_checkpoint
from controltac_il.metrics import mse
from controltac_il.tactile import HELDOUT_OBJECTS, SensorSpec, TactileSensor

# ForceAugment caches key on these: a changed file is a new generator, never the same name silently
HASHES = {"default": "ded63c1c8e7216ae", "fast": "41bfd44359d0212d", "quality": "43804a76f38836b6",
          "frontier_tiny": "3b260a406790ba20", "frontier_small": "367c790bce80dbcb"}


@pytest.fixture(scope="module", params=SHIPPED)
def preset(request):
    return request.param, ForceGenerator.from_pretrained(request.param)


@pytest.fixture(scope="module")
def native():
    """Sensor-model residuals at the GelSight Mini's 240×320 at Fz = 4 N, and the same poses at 7 N."""
    sensor = TactileSensor(SensorSpec.gelsight_mini())
    cases = [("big_sphere", (0.4, -0.3, 0.2)), ("cross", (-0.5, 0.2, 0.9)), ("usb_c", (0.0, 0.5, 1.3))]
    ref = np.stack([sensor.press(o, p, (0.0, 0.0, 4.0), noise_seed=1).residual for o, p in cases])
    up = np.stack([sensor.press(o, p, (0.0, 0.0, 7.0), noise_seed=2).residual for o, p in cases])
    return ref, up


def test_every_shipped_checkpoint_is_named_and_pinned():
    assert {*SHIPPED, *FRONTIER_SIZES} == set(HASHES)
    for name in HASHES:
        assert checkpoint_hash(locate_checkpoint(name)) == HASHES[name]


def test_contact_area_never_shrinks_as_fz_grows(preset):
    """The contact-area check (area drop <= 0.15 pp between neighbouring 0.5 N steps), over ΔFz in [-1, 2] N and a
    +6 N step, on the real GelSight Mini frames of ../shared (measured, never shipped) where present, and on a
    held-out object at 240×320 (benchmarks.response sweeps [-2, 8] N)."""
    name, gen = preset
    refs = {**bench.real_references(), **bench.sim_references(HELDOUT_OBJECTS[:1], (240, 320))}
    deltas = np.append(bench.QUICK_DELTAS, 6.0)
    rows = {n: bench.response(gen, r, deltas) for n, r in refs.items()}
    assert max(r["max_drop_pp"] for r in rows.values()) <= bench.MAX_DROP_PP, (name, rows)
    assert min(r["growth_pp"] for r in rows.values()) > 0, (name, rows)  # +6 N does press deeper


def test_zero_force_change_returns_a_240x320_reference(preset, native, request):
    name, gen = preset
    if name == "fast":
        request.applymarker(pytest.mark.xfail(strict=True, reason=(
            "fast decodes once, without the reference anchoring: at 240x320 its output at ΔF = 0 lies 0.3-2x a +3 N "
            "change away from the reference (docs/generator.md); strict, so a fast preset that passes is noticed")))
    ref, up = native
    out = gen.generate(ref, np.zeros((len(ref), 3)), seed=0)
    assert out.shape == ref.shape
    assert np.all(mse(out, ref) < 0.1 * mse(up, ref)), (mse(out, ref), mse(up, ref))
