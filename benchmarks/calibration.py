"""``calibrate`` end to end on a sensor it never saw, under a lab's conditions.

    python -m benchmarks.calibration --out calibration.json [--quick]

Each sensor is one of ``benchmarks.calibration_methods``'s: an ``unseen``-family instance with its own optics,
``three_light`` or ``three_light_rot`` (an optical design no training instance has), square frames (another aspect
ratio), lighting drift per grasp. A grasp is a loading ramp Fz 0 -> 10-14 N; its recording (frames written as
PNGs, resized by ``calibrate`` to 240x320) starts with ``FREE_FRAMES`` no-contact frames, and its force log (Fz
only) lags the video by -1, 0 or +1 frame. ``K`` grasps are recorded and calibrated with
``python -m controltac_il.calibrate --recordings DIR --lag auto --stride 2`` (about 50 frames at K = 10); other
grasps of the same sensor are the test: the estimator's Fz MAE on all their contact frames against the
constant (the calibration labels' mean) and the zero-shot estimator; the generator's MSE against a reference
copy's on pairs within a grasp with |ΔFz| >= 1.5 N, before and after. Targets: estimator <= 0.5x the constant,
generator <= 0.35x a copy, <= 15 min a calibration on two cores (the mean over these sensors).

``--heldout-draws D`` adds the held-out-object setting a lab's data holds out: per sensor, D draws of K calibration
grasps of the base models' training objects, each calibrated and tested on grasps of the held-out objects (in
neither the calibration grasps nor the base models' training); per (sensor, draw) case, whether ``calibrate``'s
decision was right (the estimator used exactly where its test MAE beats the constant's), and over the cases the
decision's accuracy, the used estimator's test MAE ÷ the constant's, the generator's ÷ a copy's and the minutes,
against ``HELDOUT_TARGETS``.

Beside them, ``sim_record``: ``python -m controltac_il.calibrate record --sim`` presses in the MuJoCo scene (the
gripper squeezing the standing peg, the pad force its label, frames of the training sensor as the scene renders
it), ``K`` presses calibrated and ``--test-grasps`` presses of another seed, at other places on the gel, the test:
the recording routine end to end (``--no-sim-record`` skips it). Rows record their commit: ``--resume`` keeps
the rows already written.
"""

from __future__ import annotations

import csv
import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from benchmarks.calibration_methods import lag_labels, make_sensor, render_grasp
from benchmarks.common import base_parser, machine_info, print_table, write_results
from controltac_il.tactile import HELDOUT_OBJECTS, TRAIN_OBJECTS

FREE_FRAMES = 3  # no-contact frames at the start of each recording
TARGETS = {"estimator_ratio": 0.5, "generator_ratio": 0.35, "minutes": 15.0}
# the held-out-object setting: the decision right in this share of (sensor, draw) cases, the estimator where used
# at most this share of the constant's MAE on the mean, the generator at most this share of a copy's MSE
HELDOUT_TARGETS = {"decision_accuracy": 0.9, "used_estimator_ratio": 0.7, "generator_ratio": 0.40, "minutes": 15.0}
# calibration objects: the base models' training objects (a lab presses what it has); test objects: the held-out
# ones, in neither the calibration grasps nor the base models' training
CALIBRATION_OBJECTS, TEST_OBJECTS = TRAIN_OBJECTS, HELDOUT_OBJECTS
SAME_OBJECTS = (CALIBRATION_OBJECTS + TEST_OBJECTS,) * 2
# (instance index, optics): the unseen-family sensors calibrated, two of them with the rotated light
SENSORS = ((0, "three_light"), (0, "three_light_rot"), (1, "three_light_rot"))

PROG = "python -m benchmarks.calibration"


def record_grasps(sensor, rng, n: int, folder: Path | None, objects: tuple[str, ...]) -> list[tuple]:
    """Render ``n`` grasps of ``objects``: (residuals (T, H, W, 3), true Fz (T,), lag); with ``folder``, each written
    as a recording (``<g>/`` PNG frames and ``<g>.csv`` lagged Fz, preceded by FREE_FRAMES no-contact frames)."""
    from controltac_il.tactile.residual import from_residual

    out = []
    for g in range(n):
        res, fz = render_grasp(sensor, objects[int(rng.integers(len(objects)))], rng)
        lag = int(rng.integers(-1, 2))
        out.append((res, fz, lag))
        if folder is None:
            continue
        x0 = (sensor.background.shape[1] - res.shape[2]) // 2
        bg = sensor.background[:, x0:x0 + res.shape[2]]
        frames = [bg] * FREE_FRAMES + [from_residual(r, bg) for r in res]
        labels = np.r_[np.zeros(FREE_FRAMES), lag_labels(fz, lag)]
        (folder / f"g{g:02d}").mkdir(parents=True)
        for k, img in enumerate(frames):
            cv2.imwrite(str(folder / f"g{g:02d}" / f"{k:04d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        with open(folder / f"g{g:02d}.csv", "w", newline="") as f:
            csv.writer(f).writerows([["fz"], *[[f"{v:.4f}"] for v in labels]])
    return out


def test_figures(bundle: Path, base_generator: str, test: list[tuple], const: float, size) -> dict:
    """The calibrated bundle and the shipped models on the test grasps (module docstring)."""
    from controltac_il.estimators import ForceEstimator
    from controltac_il.generator import ForceGenerator
    from controltac_il.generator.training.validation import generation_error

    def resized(r):
        return np.stack([cv2.resize(x, (size[1], size[0]), interpolation=cv2.INTER_AREA) for x in r])

    res = np.concatenate([resized(r) for r, _, _ in test])
    fz = np.concatenate([f for _, f, _ in test])
    touch = fz >= 0.5
    out = {"test_frames": int(touch.sum()), "constant_mae_n": float(np.abs(const - fz[touch]).mean())}
    for name, path in (("zero_shot", None), ("calibrated", bundle)):
        pred = ForceEstimator.from_pretrained(path).predict(res[touch], gate=False)[:, 2]
        out[f"{name}_mae_n"] = float(np.abs(pred - fz[touch]).mean())
        out[f"{name}_ratio"] = out[f"{name}_mae_n"] / out["constant_mae_n"]
    rng, refs, tgts, delta, ref_f = np.random.default_rng(0), [], [], [], []
    for r, f, _ in test:
        ok = [(a, b) for a in range(len(f)) for b in range(len(f))
              if abs(f[b] - f[a]) >= 1.5 and 1 <= f[a] <= 10 and 1 <= f[b] <= 10]
        for k in rng.choice(len(ok), size=min(8, len(ok)), replace=False):
            a, b = ok[k]
            refs.append(r[a]), tgts.append(r[b]), delta.append([0.0, 0.0, f[b] - f[a]])
            ref_f.append([0.0, 0.0, f[a]])
    args = (resized(np.stack(refs)), resized(np.stack(tgts)), np.asarray(delta, np.float32), np.asarray(ref_f))
    for name, path in (("zero_shot", base_generator), ("calibrated", bundle)):
        out[f"generator_{name}_ratio"] = generation_error(ForceGenerator.from_pretrained(path), *args)["ratio_to_copy"]
    out["generator_pairs"] = len(refs)
    return out


def calibrate_one(sensor_name: str, index: int, optics: str, args, work: Path, draw: int | None = None) -> dict:
    """Record, calibrate and test one sensor of the sensor model; the row of the results. ``draw`` None: the
    calibration and test grasps of every object (``SAME_OBJECTS``); an int: the held-out-object setting, that draw
    of calibration grasps of ``CALIBRATION_OBJECTS``, test grasps of ``TEST_OBJECTS``."""
    _, sensor = make_sensor(index, optics)
    rng = np.random.default_rng([args.seed, index, len(optics)] + ([] if draw is None else [draw]))
    rec = work / (sensor_name.replace("/", "_") + ("" if draw is None else f"_draw{draw}"))
    cal_objects, test_objects = SAME_OBJECTS if draw is None else (CALIBRATION_OBJECTS, TEST_OBJECTS)
    cal = record_grasps(sensor, rng, args.k, rec / "recordings", cal_objects)
    test = record_grasps(sensor, rng, args.test_grasps, None, test_objects)
    labels = np.concatenate([lag_labels(f, lag) for _, f, lag in cal])
    row = {"sensor": sensor_name, **calibrate_and_test(rec, labels, test, args), "lags_true": [lag for _, _, lag in cal]}
    if draw is not None:  # right: used exactly where it beats the constant on the test grasps
        row.update(draw=draw, decision_right=bool(row["use_estimator"] == (row["calibrated_ratio"] < 1.0)))
    return row


def sim_record_one(args, work: Path) -> dict:
    """``calibrate record --sim``: ``args.k`` presses of the MuJoCo scene's gripper on the standing peg (its pad
    force the label), calibrated; ``args.test_grasps`` presses of another seed (other places on the gel) the test."""
    from controltac_il.app.record_cli import main as record
    from controltac_il.calibrate.recordings import find_recordings, read_forces, read_frames
    from controltac_il.tactile.residual import to_residual

    rec = work / "sim_record"
    for name, seed, n in (("recordings", args.seed, args.k), ("test", args.seed + 1, args.test_grasps)):
        if record(["--sim", "--out", str(rec / name), "--presses", str(n), "--seed", str(seed)]) != 0:
            raise SystemExit("calibrate record --sim failed")
    test, labels = [], []
    for folder, tests in (("recordings", False), ("test", True)):
        for frames_path, csv_path in find_recordings(rec / folder).values():
            fz = read_forces(csv_path)[0][:, 2]
            labels.append(fz)
            if tests:
                frames = read_frames(frames_path, tuple(args.size))
                bg = np.median(frames[fz < 0.2], axis=0).astype(np.uint8)
                test.append((np.stack([to_residual(f, bg) for f in frames]), fz, 0))
    return {"sensor": "sim_record/peg_squeeze", **calibrate_and_test(rec, np.concatenate(labels[:args.k]), test, args),
            "lags_true": [0] * args.k}


def calibrate_and_test(rec: Path, labels: np.ndarray, test: list[tuple], args) -> dict:
    """``calibrate --recordings rec/recordings``, timed, and its bundle on the ``test`` grasps; the constant is the
    calibration ``labels``' mean over the validated range."""
    from controltac_il.calibrate import main as calibrate
    from controltac_il.checkpoint import read_json

    argv = ["--recordings", str(rec / "recordings"), "--out", str(rec / "bundle"), "--lag", "auto", "--stride", "2",
            "--threads", str(args.threads), "--device", args.device, "--ae-steps", str(args.ae_steps),
            "--dit-steps", str(args.dit_steps)]
    t0 = time.perf_counter()
    if calibrate(argv) != 0:
        raise SystemExit(f"calibrate failed on {rec.name}")
    minutes = (time.perf_counter() - t0) / 60
    record = read_json(rec / "bundle" / "calibration.json")
    kept = labels[(labels >= 1) & (labels <= 10)]
    h = record["estimator"]["held_out"]
    return {"grasps": args.k, "cal_frames": record["images"], "minutes": minutes,
            "commit": machine_info()["git_commit"],
            "lags_found": [v["lag_frames"] for v in record["source"]["per_recording"].values()],
            "machine": {k: machine_info()[k] for k in ("cpu", "cores", "cuda_device")}, "device": args.device,
            "cv_ratio": h["ratio_to_constant"], "cv_interval": h["decision"]["interval"],
            "cv_wins": h["decision"]["wins"], "cv_grasps": h["decision"]["grasps"],
            "cv_per_grasp": h["per_grasp"], "use_estimator": record["estimator"]["use_estimator"],
            **test_figures(rec / "bundle", "default", test, float(kept.mean()), tuple(args.size))}


def add_options(p) -> None:
    """The options of a calibration case (``calibrate_one``'s ``args``): also ``benchmarks.calibration_rule``'s."""
    p.add_argument("--k", type=int, default=10, help="calibration grasps per sensor (default 10: ~50 frames)")
    p.add_argument("--test-grasps", type=int, default=12)
    p.add_argument("--ae-steps", type=int, default=600)
    p.add_argument("--dit-steps", type=int, default=600)
    p.add_argument("--threads", type=int, default=2, help="torch threads per calibration")
    p.add_argument("--device", default="cpu", help="where calibrate fine-tunes the generator: cpu (its default), cuda")
    p.add_argument("--jobs", type=int, default=1, help="sensor cases calibrated at once, each in its own process")
    p.add_argument("--seed", type=int, default=40)
    p.add_argument("--size", type=int, nargs=2, default=(240, 320), help="calibrate's frame size (its default)")
    p.add_argument("--resume", action="store_true", help="keep the cases already in --out (written after each)")


def check_options(p, args) -> None:
    """Refuse, by flag, options no calibration case can run with (before any case starts)."""
    from controltac_il.calibrate.decision import MIN_GRASPS
    from controltac_il.training import device_problem

    for flag, value, low in (("--k", args.k, MIN_GRASPS), ("--test-grasps", args.test_grasps, 1),
                             ("--ae-steps", args.ae_steps, 0), ("--dit-steps", args.dit_steps, 1),
                             ("--threads", args.threads, 1), ("--jobs", args.jobs, 1), ("--size", min(args.size), 8)):
        if value < low:
            p.error(f"{flag}: expected an int >= {low}, got {value}")
    problem = device_problem(args.device)  # names --device itself
    if problem:
        p.error(problem)


def quick_settings(args) -> list[tuple[int, str]]:
    """The sensors to calibrate; with ``--quick`` one of them, 4 grasps and a few steps (CI)."""
    if not args.quick:
        return list(SENSORS)
    args.k, args.test_grasps, args.ae_steps, args.dit_steps = 4, 2, 1, 2
    return list(SENSORS[:1])


def resumed_rows(args) -> list[dict]:
    """The rows already in ``--out`` with ``--resume``; else none."""
    if args.resume and args.out is not None and args.out.is_file():
        return json.loads(args.out.read_text())["rows"]
    return []


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.split("\n\n")[0].strip("`"))
    add_options(p)
    p.add_argument("--no-sim-record", action="store_true", help="skip the MuJoCo scene's recorded presses")
    p.add_argument("--heldout-draws", type=int, default=0, metavar="D",
                   help="also the held-out-object setting: D draws of calibration grasps per sensor, tested on "
                        "objects in neither them nor the base models' training (default 0: not run)")
    args = p.parse_args(argv)
    check_options(p, args)
    sensors, rows, t0 = quick_settings(args), resumed_rows(args), time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="calibration-bench-") as work:
        run_cases(todo_cases(sensors, (None, *range(args.heldout_draws)), rows), args, Path(work),
                  lambda row: add_row(rows, row, args, t0))
        if not (args.no_sim_record or args.quick or any(r["sensor"].startswith("sim_record") for r in rows)):
            add_row(rows, sim_record_one(args, Path(work)), args, t0)
    return summary(rows, args, t0, show=True)


def todo_cases(sensors, draws, rows: list[dict]) -> list[tuple]:
    """The (name, index, optics, draw) cases not yet in ``rows``, draw by draw in the order of ``draws`` (None: the
    same-object case), so that a run cut short has each sensor's first draws."""
    cases = [(f"unseen_{i:02d}/{o}", i, o, d) for d in draws for i, o in sensors]
    return [c for c in cases if not any(r["sensor"] == c[0] and r.get("draw") == c[3] for r in rows)]


def run_cases(cases: list[tuple], args, work: Path, on_row: Callable[[dict], None]) -> None:
    """``calibrate_one`` on each case, ``args.jobs`` processes at once; ``on_row`` saves each row as it finishes."""
    if args.jobs <= 1:
        for name, index, optics, draw in cases:
            on_row(calibrate_one(name, index, optics, args, work, draw))
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        for fut in as_completed([pool.submit(calibrate_one, *c[:3], args, work, c[3]) for c in cases]):
            on_row(fut.result())


def add_row(rows: list[dict], row: dict, args, t0: float) -> None:
    rows.append(row)
    print_table(rows[-1:], ["sensor", "cal_frames", "minutes", "calibrated_ratio", "zero_shot_ratio",
                            "generator_calibrated_ratio", "generator_zero_shot_ratio"])
    write_results(args.out, summary(rows, args, t0))


def heldout_summary(rows: list[dict]) -> dict:
    """The held-out-object setting over its (sensor, draw) cases: the decision's accuracy, the estimator's test MAE
    ÷ the constant's where it was used, the generator's MSE ÷ a copy's, minutes; against HELDOUT_TARGETS."""
    used = [r["calibrated_ratio"] for r in rows if r["use_estimator"]]
    figures = {"cases": len(rows), "decision_accuracy": float(np.mean([r["decision_right"] for r in rows])),
               # the two ways to be wrong: used where it loses to the constant (harm), declined where it wins
               "false_uses": sum(r["use_estimator"] and r["calibrated_ratio"] >= 1 for r in rows),
               "missed_uses": sum(not r["use_estimator"] and r["calibrated_ratio"] < 1 for r in rows),
               "used": len(used), "used_estimator_ratio": float(np.mean(used)) if used else None,
               "generator_ratio": float(np.mean([r["generator_calibrated_ratio"] for r in rows])),
               "minutes": cpu_minutes(rows)}
    meets = {k: None if figures[k] is None else bool(figures[k] >= t if k == "decision_accuracy" else figures[k] <= t)
             for k, t in HELDOUT_TARGETS.items()}
    return {**figures, "targets": HELDOUT_TARGETS, "meets": meets}


def cpu_minutes(rows: list[dict]) -> float | None:
    """Mean minutes of a calibration on two CPU cores: the rows that fine-tuned on the CPU of a 2-core machine (rows
    without ``machine`` ran on this project's); None where there are none."""
    cpu = [r["minutes"] for r in rows if r.get("device", "cpu") == "cpu" and r.get("machine", {}).get("cores", 2) == 2]
    return float(np.mean(cpu)) if cpu else None


def mean_present(values: list) -> float | None:
    """The mean of the values that exist: calibrate records no cross-validated ratio (None) where the constant's
    held-out error is 0 or too few grasps were held out. None where no value exists."""
    present = [v for v in values if v is not None]
    return float(np.mean(present)) if present else None


def summary(rows: list[dict], args, t0: float, show: bool = False) -> dict:
    """The results document of the sensors done so far: the mean of the unseen sensors against the targets (the
    MuJoCo scene's presses, of the training sensor, reported beside it)."""
    heldout = [r for r in rows if "draw" in r]
    rows_same = [r for r in rows if "draw" not in r]
    unseen = [r for r in rows_same if not r["sensor"].startswith("sim_record")] or rows_same
    mean = {k: mean_present([r[k] for r in unseen]) for k in ("calibrated_ratio", "zero_shot_ratio", "cv_ratio",
                                                             "generator_calibrated_ratio", "generator_zero_shot_ratio")}
    mean["minutes"] = cpu_minutes(unseen)
    verdict = {"estimator_ratio": mean["calibrated_ratio"], "generator_ratio": mean["generator_calibrated_ratio"],
               "minutes": mean["minutes"]}
    results = {"benchmark": "calibration", "settings": {k: v for k, v in vars(args).items() if k != "out"},
               "targets": TARGETS, "mean": mean,
               "meets": {k: None if verdict[k] is None else bool(verdict[k] <= TARGETS[k]) for k in TARGETS},
               "rows": rows,
               "heldout_objects": heldout_summary(heldout) if heldout else None,
               "wall_s_this_invocation": round(time.perf_counter() - t0, 1)}
    if show:
        print_table([{**mean, **{f"meets_{k}": v for k, v in results["meets"].items()}}],
                    [*mean, *[f"meets_{k}" for k in TARGETS]],
                    title="mean over sensors (ratios: estimator MAE / constant's, generator MSE / a copy's)")
        if heldout:
            h = results["heldout_objects"]
            columns = ["cases", "decision_accuracy", "used", "used_estimator_ratio", "generator_ratio", "minutes"]
            print_table([h], columns, title=f"held-out objects (targets {HELDOUT_TARGETS})")
        write_results(args.out, results)
    return results


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
