"""benchmarks.response: contact area against ΔFz, the drop and growth it reports, and its --quick run."""

import json
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from benchmarks import response as bench
from controltac_il.tactile.residual import OFFSET


class AreaGenerator:
    """Answers ΔFz with a residual whose contact covers ``areas[ΔFz]`` rows of 100 (a known contact area)."""

    def __init__(self, areas):
        self.areas = areas
        self.config = SimpleNamespace(image_size=(100, 10))

    def generate(self, refs, delta, seed=0):
        out = np.full(refs.shape, OFFSET, np.uint8)
        for k, d in enumerate(delta[:, 2]):
            out[k, : self.areas[float(d)]] = OFFSET + 40
        return out


def test_area_drop_and_growth_are_measured_between_neighbouring_steps():
    ref = np.full((100, 10, 3), OFFSET, np.uint8)
    ref[:20] = OFFSET + 13  # just above the 12-grey-level contact threshold
    assert bench.contact_area_pct(ref[None])[0] == pytest.approx(20.0)
    deltas = np.array([-1.0, -0.5, 0.0, 0.5, 1.0])
    r = bench.response(AreaGenerator({-1.0: 10, -0.5: 15, 0.0: 20, 0.5: 17, 1.0: 30}), ref, deltas)
    assert r["reference_area_pct"] == 20.0 and r["area_pct"] == [10.0, 15.0, 20.0, 17.0, 30.0]
    assert r["max_drop_pp"] == 3.0 and r["worst_step_n"] == [0.0, 0.5] and r["growth_pp"] == 10.0
    assert not r["monotone"]
    flat = bench.response(AreaGenerator({d: 20 for d in deltas.tolist()}), ref, deltas)
    assert flat["max_drop_pp"] == 0.0 and flat["worst_step_n"] is None and flat["monotone"]


class ResizingGenerator:
    """Returns each reference, or (``blur``) its round trip through the model size: detail resized away."""

    def __init__(self, blur):
        self.blur, self.config = blur, SimpleNamespace(image_size=(12, 16))

    def generate(self, refs, delta, seed=0):
        if not self.blur:
            return refs.copy()
        return np.stack([cv2.resize(cv2.resize(r, (16, 12), interpolation=cv2.INTER_AREA), (32, 24)) for r in refs])


def test_detail_kept_tells_a_frame_that_keeps_its_fine_detail_from_one_resized_through_the_model():
    ref = np.full((24, 32, 3), OFFSET, np.uint8)
    ref[::2, ::2] += 20  # detail at the pixel scale, finer than the 12x16 model
    assert bench.fine_detail(ref, (12, 16)) > 10 and bench.fine_detail(np.full_like(ref, OFFSET), (12, 16)) == 0
    deltas = np.array([0.0, 2.0])
    kept = bench.response(ResizingGenerator(blur=False), ref, deltas)
    assert kept["detail_kept"] == 1.0 and kept["reference_fine_detail"] == pytest.approx(bench.fine_detail(ref, (12, 16)), abs=1e-3)
    assert bench.response(ResizingGenerator(blur=True), ref, deltas)["detail_kept"] < 0.05
    assert bench.response(ResizingGenerator(blur=False), ref, np.array([0.0, 1.0]))["detail_kept"] is None  # no +2 N


@pytest.mark.slow  # the whole --quick benchmark: its response measure is tested above; with -m slow
def test_quick_run_writes_every_reference_and_the_plot(tmp_path):
    out = tmp_path / "response.json"
    doc = bench.main(["--quick", "--out", str(out)])
    assert json.loads(out.read_text()) == json.loads(json.dumps(doc))
    sims = [n for n in doc["references"] if n.startswith("sim")]
    assert len(sims) == 2 * len(bench.SIM_SIZES)
    for r in doc["references"].values():
        assert len(r["area_pct"]) == len(bench.QUICK_DELTAS)
    assert (tmp_path / "response.png").stat().st_size > 0
    if bench.REAL_DIR.is_dir():  # the GPL frames are measured where ../shared is, never shipped
        assert {"real/bead", "real/key", "real/seed"} <= set(doc["references"])


@pytest.mark.slow  # a real fine-tune through the training CLI (10 s): with -m slow
def test_finetune_quick_run_scores_zero_shot_and_a_fine_tune_and_resumes(tmp_path):
    from benchmarks import finetune

    out, runs = tmp_path / "ft.json", tmp_path / "runs"
    doc = finetune.main(["--quick", "--out", str(out), "--runs", str(runs)])
    rows = {r["images"]: r for r in doc["rows"]}
    assert set(rows) == {0, 48} and rows[0]["steps"] == 0 and rows[48]["images_rendered"] == 48
    assert rows[0]["copy_mse"] == rows[48]["copy_mse"] > 0  # one held-out evaluation set for every budget
    for r in rows.values():
        assert r["mse_ratio_to_copy"] == pytest.approx(r["mse"] / r["copy_mse"]) and r["n"] == 12
    card = json.loads((runs / "unseen_00_n48_s4_a2_e4" / "generator" / "model_card.json").read_text())
    assert "--denoiser-from" in card["command"] and card["denoiser"]["steps"] == 4
    assert card["autoencoder"]["finetune"]["step"] == 2 and rows[48]["ae_steps"] == 2
    assert len(rows[0]["estimator_mae"]) == 3 and rows[48]["estimator_mae"] != rows[0]["estimator_mae"]
    assert rows[48]["estimator_steps"] == rows[48]["estimator_steps_requested"] == 4  # as the bundle records it
    assert rows[0]["cpu"] == rows[48]["cpu"] == doc["machine"]["cpu"]  # each budget names its machine (resumes may move)
    again = finetune.main(["--quick", "--out", str(out), "--runs", str(runs), "--resume"])
    assert again["rows"] == doc["rows"]  # nothing retrained or rescored
    assert out.with_suffix(".png").stat().st_size > 0


def test_finetune_leaves_the_estimator_steps_to_calibrate_unless_asked(tmp_path, monkeypatch):
    """Without --estimator-steps each budget runs calibrate's own steps for the method it picks (150 for the colour
    adapter, 1000 for the fine-tune); with it, every budget runs that many. The calibrate CLI is replaced by a
    recorder of its arguments that fails (nothing trains)."""
    import controltac_il.calibrate as cal
    from benchmarks import finetune

    seen = []
    monkeypatch.setattr(cal, "main", lambda argv: seen.append(argv) or 1)
    for extra in ([], ["--estimator-steps", "7"]):
        args = finetune._parser().parse_args(["--out", str(tmp_path / "x.json"), *extra])
        with pytest.raises(RuntimeError, match="calibrating on"):
            finetune.calibrate(Path("base"), tmp_path / "data", tmp_path / "bundle", args)
    assert "--estimator-steps" not in seen[0]
    assert seen[1][seen[1].index("--estimator-steps") + 1] == "7"


def _finetune_run(path, base: str, instance: str = "unseen_00") -> Path:
    rows = [{"images": n, "mse_ratio_to_copy": r, "estimator_mae": [0.3, 0.3, e]}
            for n, r, e in ((0, 0.56, 2.2), (100, 0.44, 1.0), (500, 0.40, 0.5))]
    path.write_text(json.dumps({"instance": instance, "base": f"/x/checkpoints/{base}", "rows": rows}))
    return path


def test_finetune_plot_draws_finished_runs_of_one_sensor_and_refuses_a_mix(tmp_path):
    from benchmarks import finetune

    a, b = _finetune_run(tmp_path / "a.json", "default"), _finetune_run(tmp_path / "b.json", "quality")
    assert finetune.main(["--plot", str(a), str(b), "--out", str(tmp_path / "both.png")]) is None
    assert (tmp_path / "both.png").stat().st_size > 0
    other = _finetune_run(tmp_path / "c.json", "quality", instance="unseen_01")
    with pytest.raises(SystemExit, match="different sensors"):
        finetune.main(["--plot", str(a), str(other), "--out", str(tmp_path / "mix.png")])
    with pytest.raises(SystemExit, match="no such run file: .*nope.json"):
        finetune.main(["--plot", str(a), str(tmp_path / "nope.json"), "--out", str(tmp_path / "x.png")])
    with pytest.raises(SystemExit):  # argparse: --plot needs --out FILE.png
        finetune.main(["--plot", str(a), "--out", str(tmp_path / "x.json")])
    assert not (tmp_path / "mix.png").exists() and not (tmp_path / "x.png").exists()


@pytest.mark.slow  # 4 s each; every preset's monotone area on real and 240x320 frames runs in the suite (test_gen_presets)
@pytest.mark.parametrize("group", ["held_out", "training"])
def test_the_shipped_default_never_shrinks_a_sensor_model_contact_as_the_force_grows(group):
    """The physical check on references of every object at the model's size: the contact area does not
    fall by more than 0.15 pp between neighbouring 0.5 N steps of ΔFz in [-2, 8] N (with -m slow)."""
    from controltac_il.generator import ForceGenerator
    from controltac_il.tactile import HELDOUT_OBJECTS, TRAIN_OBJECTS

    gen = ForceGenerator.from_pretrained("default")
    refs = bench.sim_references(HELDOUT_OBJECTS if group == "held_out" else TRAIN_OBJECTS, (120, 160))
    drops = {n: bench.response(gen, r, bench.DELTAS)["max_drop_pp"] for n, r in refs.items()}
    assert max(drops.values()) <= bench.MAX_DROP_PP, drops
