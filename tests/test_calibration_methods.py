"""benchmarks.calibration_methods: grasp-wise splits, label lag, the monotone fit and the --quick run."""

import numpy as np
import pytest

from benchmarks import calibration_methods as cm


def _bank(n_cal=4, n_test=3, frames=12):
    """A synthetic bank: ramps of ``frames`` frames, one feature = the true Fz; residuals a disc growing with Fz."""
    from controltac_il.estimators import ForceEstimator

    gid = np.repeat(np.arange(n_cal + n_test), frames)
    pos = np.tile(np.arange(frames), n_cal + n_test)
    fz = np.tile(cm.ramp(frames, 12.0), n_cal + n_test)
    feats = {k: fz.copy() for k in ("fz_ship", "area", "summag")}
    feats["hidden"] = np.stack([fz, fz**2, np.sin(fz)], 1)
    yy, xx = np.mgrid[:48, :64]
    disc = np.hypot(yy - 24, xx - 32)[None] < 4 * np.sqrt(fz)[:, None, None]
    res = np.where(disc[..., None], np.array([150, 110, 170], np.uint8), np.uint8(127)).astype(np.uint8)
    return cm.Bank("synthetic", gid, pos, fz, feats, np.arange(n_cal), np.arange(n_cal, n_cal + n_test), res,
                   ForceEstimator.from_pretrained())


def test_ramp_rises_from_zero_to_its_peak():
    f = cm.ramp(17, 12.0)
    assert f[0] == 0 and f[-1] == pytest.approx(12.0) and (np.diff(f) > 0).all()


@pytest.mark.parametrize("lag", [-1, 0, 1])
def test_lag_gives_each_frame_its_neighbours_force(lag):
    fz = cm.ramp(15, 12.0)
    lab = cm.lag_labels(fz, lag)
    inner = np.arange(1, 14)
    assert np.array_equal(lab[inner], fz[inner + lag])
    assert lab[0] == fz[max(lag, 0)] and lab[-1] == fz[min(14 + lag, 14)]  # clamped at the ramp's ends


def test_calibration_and_test_frames_never_share_a_grasp():
    bank = _bank()
    rng = np.random.default_rng(0)
    for _ in range(20):
        grasps = rng.choice(bank.cal_pool, size=3, replace=False)
        rows, y = cm.calibration_set(bank, grasps, rng.integers(-1, 2, size=3), 2, int(rng.integers(2)))
        test = cm.scored_rows(bank)
        assert set(bank.gid[rows]) <= set(grasps.tolist())
        assert not set(bank.gid[rows]) & set(bank.gid[test])
        assert ((y >= cm.LABEL_RANGE[0]) & (y <= cm.LABEL_RANGE[1])).all()


def test_calibration_labels_carry_the_grasps_lag():
    bank = _bank(n_cal=1, n_test=1)
    for lag in (-1, 0, 1):
        rows, y = cm.calibration_set(bank, [0], [lag], 1, 0)
        assert np.allclose(y, bank.fz[np.clip(bank.pos[rows] + lag, 0, 11)])


def test_leave_one_grasp_out_never_fits_on_the_held_out_grasp():
    groups = np.repeat(np.arange(4), 5)
    x = np.arange(20.0)[:, None]
    seen = []

    def fit(a, b):
        seen.append(set(a[:, 0].astype(int)))
        return lambda q: np.zeros(len(q))

    cm.logo_mae(fit, x, np.zeros(20), groups)
    assert len(seen) == 4  # one fit per held-out grasp
    for g, train in zip(range(4), seen):
        assert not train & set(np.flatnonzero(groups == g))


def test_monotone_map_is_monotone_and_recovers_a_monotone_map():
    rng = np.random.default_rng(1)
    x = rng.uniform(0, 10, 400)
    truth = lambda v: 3 * np.sqrt(v) + 0.5  # noqa: E731
    m = cm.MonotoneMap().fit(x, truth(x) + rng.normal(0, 0.3, x.size))
    grid = np.linspace(-2, 14, 500)
    assert (np.diff(m.predict(grid)) >= -1e-12).all()  # also beyond the fit points
    inner = np.linspace(1, 9, 50)
    assert np.abs(m.predict(inner) - truth(inner)).mean() < 0.15


def test_methods_fit_on_a_clean_sensor():
    """On a clean sensor the feature is the force itself: every fitted map recovers it; the constant is the
    calibration labels' mean; the colour adapter, three steps in, is already far better than the constant."""
    bank = _bank(n_cal=6)
    rows, y = cm.calibration_set(bank, np.arange(6), np.zeros(6, int), 1, 0)
    test = cm.scored_rows(bank)
    constant = np.abs(y.mean() - bank.fz[test]).mean()
    for m in cm.METHODS:
        predict, _ = cm.fit_method(m, bank, rows, y, adapter_steps=3)  # the adapter's own test: test_calibrate_recordings
        mae = np.abs(predict(test) - bank.fz[test]).mean()
        if m == "constant":
            assert mae == pytest.approx(constant)
        elif m == "colour_adapter":
            assert mae < 0.5 * constant, mae
        else:
            assert mae < 0.05, (m, mae)


def test_quick_run_end_to_end(tmp_path, capsys):
    out = tmp_path / "r.json"
    doc = cm.main(["--quick", "--out", str(out)])
    assert out.is_file() and doc["machine"]["cores"]
    methods = {r["method"] for r in doc["summary"]}
    assert methods == set(cm.METHODS)
    const = [r for r in doc["summary"] if r["method"] == "constant"]
    assert all(r["ratio"] == pytest.approx(1.0) for r in const)
    assert "ratio to the constant" in capsys.readouterr().out
