"""Dataset writer/loader: determinism, atomicity, FeelAnyForce sign convention, malformed manifests."""

import csv
import hashlib
from pathlib import Path

import numpy as np
import pytest

from controltac_il.tactile import SensorSpec
from controltac_il.tactile import dataset as tds
from controltac_il.tactile.sensor import TactileSensor

SPEC = SensorSpec.gelsight_mini().scaled(60, 80)


def _digest(root: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        if p.is_file():
            h.update(p.relative_to(root).as_posix().encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def _write(path, **kw):
    args = dict(objects=("cross", "big_sphere"), poses_per_object=2, forces_per_pose=3, seed=3, spec=SPEC, progress=False)
    args.update(kw)
    return tds.write_dataset(path, **args)


def test_same_seed_same_bytes_other_seed_differs(tmp_path):
    a, b, c = _write(tmp_path / "a"), _write(tmp_path / "b"), _write(tmp_path / "c", seed=4)
    assert _digest(a) == _digest(b)
    assert _digest(a) != _digest(c)


@pytest.mark.parametrize("sensors", [None, "train"])
def test_worker_processes_write_the_same_bytes(tmp_path, sensors):
    """Rendering objects in parallel changes nothing on disk: images, manifest order, the background or the
    instances' backgrounds."""
    kw = dict(objects=("cross", "big_sphere", "procedural_0001"), sensors=sensors, instances=5)
    one, two = _write(tmp_path / "one", **kw), _write(tmp_path / "two", workers=2, **kw)
    assert _digest(one) == _digest(two)
    if sensors:  # several instances drawn, each background written
        assert len(list((two / "backgrounds").iterdir())) >= 2
    else:
        assert (two / "background.png").is_file()


def test_round_trip_and_pose_groups(tmp_path):
    ds = tds.load_dataset(_write(tmp_path / "d"))
    assert len(ds) == 12
    groups = ds.pose_groups()
    assert len(groups) == 4 and all(len(v) == 3 for v in groups.values())
    for idx in groups.values():  # one pose per group, forces differ
        assert len({ds.records[i].pose for i in idx}) == 1
        assert len({ds.records[i].force for i in idx}) == 3
    f = ds.forces()
    assert f.shape == (12, 3) and (f[:, 2] > 0).all() and (np.abs(f[:, :2]) <= 1).all()
    assert ds.image(0).shape == (60, 80, 3) and ds.residual(0).dtype == np.uint8


def test_interrupted_write_leaves_nothing(tmp_path, monkeypatch):
    calls = {"n": 0}
    real_press = TactileSensor.press

    def failing_press(self, *a, **k):
        calls["n"] += 1
        if calls["n"] == 5:
            raise KeyboardInterrupt
        return real_press(self, *a, **k)

    monkeypatch.setattr(TactileSensor, "press", failing_press)
    with pytest.raises(KeyboardInterrupt):
        _write(tmp_path / "out")
    assert list(tmp_path.iterdir()) == []


def test_rewrite_replaces_existing_dataset_only_when_complete(tmp_path):
    out = _write(tmp_path / "d")
    before = _digest(out)
    _write(tmp_path / "d", seed=9)
    assert _digest(out) != before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]
    (tmp_path / "empty").mkdir()
    _write(tmp_path / "empty")  # an empty folder is as good as a new one


@pytest.mark.parametrize("mine", ["episode_0.hdf5", "manifest.csv"])  # a manifest without our meta.json is not ours
def test_a_folder_of_the_users_is_never_replaced(tmp_path, mine):
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / mine).write_text("the user's")
    with pytest.raises(ValueError, match=r"^out_dir: .*d holds files this writer did not write"):
        _write(tmp_path / "d")
    assert [p.name for p in (tmp_path / "d").iterdir()] == [mine] and (tmp_path / "d" / mine).read_text() == "the user's"


def _feelanyforce_like(root: Path, rows):
    root.mkdir()
    with open(root / "manifest.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["image", "object", "pose_id", "Fx", "Fy", "Fz"])
        w.writerows(rows)
    return root


def test_feelanyforce_negative_fz_is_converted(tmp_path):
    root = _feelanyforce_like(tmp_path / "faf", [["a.png", "cross", 0, 0.1, 0.2, -3.0], ["b.png", "cross", 0, 0.0, 0.0, -5.0]])
    ds = tds.load_dataset(root)
    np.testing.assert_allclose(ds.forces()[:, 2], [3.0, 5.0])
    ds = tds.load_dataset(root, fz_pressing="positive")
    np.testing.assert_allclose(ds.forces()[:, 2], [-3.0, -5.0])


@pytest.mark.parametrize(
    "row, message",
    [
        (["a.png", "cross", 0, 0.1, 0.2], "missing field 'fz'"),
        (["a.png", "cross", "x", 0.1, 0.2, 1.0], "field 'pose_id' must be int"),
        (["a.png", "cross", 0, "nan", 0.2, 1.0], "field 'fx' must be finite"),
        (["a.png", "cross", 0, "abc", 0.2, 1.0], "field 'fx' must be float"),
    ],
)
def test_malformed_manifest_rows_name_the_line_and_field(tmp_path, row, message):
    root = _feelanyforce_like(tmp_path / "bad", [["ok.png", "cross", 0, 0.0, 0.0, 1.0], row])
    with pytest.raises(ValueError, match=f"line 3: {message}"):
        tds.load_dataset(root)


def test_a_bad_pose_field_meta_or_background_is_named(tmp_path):
    root = _feelanyforce_like(tmp_path / "pose", [["a.png", "cross", 0, 0.0, 0.0, 1.0]])
    (root / "manifest.csv").write_text("image,object,pose_id,x_mm,Fx,Fy,Fz\na.png,cross,0,abc,0,0,1\n")
    with pytest.raises(ValueError, match="line 2: field 'x_mm' must be float, got 'abc'"):
        tds.load_dataset(root)
    root = _feelanyforce_like(tmp_path / "meta", [["a.png", "cross", 0, 0.0, 0.0, 1.0]])
    (root / "meta.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"meta.json: not valid JSON"):
        tds.load_dataset(root)
    root = _feelanyforce_like(tmp_path / "bg", [["a.png", "cross", 0, 0.0, 0.0, 1.0]])
    (root / "background.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match=r"background.png: not a readable image"):
        tds.load_dataset(root)


def test_not_a_dataset_and_bad_options(tmp_path):
    with pytest.raises(ValueError, match="no manifest.csv"):
        tds.load_dataset(tmp_path)
    with pytest.raises(ValueError, match="fz_range"):
        _write(tmp_path / "x", fz_range=(5.0, 1.0))
    with pytest.raises(ValueError, match="unknown object"):
        _write(tmp_path / "y", objects=("banana",))


def test_command_line_writes_the_same_bytes_as_the_call(tmp_path, capsys):
    out = tds.main(["--out", str(tmp_path / "cli"), "--objects", "cross", "big_sphere", "--poses-per-object", "2",
                    "--forces-per-pose", "3", "--seed", "3", "--size", "60", "80"])
    assert _digest(out) == _digest(_write(tmp_path / "call"))
    assert "12 images" in capsys.readouterr().out


@pytest.mark.parametrize("argv, flag", [
    (["--size", "60", "60"], "--size"),
    (["--size", "0", "0"], "--size"),
    (["--objects", "teapot"], "--objects"),
    (["--objects", "cross", "cross"], "--objects"),
    (["--poses-per-object", "0"], "--poses-per-object"),
    (["--forces-per-pose", "-2"], "--forces-per-pose"),
    (["--fz-range", "5", "1"], "--fz-range"),
    (["--fz-range", "-1", "5"], "--fz-range"),
    (["--fz-range", "nan", "5"], "--fz-range"),
    (["--fz-range", "1", "inf"], "--fz-range"),
    (["--fz-range", "1", "1e9"], "HIGH <= 60"),  # else the mechanics' "not reached within 50 mm"
    (["--size", "99999", "133332"], "--size H W must be ints in [8, 2048]"),  # else a 40 GB allocation
    (["--shear-max", "nan"], "--shear-max"),
    (["--shear-max", "-1"], "--shear-max"),
    (["--shear-max", "80"], "--shear-max must be a finite number in [0, 60] N"),
    (["--seed", "-1"], "--seed"),
    (["--optics", "raytrace"], "--optics"),
    (["--procedural", "-2"], "--procedural"),
    (["--workers", "0"], "--workers"),
    (["--instances", "5"], "--instances 5: the number of randomised sensors to draw from, used only with --sensors"),
    (["--sensors", "train", "--optics", "polynomial"], "--optics polynomial: the one sensor's optics; --sensors train"),
    (["--out", "/proc/controltac-dataset"], "--out /proc/controltac-dataset: no file can be made in /proc"),
])
def test_command_line_refuses_bad_arguments_by_name(tmp_path, capsys, argv, flag):
    with pytest.raises(SystemExit) as exit_:
        tds.main(["--out", str(tmp_path / "x"), *argv])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in err and flag in err and "Traceback" not in err, err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("kwargs, name", [
    (dict(objects=("cross", "cross")), "objects"),
    (dict(shear_max=float("nan")), "shear_max"),
    (dict(seed=-1), "seed"),
    (dict(fz_range=(1.0, float("inf"))), "fz_range"),
    # beyond the sensor model's ±60 N: refused before rendering, not by the first press that reaches it
    (dict(fz_range=(1.0, 80.0)), r"^fz_range must be .* <= 60 N"), (dict(shear_max=80.0), r"^shear_max .*\[0, 60\] N"),
    (dict(forces_per_pose=0), "forces_per_pose"),
    (dict(workers=0), "workers"),
])
def test_write_dataset_refuses_bad_arguments_by_name(tmp_path, kwargs, name):
    with pytest.raises(ValueError, match=name):
        _write(tmp_path / "x", **kwargs)
    assert not (tmp_path / "x").exists()


def test_command_line_never_overwrites_a_dataset(tmp_path, capsys):
    existing = _write(tmp_path / "mine")
    before = _digest(existing)
    with pytest.raises(SystemExit) as exit_:
        tds.main(["--out", str(existing), "--poses-per-object", "1", "--forces-per-pose", "1"])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "\n" not in err and "--out" in err and "exists" in err, err
    assert _digest(existing) == before
