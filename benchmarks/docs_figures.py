"""The tables the docs pages gained when the README became a front door, and the README's one table of
headline figures: render functions joined to ``benchmarks.readme_figures``' ``BLOCKS`` (which owns the markers and
``--check``), written with ``benchmarks.figure_text``. Each reads committed JSONs in ``benchmarks/results/`` only.
"""

from __future__ import annotations

from functools import partial
from statistics import median

from controltac_il.metrics import wilson_interval

from benchmarks import figure_text as ft
from benchmarks import verdict_figures
from benchmarks.generator_frontier import b32


# -- the sensor model, the scene, the robot side, the cache ---------------------------------------------------

def sensor() -> str:
    doc = ft.load("sensor.json")
    speed = [[r["optics"], r["resolution"], f"{r['frames_per_s']:.0f}", f"{r['ms_per_frame']:.1f}",
              f"{r['solver_iters_median']:.0f} (max {r['solver_iters_max']})"] for r in doc["speed"]]
    labels = {"ours_three_light": "sensor model, three-light optics", "ours_polynomial": "sensor model, polynomial optics",
              "real_gelsight_mini": "real GelSight Mini (`../shared`, GPL: measured, not shipped)"}
    real = [[labels[k], f"{r['max_abs']:.0f}", f"{r['p99_abs']:.0f}", f"{r['contact_fraction']:.2f}",
             f"{r['background_noise_std']:.1f}", " / ".join(f"{v:.0f}" for v in r["contact_std_rgb"])]
            for k, r in doc["realism"].items()]
    return (ft.table(["optics", "size", "frames/s", "ms per frame", "solver iterations, median"], speed) + "\n\n"
            + ft.table(["residuals of", "max |residual|", "p99 |residual|", "contact fraction", "bare-gel noise SD",
                        "contact SD R / G / B"], real) + "\n\n" + ft.source("sensor.json", doc))


def env_speed() -> str:
    doc = ft.load("env.json")
    rows = [[r["setting"], f"{r['ms_per_step']:.1f}", timing_spread(r, "step", "steps"), f"{r['steps_per_s']:.0f}",
             f"{r['realtime_factor']:.1f}×"] for r in doc["step_timing"]]
    experts = "; ".join(f"Ø{e['hole_diameter_mm']:g} mm hole {e['successes']}/{e['episodes']}, median "
                        f"{e['median_steps_to_success']:.0f} steps" for e in doc["expert"])
    return (ft.table(["rendered per 100 ms control step", "ms per step (median)", "spread", "steps/s", "real time ×"],
                     rows)
            + f"\n\nTarget: ≥ {doc['targets']['realtime_factor_full']:g}× real time with everything rendered. "
            f"Scripted expert: {experts}.\n\n" + ft.source("env.json", doc))


def hardware() -> str:
    doc = ft.load("hardware.json")
    rows = [[r["measure"], f"{r['p50_ms']:.2f}", f"{r['p99_ms']:.2f}", f"{r['max_ms']:.2f}", r["n"]] for r in doc["table"]]
    loop = doc["control_loop"]
    return (ft.table(["measure", "p50 ms", "p99 ms", "max ms", "n"], rows)
            + f"\n\nDeadline misses of the {loop['rate_hz']:g} Hz loop: {loop['deadline_misses']}; load average "
            f"{doc['load_avg_1m']:.1f} while it ran.\n\n" + ft.source("hardware.json", doc))


def generation_chunk() -> str:
    doc = ft.load("generation_chunk.json")
    rows = [[r["pattern"], r["chunk"], r["frames"], f"{r['cpu_s']:.2f}", f"{r['frames_per_cpu_s']:.1f}",
             r["bytes_differ_from_cache_chunk"]] for r in doc["rows"]]
    header = ["pattern", "rows per forward pass", "frames", "CPU s", "frames per CPU s",
              f"bytes differing from a cache built in chunks of {doc['shipped_chunk']}"]
    return (ft.table(header, rows) + "\n\n"
            + ft.provenance("generation_chunk.json", doc, None, f", {doc['threads']} torch thread"))


def force_scaling() -> str:
    doc = ft.load("force_scaling.json")
    rows = [[r["row"], r["train_images"], f"{r['mae_n']:.2f} ± {r['sd_n']:.2f}",
             f"{r['mae_fx']:.2f} / {r['mae_fy']:.2f} / {r['mae_fz']:.2f}"] for r in doc["rows"]]
    v, pc, g = doc["verdict"], doc["physical_check"], doc["generation"]
    text = (f"One third of the real set alone: {v['third_real_vs_full']:.2f}× the full set's MAE; that third plus "
            f"generated frames: {v['third_plus_generated_vs_full']:.2f}× (target: within 1.10×, "
            f"{'met' if v['target_c_within_10pct_of_full'] else 'missed'}). Physical check (the full-real estimator "
            f"reads the generated frames against their target force): MAE {pc['generated_mae_n']:.2f} ± "
            f"{pc['generated_sd_n']:.2f} N, against {pc['real_same_targets_mae_n']:.2f} ± "
            f"{pc['real_same_targets_sd_n']:.2f} N on the real frames they stand in for; "
            f"{g['targets_clamped_to_validated_range']} of {g['frames']} generated targets were clamped to the "
            f"validated range.")
    return (ft.table(["training set", "images", "test MAE, N (± SD over test frames)", "Fx / Fy / Fz MAE, N"], rows)
            + "\n\n" + text + "\n\n" + ft.source("force_scaling.json", doc))


# -- the README's one table of headline figures ----------------------------------------------------------------

def _decision_figures(h: dict) -> str:
    """A held-out-object summary (``benchmarks.calibration.heldout_summary``) in words: the decision's accuracy with
    its count and Wilson interval, the estimator's ratio where used, the generator's."""
    right = round(h["decision_accuracy"] * h["cases"])
    return (f"right in {h['decision_accuracy']:.0%} ({right} of {h['cases']}, Wilson 95 % "
            + "–".join(f"{x * 100:.0f}" for x in wilson_interval(right, h["cases"]))
            + f" %; target ≥ {h['targets']['decision_accuracy']:.0%}), the estimator where used "
            + ("never" if h["used_estimator_ratio"] is None else f"{h['used_estimator_ratio']:.2f}×")
            + f" the constant's, generator {h['generator_ratio']:.2f}×")


def calibration_row(cal: dict, rule: dict, src: dict) -> list[str]:
    """The few-shot calibration's headline row; with the decision's level tested once on new cases
    (``calibration_rule.json``'s complete test split), those figures beside the first held-out cases'."""
    unseen = [r for r in cal["rows"] if not r["sensor"].startswith("sim_record") and "draw" not in r]
    m, t, h = cal["mean"], cal["targets"], cal.get("heldout_objects")
    frames = sorted({r["cal_frames"] for r in unseen})
    heldout = "" if not h else f"; on objects it never saw ({h['cases']} cases): its use-or-decline decision " + \
        _decision_figures(h)
    test, source = rule.get("test", {}), src["calibration.json"]
    done, of = rule_counts(rule)["test"]
    if test.get("figures") and done == of:
        heldout += (f"; its {test['level']:.0%} level, chosen on {len(rule['validation']['rows'])} other cases and "
                    f"tested once on {len(test['rows'])} more: " + _decision_figures(test["figures"]))
        source += ", " + src["calibration_rule.json"]
    return [f"few-shot calibration of {len(unseen)} simulated sensor instances never seen "
            f"({'-'.join(map(str, frames[::max(1, len(frames) - 1)]))} labelled frames each)",
            f"estimator Fz MAE {m['calibrated_ratio']:.2f}× the constant's (target ≤ {t['estimator_ratio']}×), generator "
            f"{m['generator_calibrated_ratio']:.2f}× a copy's (target ≤ {t['generator_ratio']}×), "
            f"{_minutes(m['minutes'])} min each{heldout}", "over sensors: estimator "
            f"{min(r['calibrated_ratio'] for r in unseen):.2f}-{max(r['calibrated_ratio'] for r in unseen):.2f}×, generator "
            f"{min(r['generator_calibrated_ratio'] for r in unseen):.2f}-{max(r['generator_calibrated_ratio'] for r in unseen):.2f}×",
            "[calibration](docs/calibration.md#calibrate-to-your-own-sensor)", source]


def touch_il_verdict_v2() -> str:
    """The verdict v2's docs block (``benchmarks.verdict_figures``)."""
    doc = ft.load("touch_il_verdict_v2.json")
    return verdict_figures.block(doc, ft.provenance("touch_il_verdict_v2.json", doc, None))


def touch_il_verdict_v3() -> str:
    """The confirmatory verdict's docs block, running or decided (``benchmarks.verdict_figures``)."""
    doc = ft.load("touch_il_verdict_v3.json")
    return verdict_figures.block(doc, ft.provenance("touch_il_verdict_v3.json", doc, None))


def headline() -> str:
    """One row per headline figure: what, the figure, its spread or interval, its docs section, its JSON."""
    names = ("generator.json", "finetune.json", "calibration.json", "touch_il_verdict.json", "env.json", "act_speed.json",
             "generator_speed.json", "touch_il_verdict_v2.json", "finetune_quality.json", "touch_il_verdict_v3.json",
             "generator_speed_gpu.json", "calibration_rule.json")
    gen, fin, cal, ver, env, act, speed, v2, fin_q, v3, gpu, rule = docs = [ft.load(n) for n in names]
    src = {n: f"`{n}` ({doc['machine']['git_commit']}, {doc['machine']['date_utc'][:10]})"
           + (" *History*" if ft.source(n, doc).startswith("*History") else "") for n, doc in zip(names, docs)}
    first, last, first_q = fin["rows"][0], fin["rows"][-1], fin_q["rows"][0]
    last_q = next((r for r in fin_q["rows"] if r["images"] == last["images"]), None)  # None while its run goes on
    vis = next(c for c in ver["comparisons"] if (c["variant"], c["setting"]) == ("vision_only", "nominal"))
    full, expert = env["step_timing"][-1], env["expert"][0]
    lo, hi = (ft.pct(x) for x in wilson_interval(expert["successes"], expert["episodes"]))
    cpu = next(r for r in act["latency"] if r["preset"] == "cpu")
    verdict_link = "[experiments](docs/experiments.md#the-verdict-v1)"
    rows = [
        *(_preset_row(gen, speed, gpu, name, src) for name in ("fast", "default", "quality")),
        [f"calibration to a held-out sensor ({last['images']:,} presses)".replace(",", " "), f"generator from `default` "
         f"{last['mse_ratio_to_copy']:.3f}× a copy's MSE (zero-shot {first['mse_ratio_to_copy']:.3f}×), from `quality` "
         + (f"{last_q['mse_ratio_to_copy']:.3f}×" if last_q else "not yet measured")
         + f" (zero-shot {first_q['mse_ratio_to_copy']:.3f}×); estimator Fz MAE "
         f"{first['estimator_mae'][2]:.2f} → {last['estimator_mae'][2]:.2f} N",
         f"MSE {last['mse']:.1f} ± {last['mse_sd']:.1f}" + (f" / {last_q['mse']:.1f} ± {last_q['mse_sd']:.1f}" if last_q else "")
         + f" SD over {last['n']} pairs",
         "[calibration](docs/calibration.md#what-calibration-buys-the-fine-tuning-curve)",
         f"{src['finetune.json']}, {src['finetune_quality.json']}"],
        calibration_row(cal, rule, src),
        *verdict_figures.headline_rows_v3(v3, src["touch_il_verdict_v3.json"]),
        *verdict_figures.headline_rows(v2, src["touch_il_verdict_v2.json"]),
        ["touch matters: ACT without its tactile streams vs with them, grip as in the demos",
         f"{vis['diff'] * 100:+.1f} points: **{vis['verdict']}**", ft.ci_points(vis) + " (95 % CI)", verdict_link,
         src["touch_il_verdict.json"]],
        [f"MuJoCo scene speed ({full['setting']} rendered)", f"{full['realtime_factor']:.1f}× real time "
         f"({full['ms_per_step']:.1f} ms per 100 ms step); scripted expert {expert['successes']}/{expert['episodes']}",
         f"{timing_spread(full, 'step', 'steps')}; expert [{lo}, {hi}] % (Wilson 95 %)",
         "[scene](docs/act_and_deployment.md#scene-speed)", src["env.json"]],
        [f"ACT latency ({cpu['preset']} preset, {cpu['threads']} torch thread, CPU)",
         f"{cpu['ms_per_chunk']:.1f} ms per chunk of {cpu['chunk']} (target {cpu['target_ms']:.0f})",
         timing_spread(cpu, "call", "calls"), "[ACT](docs/act_and_deployment.md#speed)", src["act_speed.json"]]]
    return ft.table(["what", "measured", "error or interval", "details", "source (`benchmarks/results/`)"], rows)


def timing_spread(row: dict, unit: str, count: str) -> str:
    """The interquartile range of a timed median (ms), or that the JSON holds one timing."""
    if "ms_quartiles" not in row:
        return "one timing, no interval"
    lo, hi = row["ms_quartiles"]
    return f"{lo:.1f}–{hi:.1f} ms per {unit} (interquartile, {row[count]} {count})"


def _preset_row(gen: dict, speed: dict, gpu: dict, name: str, src: dict) -> list:
    """A shipped generator preset at DDIM-1: its speed on the CPU and on the GPU (median, range over rounds) and,
    beside each, its error at 240×320 on the pairs ForceAugment asks for (``generator.json``'s split: the nominal
    sensor, held-out objects) and on the symmetric held-out-object pairs."""
    m = next(m for m in gen["methods"] if m["method"] == f"{name} DDIM-1")
    s = next(r for r in speed["rows"] if (r["checkpoint"], r["frames"], r["steps"]) == (name, "240", 1) and b32(r))
    g = next(r for r in gpu["rows"] if (r["checkpoint"], r["frames"], r["batch"]) == (name, "240", "auto"))
    fa = gen["forceaugment_split"]["rows"]
    f = next(r for r in fa if (r["size"], r["sensor"]) == ("240", "nominal"))["presets"][name]
    copy = next(m for m in gen["methods"] if m["kind"] == "copy")["unseen_240"]["mse"]
    ratio, q = m["unseen_240"]["mse"] / copy, m["unseen_240"]
    objects, threads = len(gen["settings"]["splits"]["unseen_240"]["objects"]), speed["settings"]["threads"]
    return [f"generator preset `{name}` ({m['parameters'] / 1e6:.2f} M-parameter DiT, DDIM-1, batch 32, {threads} CPU threads)",
            f"{s['img_per_s_b32']:.1f} img/s on 240×320 frames; MSE on the pairs ForceAugment asks for "
            f"**{f['all']['ratio']:.3f}×** a reference copy's (pressing harder {f['increase']['ratio']:.3f}×), on "
            f"symmetric pairs {ratio:.3f}× ({objects} held-out objects; target ≤ 0.25×: "
            f"{'met' if ratio <= 0.25 else 'missed'}); on an NVIDIA H200 "
            f"{median(g['img_per_s_rounds']):.0f} img/s at the auto batch, {g['mse_ratio_to_copy']:.3f}× there",
            f"speed {min(s['img_per_s_rounds']):.1f}–{max(s['img_per_s_rounds']):.1f} over {len(s['img_per_s_rounds'])} "
            f"rounds (H200 {min(g['img_per_s_rounds']):.0f}–{max(g['img_per_s_rounds']):.0f}); MSE {q['mse']:.1f} ± "
            f"{q['mse_sd']:.1f} SD over {q['n']} symmetric pairs, {f['all']['pairs']} ForceAugment pairs",
            "[generator](docs/generator.md#where-forceaugment-uses-it)",
            f"{src['generator.json']}, {src['generator_speed.json']}, {src['generator_speed_gpu.json']}"]


def calibration() -> str:
    """``calibrate`` per sensor on its test grasps, and the mean of the unseen sensors against the targets."""
    doc = ft.load("calibration.json")
    t = doc["targets"]

    def row(r: dict, name: str) -> list:
        lags = sum(-a == b for a, b in zip(r["lags_true"], r["lags_found"]))  # a log late by L needs the shift -L
        return [name, f"{r['grasps']} / {r['cal_frames']}", f"{r['calibrated_ratio']:.2f}× ({r['calibrated_mae_n']:.2f} N)",
                f"{r['zero_shot_ratio']:.2f}×", f"{r['cv_ratio']:.2f}×", f"{r['generator_calibrated_ratio']:.2f}×",
                f"{r['generator_zero_shot_ratio']:.2f}×", _minutes(r["minutes"]), f"{lags}/{len(r['lags_true'])}",
                r.get("commit", doc["machine"]["git_commit"])]

    m = doc["mean"]
    rows = [row(r, f"`{r['sensor']}`") for r in doc["rows"] if "draw" not in r]  # the same-object setting
    rows.append(["**mean of the unseen sensors**", "", f"**{m['calibrated_ratio']:.2f}×** (target ≤ {t['estimator_ratio']}×)",
                 f"{m['zero_shot_ratio']:.2f}×", f"{m['cv_ratio']:.2f}×",
                 f"**{m['generator_calibrated_ratio']:.2f}×** (target ≤ {t['generator_ratio']}×)",
                 f"{m['generator_zero_shot_ratio']:.2f}×", f"**{_minutes(m['minutes'])}** (target ≤ {t['minutes']:.0f})", "", ""])
    head = ["sensor", "grasps / frames", "estimator MAE ÷ constant's (calibrated)", "zero-shot", "its own CV estimate",
            "generator MSE ÷ copy's (calibrated)", "zero-shot", "minutes", "lags found", "commit"]
    return ft.table(head, rows) + "\n\n" + ft.source("calibration.json", doc)


def _minutes(value: float | None) -> str:
    """Minutes of a calibration on two CPU cores, or a dash where none were timed there."""
    return "–" if value is None else f"{value:.1f}"


def calibration_heldout() -> str:
    """The held-out-object setting case by case: ``calibrate``'s own leave-one-grasp-out estimate and decision, the
    test on objects it never saw, whether the decision was right; the summary against the targets."""
    doc = ft.load("calibration.json")
    h = doc.get("heldout_objects")
    if not h:
        return "Not yet measured: `calibration.json` holds no held-out-object case. " + ft.source("calibration.json", doc)
    rows = [[f"`{r['sensor']}`", r["draw"], f"{r['cv_ratio']:.2f}× [{r['cv_interval'][0]:.2f}, {r['cv_interval'][1]:.2f}]",
             f"{r['cv_wins']} of {r['cv_grasps']}", "used" if r["use_estimator"] else "declined",
             f"{r['calibrated_ratio']:.2f}×", "yes" if r["decision_right"] else "**no**",
             f"{r['generator_calibrated_ratio']:.2f}× ({r['generator_zero_shot_ratio']:.2f}×)", _minutes(r["minutes"])]
            for r in sorted((r for r in doc["rows"] if "draw" in r), key=lambda r: (r["sensor"], r["draw"]))]
    t, ok = h["targets"], {k: "met" if v else "missed" for k, v in h["meets"].items()}
    used = "–" if h["used_estimator_ratio"] is None else f"{h['used_estimator_ratio']:.2f}×"
    sensors = {r["sensor"] for r in doc["rows"] if "draw" not in r and r["sensor"].startswith("unseen_")}
    losing = sum(r["calibrated_ratio"] >= 1 for r in doc["rows"] if "draw" in r)
    coverage = (f"{h['cases']} of the {len(sensors) * doc['settings']['heldout_draws']} cases measured "
                f"({len(sensors)} sensors × {doc['settings']['heldout_draws']} draws); in {losing} of them the "
                "estimator loses to the constant on the new objects, the side where declining is right. ")
    summary = coverage + (f"Decision right in **{h['decision_accuracy']:.0%}** of {h['cases']} cases (target ≥ "
               f"{t['decision_accuracy']:.0%}: {ok['decision_accuracy']}; wrong by using an estimator that loses to "
               f"the constant in {h['false_uses']}, by declining one that beats it in {h['missed_uses']}); used in "
               f"{h['used']}, where the test MAE is "
               f"**{used}** the constant's on the mean (target ≤ {t['used_estimator_ratio']}×: "
               f"{ok['used_estimator_ratio']}); generator **{h['generator_ratio']:.2f}×** a copy's (target ≤ "
               f"{t['generator_ratio']}×: {ok['generator_ratio']}); **{_minutes(h['minutes'])}** min a calibration on "
               f"two cores (target ≤ {t['minutes']:.0f}).")
    head = ["sensor", "draw", "its own held-out estimate [95 %]", "grasps won", "decision",
            "test MAE ÷ constant's (held-out objects)", "right", "generator ÷ copy's (zero-shot)", "minutes"]
    return ft.table(head, rows) + "\n\n" + summary + "\n\n" + ft.source("calibration.json", doc)


def calibration_rule() -> str:
    """The decision's interval level, case by case on the validation and test draws: each level's upper end and
    decision beside the test on objects it never saw; each level's scores per split, validation's choice marked;
    the test's figures of ``calibrate``'s own decisions against the targets."""
    from benchmarks.calibration_rule import LEVELS
    from controltac_il.calibrate.decision import decide

    doc = ft.load("calibration_rule.json")
    splits = [s for s in ("validation", "test") if doc.get(s, {}).get("rows")]
    counts = rule_counts(doc)
    rows, scores = [], []
    for split in splits:
        for r in sorted(doc[split]["rows"], key=lambda r: (r["draw"], r["sensor"])):
            ds = [decide(r["cv_per_grasp"], level) for level in LEVELS]
            ends = " / ".join("–" if d["interval"][1] is None else f"{d['interval'][1]:.2f}" for d in ds)
            uses = " / ".join("used" if d["use"] else "declined" for d in ds)
            beats = "yes" if r["calibrated_ratio"] < 1 else "**no**"
            rows.append([split, f"`{r['sensor']}`", r["draw"], f"{r['cv_ratio']:.2f}×", ends,
                         f"{r['cv_wins']} of {r['cv_grasps']}", uses, f"{r['calibrated_ratio']:.2f}×", beats,
                         _minutes(r["minutes"])])
        complete = counts[split][0] == counts[split][1]
        chosen = doc[split].get("chosen_level", doc[split].get("level")) if complete else None
        scores += [[split, f"**{s['level']:.0%}**" if s["level"] == chosen else f"{s['level']:.0%}",
                    f"{s['decision_accuracy']:.0%}", s["false_uses"], s["missed_uses"], s["used"]]
                   for s in doc[split]["levels"]]
    levels = " / ".join(f"{level:.0%}" for level in LEVELS)
    head = ["split", "sensor", "draw", "held-out estimate", f"upper end at {levels}", "grasps won",
            f"decision at {levels}", "test MAE ÷ constant's (held-out objects)", "beats the constant", "minutes"]
    out = ft.table(head, rows) + "\n\n" + ft.table(["split", "level (bold: chosen, once the split is complete)",
                                                      "decision right", "false uses", "missed uses", "used"], scores)
    out += "\n\n" + _rule_summary(doc, counts)
    return out + "\n\n" + "\n".join(ft.source("calibration_rule.json", doc[s]) for s in splits)


def rule_counts(doc: dict) -> dict[str, tuple[int, int]]:
    """{split: (cases in, cases of the split)} of ``calibration_rule.json``: a split is complete when they are equal
    (every sensor of ``benchmarks.calibration`` at every draw of the split)."""
    from benchmarks.calibration import SENSORS

    return {s: (len(doc.get(s, {}).get("rows", [])), len(draws) * len(SENSORS))
            for s, draws in doc["protocol"]["splits"].items()}


def _rule_summary(doc: dict, counts: dict) -> str:
    """How far each split is (``counts``: {split: (cases in, cases of the split)}), the level validation chose, and
    the test's figures against the targets."""
    val, test = doc.get("validation", {}), doc.get("test", {})
    line = "Validation: {} of {} cases".format(*counts["validation"])
    if counts["validation"][0] == counts["validation"][1]:
        line += f", chose the {val['chosen_level']:.0%} level"
    line += ". Test: {} of {} cases".format(*counts["test"])
    f = test.get("figures")
    if not f:
        return line + "."
    used = "–" if f["used_estimator_ratio"] is None else f"{f['used_estimator_ratio']:.2f}×"
    ok = {k: "met" if v else "missed" for k, v in f["meets"].items()}
    return line + (f" at the {test['level']:.0%} level: decision right in **{f['decision_accuracy']:.0%}** (target ≥ "
                   f"{f['targets']['decision_accuracy']:.0%}: {ok['decision_accuracy']}; false uses "
                   f"{f['false_uses']}, missed uses {f['missed_uses']}); used in {f['used']}, where the test MAE is "
                   f"**{used}** the constant's (target ≤ {f['targets']['used_estimator_ratio']}×: "
                   f"{ok['used_estimator_ratio']}); generator **{f['generator_ratio']:.2f}×** a copy's (target ≤ "
                   f"{f['targets']['generator_ratio']}×: {ok['generator_ratio']}); **{_minutes(f['minutes'])}** min a "
                   "calibration on two cores.")


def calibration_methods() -> str:
    """Each estimator calibration method at every K: its test MAE's ratio to the constant's, over sensors x draws."""
    doc = ft.load("calibration_methods.json")
    rows = [[r["k"], f"`{r['method']}`", f"{r['cal_frames']:.0f}", f"{r['mae']:.2f} ± {r['mae_sd']:.2f}",
             f"{r['ratio']:.2f}× ± {r['ratio_sd']:.2f}", f"{r['ratio_worst']:.2f}×",
             "" if r["corr"] is None else f"{r['corr']:.2f}", f"{r['fit_ms']:.0f}", r["n"]]
            for r in doc["summary"] if r["method"] != "constant"]
    head = ["K grasps", "method", "frames", "Fz MAE, N (± SD)", "÷ constant's (± SD)", "worst", "corr", "fit ms", "n"]
    return ft.table(head, rows) + "\n\n" + ft.source("calibration_methods.json", doc)


# -- calibration ----------------------------------------------------------------------------------------------

FINETUNE = {"default": "finetune.json", "quality": "finetune_quality.json"}  # the fine-tuning curve per base preset


def _presses(n: int) -> str:
    return "0 (zero-shot)" if n == 0 else f"{n:,}".replace(",", " ")


def _cells(rows: dict, budgets: list[int], fmt) -> list[str]:
    """``fmt(row)`` per budget; a budget the run has not reached yet reads "–"."""
    return [fmt(rows[n]) if n in rows else "–" for n in budgets]


def _mae(row: dict) -> str:
    return "{2:.2f} ({0:.2f} / {1:.2f})".format(*row["estimator_mae"])  # Fz (Fx / Fy), N


def finetune() -> str:
    """The fine-tuning curve (benchmarks.finetune) from each base preset on one held-out sensor: the generator's
    MSE ÷ a copy's, SSIM, the estimator's MAE (fine-tuned alike in both runs) and the wall time per budget."""
    docs = {name: ft.load(f) for name, f in FINETUNE.items()}
    budgets = [r["images"] for r in docs["default"]["rows"]]
    by = {name: {r["images"]: r for r in d["rows"]} for name, d in docs.items()}
    alike = len({tuple(_cells(rows, budgets, _mae)) for rows in by.values()}) == 1  # the estimator owes nothing to the base
    body = []
    for name, rows in by.items():
        cells = partial(_cells, rows, budgets)
        body += [[f"`{name}` ({docs[name]['base_hash']}): MSE ÷ a copy's (MSE)",
                  *cells(lambda r: f"{r['mse_ratio_to_copy']:.3f} ({r['mse']:.1f})")],
                 [f"`{name}`: SSIM", *cells(lambda r: f"{r['ssim']:.3f}")],
                 *([] if alike else [[f"`{name}`: estimator MAE Fz (Fx / Fy), N", *cells(_mae)]]),
                 [f"`{name}`: wall time, min", *cells(lambda r: f"{r['wall_s'] / 60:.1f}")]]
    if alike:
        body.append(["estimator MAE Fz (Fx / Fy), N (the same in both runs)", *_cells(by["default"], budgets, _mae)])
    copy = docs["default"]["rows"][0]
    head = [f"presses (copy: MSE {copy['copy_mse']:.1f}, SSIM {copy['copy_ssim']:.3f})", *map(_presses, budgets)]
    return ft.table(head, body) + "\n\n" + "\n".join(
        ft.provenance(f, docs[name], None, f", base `{name}` {docs[name]['base_hash']}") for name, f in FINETUNE.items())


# -- the generator's frontier ---------------------------------------------------------------------------------

def _frontier_order() -> tuple[str, ...]:
    from benchmarks.generator_frontier import FRONTIER

    return ("fast", "default", *FRONTIER)


def _card(name: str) -> dict:
    """A shipped checkpoint's model card (its training and its own validation curve; committed beside it)."""
    from controltac_il.checkpoint import read_json
    from controltac_il.generator.shipped import locate_checkpoint

    return read_json(locate_checkpoint(name) / "model_card.json")


def generator_frontier() -> str:
    """Every size at DDIM 1 / 2 / 5: error on unseen objects at 240×320 and elsewhere (× a copy's), on real frames,
    its own validation, speed on 2 CPU threads (generator_speed.json: median and range over rounds) and on the GPU
    (generator_speed_gpu.json)."""
    doc, cpu, gpu = (ft.load(n) for n in ("generator.json", "generator_speed.json", "generator_speed_gpu.json"))
    copy = {k: v for k, v in next(m for m in doc["methods"] if m["kind"] == "copy").items() if isinstance(v, dict)}
    on_gpu = {(r["hash"], r["steps"]): median(r["img_per_s_rounds"]) for r in gpu["rows"]
              if r["frames"] == "240" and b32(r)}
    on_cpu = {(r["hash"], r["steps"]): r for r in cpu["rows"] if r["frames"] == "240" and b32(r)}
    hashes = {k: v["hash"] for k, v in doc["settings"]["checkpoints"].items()}
    rows = []
    for kind in _frontier_order():
        val = _card(kind)["denoiser"].get("validation") or {}
        for m in (m for m in doc["methods"] if m["kind"] == kind and m["steps"] in (1, 2, 5)):
            ratio = {k: m[k]["mse"] / copy[k]["mse"] for k in ("unseen", "unseen_240", "unseen_sensor")}
            real = m.get("real") or {}
            rows.append([f"`{kind}`" if m["steps"] == 1 else "", f"{m['parameters'] / 1e6:.2f} M" if m["steps"] == 1 else "",
                         m["steps"], f"**{ratio['unseen_240']:.3f}**", f"{ratio['unseen']:.3f}", f"{ratio['unseen_sensor']:.3f}",
                         f"{real['identity_mse']:.1f}" if real else "–", ("yes" if real["monotone"] else "**no**") if real else "–",
                         _validation(val) if m["steps"] == 1 else "",
                         _speed(on_cpu[(hashes[kind], m["steps"])]), f"{on_gpu[(hashes[kind], m['steps'])]:.0f}"
                         if (hashes[kind], m["steps"]) in on_gpu else "–", f"{m['peak_rss_mb']:.0f}"])
    head = ["size", "DiT params", "DDIM", "unseen 240 MSE ÷ copy", "unseen", "unseen sensor", "real: MSE at ΔF = 0",
            "real: monotone", "its validation ÷ copy", "img/s b32 240, 2 CPU threads (range)", "img/s b32 240, H200",
            "peak MB (CPU, b32)"]
    return (ft.table(head, rows) + "\n\n" + ft.source("generator.json", doc) + "\n"
            + ft.source("generator_speed.json", cpu) + "\n" + ft.source("generator_speed_gpu.json", gpu))


def generator_device() -> str:
    """Every shipped size on the GPU (generator_speed_gpu.json): img/s at batch 32, 256 and auto with the error beside
    it, at 240×320 and 120×160, DDIM-1; the presets in half precision (generator_speed_gpu_dtypes.json); the CPU path
    before and after, interleaved, and its bytes (generator_cpu_change.json)."""
    gpu, half, cpu = (ft.load(n) for n in ("generator_speed_gpu.json", "generator_speed_gpu_dtypes.json",
                                           "generator_cpu_change.json"))
    cell = {(r["checkpoint"], r["frames"], r["batch"]): r for r in gpu["rows"]}
    batches = gpu["settings"]["batch_sizes"]
    rows = [[f"`{name}`", f"{hw[0]}×{hw[1]}", *(_speed(cell[(name, size, b)]) for b in batches),
             f"{cell[(name, size, batches[0])]['mse_ratio_to_copy']:.3f}", f"{cell[(name, size, 'auto')]['batch_rows']}",
             f"{cell[(name, size, 'auto')]['peak_cuda_mb']:.0f}"]
            for name in dict.fromkeys(r["checkpoint"] for r in gpu["rows"])
            for size, hw in gpu["settings"]["frames"].items()]
    speed = ft.table(["size", "frames", *(f"img/s, batch {b}" for b in batches), "MSE ÷ copy (unseen)",
                      "auto picked", "peak MB"], rows)
    f32 = {(r["checkpoint"], r["frames"]): r for r in gpu["rows"] if r["batch"] == "auto"}
    dtype_rows = [[f"`{r['checkpoint']}`", r["frames"], r["dtype"], _speed(r), f"{r['mse_ratio_to_copy']:.4f}",
                   _speed(f32[(r["checkpoint"], r["frames"])]), f"{f32[(r['checkpoint'], r['frames'])]['mse_ratio_to_copy']:.4f}"]
                  for r in half["rows"]]
    dtypes = ft.table(["size", "frames", "dtype", "img/s, auto", "MSE ÷ copy", "float32 img/s", "float32 MSE ÷ copy"],
                      dtype_rows)
    change = ft.table(["size", "frames", "DDIM", "before img/s (rounds)", "after img/s (rounds)", "after ÷ before"],
                      [[f"`{r['checkpoint']}`", r["frames"], r["steps"], _rounds(r["before_img_per_s"], r["before_rounds"]),
                        _rounds(r["after_img_per_s"], r["after_rounds"]), f"{r['after_over_before']:.2f}"]
                       for r in cpu["speed"]])
    same = ", ".join(f"{b['output']} {b['max_diff']} ({b['values']:,} values)" for b in cpu["bytes"])
    return (speed + "\n\n" + ft.source("generator_speed_gpu.json", gpu) + "\n\n" + dtypes + "\n\n"
            + ft.source("generator_speed_gpu_dtypes.json", half) + "\n\n" + change + "\n\nLargest grey-level "
            f"difference of the outputs, after against before: {same}.\n\n" + ft.source("generator_cpu_change.json", cpu))


def _rounds(value: float, rounds: list) -> str:
    return f"{value:.1f} ({min(rounds):.1f}–{max(rounds):.1f})"


def _validation(val: dict) -> str:
    """A card's best validation ratio and its step; ``fast`` was trained before runs held out validation objects."""
    best = val.get("best")
    return f"{best['ratio_to_copy']:.3f} (step {val['best_step']})" if best else "none (trained before validation splits)"


def _speed(row: dict) -> str:
    """Median img/s over rounds with the rounds' range."""
    rounds = row["img_per_s_rounds"]
    return _rounds(median(rounds), rounds)


BLOCKS = {"calibration": calibration, "calibration-heldout": calibration_heldout,
          "calibration-methods": calibration_methods, "calibration-rule": calibration_rule, "sensor": sensor,
          "env-speed": env_speed, "hardware": hardware, "generation-chunk": generation_chunk,
          "force-scaling": force_scaling, "headline": headline, "generator-frontier": generator_frontier,
          "generator-device": generator_device,
          "touch-il-verdict-v2": touch_il_verdict_v2, "touch-il-verdict-v3": touch_il_verdict_v3, "finetune": finetune}
