"""Recordings as labs record them (video or PNG frames + a force CSV) -> the presses layout; the estimator's
colour adapter; a bundle whose estimator does not beat the constant falls back to the nominal reference."""

import csv
import json

import cv2
import numpy as np
import pytest

from controltac_il.calibrate.recordings import (RecordingOptions, best_lag, presses, read_recording,
                                                recordings_to_presses, shift)
from controltac_il.tactile import SensorSpec, TactileSensor
from controltac_il.tactile.dataset import load_dataset

SPEC = SensorSpec.gelsight_mini().scaled(60, 80)
RAMP = np.r_[np.zeros(3), np.linspace(0.6, 12.0, 12), np.zeros(2), np.linspace(0.6, 8.0, 6), np.zeros(1)]  # N, 2 presses


@pytest.fixture(scope="module")
def frames():
    """(frames uint8 (T, 60, 80, 3) of a sensor-model recording of RAMP, its background)."""
    sensor = TactileSensor(SPEC, seed=1)
    out = [sensor.press("big_sphere", (0.5, 0.0, 0.0), (0.0, 0.0, float(f)), noise_seed=k).image if f > 0 else
           sensor.background for k, f in enumerate(RAMP)]
    return np.stack(out), sensor.background


def write(folder, name, frames, fz, video=False, header="fz"):
    folder.mkdir(exist_ok=True)
    if video:
        w = cv2.VideoWriter(str(folder / f"{name}.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (80, 60))
        for f in frames:
            w.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
        w.release()
    else:
        (folder / name).mkdir()
        for k, f in enumerate(frames):
            cv2.imwrite(str(folder / name / f"{k:03d}.png"), cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    with open(folder / f"{name}.csv", "w", newline="") as fh:
        csv.writer(fh).writerows([[header], *[[v] for v in fz]])


def test_presses_are_loading_ramps_and_shift_holds_the_ends():
    fz = np.array([0, 1, 3, 5, 4, 0, 0, 2, 6, 0.0])
    assert [p.tolist() for p in presses(fz, 0.5)] == [[1, 2, 3], [7, 8]]
    assert shift(fz[:, None], 1)[:, 0].tolist() == [1, 3, 5, 4, 0, 0, 2, 6, 0, 0]
    signal = np.r_[0, 0, 0, 1, 2, 3, 4, 5, 0, 0.0]
    assert best_lag(signal, np.roll(signal, 2), max_lag=3) == 2 and best_lag(signal, signal) == 0


def test_the_lag_is_found_on_a_smooth_ramp_where_a_linear_correlation_fails():
    """A sensor-model grasp on a smoothstep ramp (its contact signal grows with force by a concave law), the log
    one frame early: the rank correlation undoes it (shift -1); a linear one picks the shift that straightens the
    curve."""
    from controltac_il.calibrate.recordings import contact_signal
    from controltac_il.tactile.residual import to_residual

    sensor = TactileSensor(SPEC, seed=1)
    t = np.linspace(0, 1, 16)
    fz = np.r_[np.zeros(3), 12 * (3 * t**2 - 2 * t**3)]
    imgs = [sensor.press("big_sphere", (0.5, 0.0, 0.0), (0.0, 0.0, float(f)), noise_seed=k).image if f > 0 else
            sensor.background for k, f in enumerate(fz)]
    signal = np.array([contact_signal(to_residual(im, sensor.background)) for im in imgs])
    log = shift(fz[:, None], 1)[:, 0]  # label[i] = force[i + 1]
    assert best_lag(signal, log) == -1
    linear = {lag: np.corrcoef(signal[3:-3], shift(log[:, None], lag)[3:-3, 0])[0, 1] for lag in range(-3, 4)}
    assert max(linear, key=linear.get) != -1


def test_recordings_become_presses_with_their_backgrounds_and_lag(frames, tmp_path):
    imgs, background = frames
    lagged = shift(RAMP[:, None], -1)[:, 0]  # the log runs one frame early: label[i] = force[i - 1]
    write(tmp_path / "rec", "png_session", imgs, -lagged)  # a load cell's sign: pressing reads negative
    write(tmp_path / "rec", "video_session", imgs, RAMP, video=True)
    summary = recordings_to_presses(tmp_path / "rec", tmp_path / "presses", RecordingOptions(size=(60, 80), lag="auto"))
    assert summary["png_session"]["lag_frames"] == 1 and summary["video_session"]["lag_frames"] == 0
    assert {v["presses"] for v in summary.values()} == {2}
    ds = load_dataset(tmp_path / "presses")
    fz = ds.forces()[:, 2]
    assert fz.min() >= 1.0 and fz.max() <= 10.0 and np.all(ds.forces()[:, :2] == 0)
    expected = np.unique(RAMP[(RAMP >= 1) & (RAMP <= 10)])
    kept = np.unique(np.round(fz, 4))
    assert len(kept) == len(expected) and np.allclose(kept, expected, atol=1e-4)  # every ramp frame in range, no more
    png = load_dataset(tmp_path / "presses").backgrounds["png_session"]
    assert np.abs(png.astype(int) - background).max() <= 1  # the median of the no-contact frames
    assert json.loads((tmp_path / "presses" / "meta.json").read_text())["force_axes"] == ["fz"]


@pytest.mark.parametrize("case, expected", [
    ("short_log", "png_session.csv: 3 force rows for"), ("all_contact", "no no-contact frame"),
    ("out_of_range", "no loading-ramp frame with Fz in the validated range"), ("no_fz", "no 'fz' column"),
    ("bad_png", "000.png: not a readable image"), ("nan", "line 3: a force that is not finite"),
    ("lag", "--lag 6: png_session has 6 frames; a lag must be shorter"),
    ("millinewtons", r"png_session.csv reaches 6000, above 60 N: are the labels in mN\?")])
def test_bad_recordings_name_the_file(frames, tmp_path, case, expected):
    imgs = frames[0][:6]
    fz = {"short_log": [0, 1, 2], "all_contact": [1, 2, 3, 4, 5, 6], "out_of_range": [0, 0, 0.6, 0.8, 0.9, 0],
          "nan": [0, "nan", 2, 3, 4, 0], "millinewtons": [0, 0, 2000, 4000, 6000, 0]}.get(case, [0, 0, 2, 4, 6, 0])
    write(tmp_path, "png_session", imgs, fz, header="force" if case == "no_fz" else "fz")
    if case == "bad_png":
        (tmp_path / "png_session" / "000.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match=expected) as info:
        recordings_to_presses(tmp_path, tmp_path / "out", RecordingOptions(size=(60, 80), lag=6 if case == "lag" else 0))
    assert "png_session" in str(info.value) and "\n" not in str(info.value) and not (tmp_path / "out").exists()


def test_blank_frames_are_left_out_of_the_background_the_lag_and_the_ramps(frames, tmp_path):
    """A dropped frame (all 0) inside a press and an overexposed one (all 255) among the no-contact frames: the
    presses are the clean recording's less the dropped frame, with the same background and lag, and a warning."""
    imgs, _ = frames
    lagged = shift(RAMP[:, None], -1)[:, 0]
    write(tmp_path / "clean", "s", imgs, lagged)
    broken = imgs.copy()
    broken[8], broken[1] = 0, 255  # frame 8: a ramp frame at 4.7 N; frame 1: before the first press
    write(tmp_path / "broken", "s", broken, lagged)
    opts = RecordingOptions(size=(60, 80), lag="auto")
    clean = read_recording("s", tmp_path / "clean" / "s", tmp_path / "clean" / "s.csv", opts)
    with pytest.warns(UserWarning, match=r"2 of 24 frames have every value 0 or 255.*left out"):
        rec = read_recording("s", tmp_path / "broken" / "s", tmp_path / "broken" / "s.csv", opts)
    assert rec.lag == clean.lag == 1 and np.array_equal(rec.background, clean.background)
    dropped = np.flatnonzero(np.all(clean.frames == imgs[8], axis=(1, 2, 3)))
    assert len(dropped) == 1 and len(rec.frames) == len(clean.frames) - 1
    assert np.array_equal(rec.frames, np.delete(clean.frames, dropped, 0))
    assert np.array_equal(rec.labels, np.delete(clean.labels, dropped, 0))


def test_recordings_holding_one_press_in_all_are_refused_before_anything_is_written(frames, tmp_path):
    """A light touch below the validated range, then one press: one press counts (the touch keeps no frame)."""
    write(tmp_path / "rec", "png_session", frames[0][:10], [0, 0, 0.6, 0.8, 0, 0, 2, 4, 6, 0])
    with pytest.raises(ValueError, match=r"rec: 1 press in all recordings; at least 3 are needed"):
        recordings_to_presses(tmp_path / "rec", tmp_path / "out", RecordingOptions(size=(60, 80)))
    assert not (tmp_path / "out").exists()


def test_a_recording_without_frames_beside_its_log_is_named(tmp_path):
    (tmp_path / "lonely.csv").write_text("fz\n0\n")
    with pytest.raises(ValueError, match="lonely: no frame could be read"):
        read_recording("lonely", tmp_path / "lonely", tmp_path / "lonely.csv", RecordingOptions())
    with pytest.raises(ValueError, match="lonely.csv: no video"):
        recordings_to_presses(tmp_path, tmp_path / "out")


def test_colour_adapter_undoes_another_optics_colour_mix():
    """Residuals of the shipped estimator's own sensor family, colour-mixed as another optics would: the adapter,
    fitted on Fz labels alone, reads Fz better than zero-shot and than the constant, and Fx / Fy exactly as the
    base does; it is another estimator by hash."""
    from controltac_il.estimators import ForceEstimator
    from controltac_il.estimators.few_shot import ColourFit, fit_colour_adapter
    from controltac_il.tactile.residual import OFFSET, to_residual

    sensor = TactileSensor(SensorSpec.gelsight_mini().scaled(60, 80), seed=0)
    rng = np.random.default_rng(0)
    mix = np.array([[0.2, 0.9, 0.1], [0.1, 0.2, 1.1], [1.0, 0.1, 0.3]])
    res, fz = [], []
    for k in range(36):
        f = float(rng.uniform(1, 10))
        img = sensor.press(("big_sphere", "cross", "slim_cylinder")[k % 3], (rng.uniform(-2, 2), rng.uniform(-2, 2), 0.0), (0, 0, f),
                           noise_seed=k).image
        r = to_residual(img, sensor.background).astype(np.float64) - OFFSET
        res.append(np.clip(np.rint(r @ mix.T * 1.4 + OFFSET), 0, 255).astype(np.uint8))
        fz.append(f)
    res, fz = np.stack(res), np.array(fz)
    base = ForceEstimator.from_pretrained()
    est = fit_colour_adapter(base, res[:24], fz[:24], ColourFit(steps=40))  # 40: 0.43x the better baseline here
    err = lambda e: np.abs(e.predict(res[24:], gate=False)[:, 2] - fz[24:]).mean()  # noqa: E731
    constant = np.abs(fz[:24].mean() - fz[24:]).mean()
    assert err(est) < 0.8 * min(err(base), constant), (err(est), err(base), constant)
    assert est.checkpoint_hash != base.checkpoint_hash
    tuned, shipped = est.predict(res[24:], gate=False), base.predict(res[24:], gate=False)
    assert np.array_equal(tuned[:, :2], shipped[:, :2])  # fitted without shear labels: Fx, Fy read the frame unmixed
    assert np.abs(tuned[:, 2] - shipped[:, 2]).min() > 0
    with pytest.raises(ValueError, match="one finite label"):
        fit_colour_adapter(base, res[:2], np.array([1.0, np.nan]))
    with pytest.raises(ValueError, match=r"shape \(2,\), is needed; got \(2, 1\)"):  # would broadcast to (2, 2)
        fit_colour_adapter(base, res[:2], np.array([[1.0], [2.0]]))


def test_a_bundle_whose_estimator_is_useless_gives_the_nominal_reference(tmp_path):
    from controltac_il.augment.reference import NominalEstimator, bundle_estimator
    from controltac_il.estimators import ForceEstimator
    from controltac_il.generator.forces import NOMINAL_FZ

    ForceEstimator.from_pretrained().save(tmp_path / "estimator")
    (tmp_path / "calibration.json").write_text(json.dumps({"estimator": {"use_estimator": False}}))
    with pytest.warns(UserWarning, match="does not beat the constant baseline"):
        est = bundle_estimator(tmp_path)
    assert isinstance(est, NominalEstimator)
    assert est.predict(np.zeros((2, 8, 8, 3), np.uint8)).tolist() == [[0.0, 0.0, NOMINAL_FZ]] * 2
    (tmp_path / "calibration.json").write_text(json.dumps({"estimator": {"use_estimator": True}}))
    assert isinstance(bundle_estimator(tmp_path), ForceEstimator)
