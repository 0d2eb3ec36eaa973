"""benchmarks.verdict_figures: the verdict's docs block and README rows (v2 and v3) from a grid's JSON, finished or
running; a v3 look is printed only once complete."""

import json
import re
from pathlib import Path

import cv2
import pytest

from benchmarks import verdict
from benchmarks import verdict_protocols as vp
from benchmarks import verdict_figures as vf
from benchmarks import verdict_report as vr

SEEDS = list(range(10))
V2 = vp.PROTOCOLS["v2"]
SETTINGS = list(V2.settings)


def _outcomes(rate: float, episodes: int = 10) -> list[int]:
    return [1] * round(rate * episodes) + [0] * (episodes - round(rate * episodes))


def _doc(tests: bool = True) -> dict:
    """A grid's JSON: real at 50 %, fa2 at 90 % everywhere, fa2_range = real, image_aug at 10 %; validation best at
    step 3000. Its protocol holds the fields the tables read (the grid writes ``verdict_protocols.record``)."""
    rate = {"real": 0.5, "fa2": 0.9, "fa2_range": 0.5, "image_aug": 0.1}
    train = [{"kind": "train", "variant": v, "seed": s,
              "validation": {str(k): _outcomes(0.6 if k == 3000 else 0.4) for k in V2.snapshots}}
             for s in SEEDS for v in V2.variants]
    test = [{"kind": "test", "variant": v, "seed": s, "test": {st: _outcomes(rate[v]) for st in SETTINGS}}
            for s in SEEDS for v in V2.variants] if tests else []
    protocol = {"settings": {k: list(b) for k, b in V2.settings.items()}, "stress_test": vp.STRESS,
                "copies": vp.COPIES, "force_settings": {v: {k: list(x) for k, x in f.items()} for v, f in vp.FORCE_SETTINGS.items()},
                "variants": list(V2.variants), "train_seeds": SEEDS, "recipe": {"snapshots": list(V2.snapshots)}}
    doc = {"benchmark": "touch_il_verdict_v2", "protocol": protocol, "units": train + test, "power_statement": "stated first",
           "force_augment_counts": {"fa2_range": {"clamped_fraction_of_contact": 0.068, "regenerated": 6016,
                                                  "requested_fz_quantiles": [1.52, 5.22, 9.95]}}}
    doc["table"], doc["comparisons"] = vr.summarise_seed_level(test, V2.variants, SEEDS, SETTINGS, V2.primary, 10, reps=50)
    if tests:
        doc["steps"] = {v: verdict.choose_step([u for u in train if u["variant"] == v], V2.snapshots) for v in V2.variants}
    return doc


def test_the_block_reports_each_variant_at_its_step_with_its_spread_and_the_primary_verdicts_first():
    doc = _doc()
    text = vf.block(doc, "*source*")
    rows = {}  # the success table's row of each variant: the first table naming it
    for line in text.splitlines():
        if line.startswith("| "):
            rows.setdefault(line.split(" | ")[0].strip("| "), line)
    assert re.match(r"\| fa2 \| 3000 \| 90 % \[\d+, \d+\], SD 0, 0/10 below real's worst \|", rows["fa2"])
    assert re.search(r"10 % \[\d+, \d+\], SD 0, 10/10 below real's worst", rows["image_aug"])
    assert "below" not in rows["real"]
    comparisons = [line for line in text.splitlines() if " vs real | " in line]
    assert len(comparisons) == 9 and all("secondary" in line for line in comparisons[6:])
    fa2 = next(line for line in comparisons if line.startswith("| fa2 vs real | nominal"))
    assert re.search(r"\| \+40\.0 \[\+\d+\.\d, \+\d+\.\d\] \|", fa2) and fa2.endswith("| **helps** |")  # 10 seeds all +40: p = 2/1024, Holm x6
    assert f"| {2 / 1024 * 6:.3g} |" in fa2
    assert any(line.startswith("| fa2_range vs real") and "**no detectable effect**" in line for line in comparisons)
    assert "grip_11-14 (11–14 N, stress test)" in text and "| **60** |" in text  # step 3000 chosen on validation
    assert "| fa2_range | 6.8 % | 1.5 / 5.2 / 9.9 | 6016 |" in text


def test_the_readme_rows_are_one_per_primary_variant_in_setting_order():
    rows = vf.headline_rows(_doc(), "src")
    assert [r[0].split("`")[1] for r in rows] == ["fa2", "fa2_range"]
    assert rows[0][1].startswith("+40.0 / +40.0 / +40.0 points (nominal (4–7 N) / ")
    assert rows[0][1].endswith("**helps** / **helps** / **helps**") and "10 paired training seeds" in rows[0][0]
    assert "(2 copies, the paper's offsets)" in rows[0][0] and "(2 copies, targets over 1–10 N)" in rows[1][0]
    assert rows[1][1].endswith(" / ".join(["**no detectable effect**"] * 3))


def test_a_running_grid_prints_provisional_steps_and_pending_tests(tmp_path, capsys):
    path = tmp_path / "grid.json"
    path.write_text(json.dumps(_doc(tests=False)))
    assert vf.main([str(path)]) == 0
    out = capsys.readouterr().out
    assert "steps provisional" in out and "Comparisons: pending" in out
    assert "| real | 3000 | pending | pending | pending |" in out


@pytest.mark.parametrize("content, says", [(None, "No such file"), ("{", "Expecting"),
                                           ('{"benchmark": "touch_il_verdict"}', "not the JSON of"),
                                           ('{"benchmark": "touch_il_verdict_v2"}', "incomplete or malformed (KeyError")])
def test_a_missing_or_foreign_json_is_one_line_and_exit_2(tmp_path, content, says):
    import subprocess
    import sys

    path = tmp_path / "grid.json"
    if content is not None:
        path.write_text(content)
    run = subprocess.run([sys.executable, "-m", "benchmarks.verdict_figures", str(path)], capture_output=True, text=True)
    assert run.returncode == 2 and run.stderr.count("\n") == 1 and says in run.stderr
    assert run.stderr.startswith("python -m benchmarks.verdict_figures: error: ")


def _v3_doc(tested_seeds: int, trained: int = 12, fa2=lambda seed: 0.8) -> dict:
    """A v3 grid after its first ``trained`` seeds' train units, ``tested_seeds`` of them tested: `real` 60 %,
    `fa2` at ``fa2(seed)`` (every seed +20 points by default)."""
    v3, seeds = vp.PROTOCOLS["v3"], list(range(12, 36))
    units = [{"id": f"train-{v}-s{s}", "kind": "train", "variant": v, "seed": s, "augment_digest": "d",
              **({"test": {k: _outcomes(fa2(s) if v == "fa2" else 0.6, n) for k, n in v3.test_episodes.items()}}
                 if i < tested_seeds else {})}
             for i, s in enumerate(seeds[:trained]) for v in v3.variants]
    looks = [{"seeds": lk.seeds, "alpha": lk.alpha, "futility": lk.futility} for lk in v3.looks]
    doc = {"benchmark": "touch_il_verdict_v3", "units": units, "steps": {v: {"step": 8000} for v in v3.variants},
           "protocol": {"demos": 50, "power": {"statement": "stated first"}, "looks": looks, "variants": list(v3.variants),
                        "train_seeds": seeds, "primary": [list(x) for x in v3.primary], "copies": vp.COPIES,
                        "force_settings": {"fa2": {}},
                        "settings": {k: list(b) for k, b in v3.settings.items()}, "stress_test": vp.STRESS,
                        "recipe": {"snapshots": list(v3.snapshots)}},
           "force_augment_counts": {}}
    verdict.report(doc, v3, seeds, Path("/nonexistent"), None, picture=False, reps=50)
    return doc


def test_v3_prints_a_look_only_once_complete_and_its_readme_row_says_running_until_then(tmp_path, capsys):
    path = tmp_path / "v3.json"
    path.write_text(json.dumps(_v3_doc(tested_seeds=11)))
    with pytest.raises(SystemExit) as exc:
        vf.main([str(path), "--look", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and "--look: look 1 is analysed once its 24 units are tested; 22 are" in err[0]
    running = _v3_doc(tested_seeds=11)
    assert vf.headline_rows_v3(running, "src")[0][1] == "running: no look complete yet"
    assert ("| 1 | 12 | p < 0.001 | mean <= 0 stops | pending: 24 of 24 units trained, 22 tested at their step |"
            in vf.looks_table(running))
    done = _v3_doc(tested_seeds=12)
    path.write_text(json.dumps(done))
    assert vf.main([str(path), "--look", "1"]) == 0
    assert "efficacy: helps (fa2 - real at nominal: +20.0 points" in capsys.readouterr().out
    row = vf.headline_rows_v3(done, "src")[0]
    assert row[0] == ("the verdict (v3, confirmatory): ACT with ForceAugment `fa2` (2 copies, the paper's offsets) vs "
                      "ACT on the real demos, nominal (4–7 N), fresh seeds, 12 paired (look 1)")
    assert row[1] == "+20.0 points: **helps**" and "against 0.001 (efficacy)" in row[2]
    done["looks"][0]["stop"] = "continue"  # a look that did not stop: the row says the grid went on
    assert vf.headline_rows_v3(done, "src")[0][1] == "running: look 1 continued to look 2 (no stop at its boundary)"


def test_a_grid_that_goes_on_gives_look_2s_verdict_over_all_24_seeds(tmp_path, capsys):
    """Ten seeds in twelve gain 20 points and two lose 10: look 1's p is above its 0.001, the mean positive, so
    the design continues; at look 2 the same pattern over 24 seeds rejects below 0.049, and the row says so."""
    def fa2(seed):
        return 0.5 if seed % 12 in (3, 7) else 0.8

    look1 = _v3_doc(tested_seeds=12, fa2=fa2)
    assert look1["looks"][0]["stop"] == "continue"
    running = _v3_doc(tested_seeds=20, trained=24, fa2=fa2)
    assert vf.headline_rows_v3(running, "src")[0][1] == "running: look 1 continued to look 2 (no stop at its boundary)"
    done = _v3_doc(tested_seeds=24, trained=24, fa2=fa2)
    path = tmp_path / "v3.json"
    path.write_text(json.dumps(done))
    assert vf.main([str(path), "--look", "2"]) == 0
    out = capsys.readouterr().out
    assert "look 2 (24 paired seeds)" in out and "+15.0 points" in out and "against alpha 0.049" in out
    row = vf.headline_rows_v3(done, "src")[0]
    assert row[0].endswith("24 paired (look 2)") and row[1] == "+15.0 points: **helps**"
    p = vr.sign_flip_p([fa2(s) - 0.6 for s in range(12, 36)])  # 20 seeds +0.2, 4 seeds -0.1: 852 / 2^24
    assert p == 852 / 2 ** 24 and f"| 2 | 24 | p < 0.049 | – | efficacy: p {p:.3g}, +15.0 points" in vf.looks_table(done)
    assert vf.main([str(path), "--pictures"]) == 0 and (tmp_path / "v3_paired.png").is_file()


def test_pictures_are_drawn_from_the_json_once_a_look_is_complete_and_not_before(tmp_path, capsys):
    path = tmp_path / "v3.json"
    path.write_text(json.dumps(_v3_doc(tested_seeds=11)))
    assert vf.main([str(path), "--pictures"]) == 0 and not list(tmp_path.glob("*.png"))
    path.write_text(json.dumps(_v3_doc(tested_seeds=12)))
    assert vf.main([str(path), "--pictures"]) == 0
    drawn = {p.name: cv2.imread(str(p)) for p in tmp_path.glob("*.png")}
    assert set(drawn) == {"v3.png", "v3_paired.png"} and all(img is not None and img.size for img in drawn.values())
    assert f"wrote {tmp_path / 'v3_paired.png'}" in capsys.readouterr().out


def test_a_sequential_designs_power_sentence_is_written_from_its_numbers_not_the_stored_text():
    rows = [{"effect": e, "sd": 0.2, "power": p, "look_1_efficacy": 0.05} for e, p in ((0.10, 0.63), (0.13, 0.84))]
    power = {"v2_paired_sd": 0.2, "rows": rows, "no_effect": {"power": 0.027}, "mde_80": 0.13,
             "statement": "80 % power at 13%"}
    doc = _doc(tests=True)
    doc["protocol"]["power"] = power
    text = vf.block(doc, "")
    assert "80 % power at a 13-point effect" in text and "at 13%" not in text
    assert "10-point effect with 63% probability and a 13-point one with 84% (5% at look 1)" in text


def test_the_cache_table_names_each_caches_seeds_only_where_a_grid_used_two():
    """A machine that rebuilt the ForceAugment cache: each seed's tested policy (a test unit at fa2's step) and its
    training run are listed under the cache they trained on; a grid on one cache has no table."""
    doc = _v3_doc(trained=6, tested_seeds=6)
    assert vf.cache_table(doc) == ""
    doc["force_augment_counts"] = {"fa2": {}}
    doc["steps"]["fa2"] = {"step": 6000}
    doc["augment_digests"] = ["old", "new"]
    for u in doc["units"]:
        u["augment_digest"] = "old" if u["seed"] < 15 else "new"
    doc["units"] += [{"kind": "test", "variant": "fa2", "seed": s, "augment_digest": "old" if s < 13 else "new"}
                     for s in (12, 13, 14)]  # seeds 13 and 14 retrained to step 6000 on the new machine
    assert vf.seed_ranges([20, 12, 13, 14, 17, 18]) == "12–14, 17–18, 20" and vf.seed_ranges([]) == "–"
    table = vf.cache_table(doc).splitlines()
    assert table[2:] == ["| `old` | fa2 (step 6000) | 12 | 12–14 |", "| `new` | fa2 (step 6000) | 13–14 | 15–17 |"]
