"""The ForceAugment benchmark's --quick run: its counts add up and it names the generator it measured."""

import json

import pytest

from benchmarks import augment as bench
from controltac_il.generator import ForceGenerator


@pytest.mark.slow  # 75 s: the benchmark's parts (ForceAugment, the writer) are tested in their own files
def test_quick_run_counts_add_up_and_name_the_shipped_generator(tmp_path):
    out = tmp_path / "augment.json"
    bench.main(["--quick", "--out", str(out), "--rows", "hdf5", "lerobot"])  # the writer row: test_lerobot_v3_write
    res = json.loads(out.read_text())
    counts = res["counts_clamp_mode"]
    assert counts["tactile_frames"] == (counts["regenerated"] + counts["clamped"] + counts["skipped"]
                                        + counts["no_contact"])
    assert res["cache_build"]["frames_generated"] == counts["regenerated"] + counts["clamped"]
    # skip mode draws the same offsets and jitter, so it keeps real exactly the frames clamp mode clamped,
    # and in both modes the frames whose reference force lies outside the validated range
    assert res["skipped_in_skip_mode"] == counts["clamped"] + counts["skipped"] and counts["clamped"] > 0
    assert res["generator_hash"] == ForceGenerator.from_pretrained().checkpoint_hash
    assert set(res["items_per_s"]) == {"bare", "cached", "online"}
    assert all(v > 0 for v in res["items_per_s"].values())
    # the LeRobot-convention row: same episodes as float CHW cameras, estimated backgrounds, labels by
    # force_keys: the same frames are in contact and get the same draws as on our HDF5 layout
    lerobot = res["lerobot"]
    assert set(lerobot["items_per_s"]) == {"bare", "cached", "online"} and all(v > 0 for v in lerobot["items_per_s"].values())
    assert lerobot["counts"] == counts and lerobot["cache_build"]["frames_generated"] == res["cache_build"]["frames_generated"]


@pytest.mark.slow  # 25 s: the LeRobot writer itself is tested in test_lerobot_v3_write
def test_quick_lerobot_write_row_times_the_write_against_the_generator_alone(tmp_path):
    res = bench.main(["--quick", "--rows", "lerobot_write", "--out", str(tmp_path / "w.json")])["lerobot_write"]
    checked, after = res["with_round_trip"], res["export_after_build"]
    assert res["rounds"] == 1 and len(res["per_round"]) == 1
    assert res["cli_wait_policy"] == "openmp_default" and set(res["wait_policies"]) == {"openmp_default", "passive"}
    assert res["write_seconds"] == res["wait_policies"]["openmp_default"]["write_seconds"]
    assert set(res["per_round"][0]) == {"generator_seconds", "write_seconds_openmp_default", "write_seconds_passive",
                                        "export_after_build_seconds"}
    assert res["generator_seconds"] > 0 and res["generator_cpu_seconds"] > 0  # the same frames, nothing beside it
    assert 0 < res["generator_seconds_in_write"] < res["write_seconds"]
    assert 0 < checked["generator_cpu_seconds_in_write"] < checked["write_cpu_seconds"]
    for times in (res, checked, after):  # wall and CPU seconds against the generator alone's
        assert times["writer_vs_generator"] == pytest.approx(res["generator_seconds"] / times["write_seconds"])
        assert times["writer_vs_generator_cpu"] == pytest.approx(res["generator_cpu_seconds"]
                                                                 / times["write_cpu_seconds"])
        assert times["writer_own_cpu_seconds"] == pytest.approx(times["write_cpu_seconds"]
                                                                - res["generator_cpu_seconds"])
    assert res["per_round"][0]["export_after_build_seconds"] == after["write_seconds"]
    assert res["round_trip_cpu_seconds"] == pytest.approx(checked["write_cpu_seconds"] - res["write_cpu_seconds"])
    assert res["episodes_written"] == 9 and res["regenerated_frames"] > 0 and res["video_round_trip_mse"] > 0
