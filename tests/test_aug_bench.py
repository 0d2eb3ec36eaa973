"""The ForceAugment benchmark's --quick run: its counts add up and it names the generator it measured."""

import json

import pytest

from benchmarks import augment as bench
from controltac_il.generator import ForceGenerator


def test_quick_run_counts_add_up_and_name_the_shipped_generator(tmp_path):
    out = tmp_path / "augment.json"
    bench.main(["--quick", "--out", str(out), "--rows", "hdf5", "lerobot"])  # the writer row: test_lerobot_v3_write
    res = json.loads(out.read_text())
    counts = res["counts_clamp_mode"]
    assert counts["tactile_frames"] == (counts["regenerated"] + counts["clamped"] + counts["skipped"]
                                        + counts["no_contact"])
    assert res["cache_build"]["frames_generated"] == counts["regenerated"] + counts["clamped"]
    # skip mode draws the same offsets and jitter, so it keeps real exactly the frames clamp mode clamped,
    # and in both modes the frames whose reference force lies outside the validated range (#20)
    assert res["skipped_in_skip_mode"] == counts["clamped"] + counts["skipped"] and counts["clamped"] > 0
    assert res["generator_hash"] == ForceGenerator.from_pretrained().checkpoint_hash
    assert set(res["items_per_s"]) == {"bare", "cached", "online"}
    assert all(v > 0 for v in res["items_per_s"].values())
    # the LeRobot-convention row (#22): same episodes as float CHW cameras, estimated backgrounds, labels by
    # force_keys: the same frames are in contact and get the same draws as on our HDF5 layout
    lerobot = res["lerobot"]
    assert set(lerobot["items_per_s"]) == {"bare", "cached", "online"} and all(v > 0 for v in lerobot["items_per_s"].values())
    assert lerobot["counts"] == counts and lerobot["cache_build"]["frames_generated"] == res["cache_build"]["frames_generated"]


@pytest.mark.slow  # 10 s: the LeRobot writer itself is tested in test_lerobot_v3_write
def test_quick_lerobot_write_row_times_the_generator_inside_the_write(tmp_path):
    res = bench.main(["--quick", "--rows", "lerobot_write", "--out", str(tmp_path / "w.json")])["lerobot_write"]
    assert 0 < res["generator_seconds"] < res["write_seconds"]
    assert res["writer_vs_generator"] == pytest.approx(res["generator_seconds"] / res["write_seconds"])
    assert res["episodes_written"] == 9 and res["regenerated_frames"] > 0 and res["video_round_trip_mse"] > 0
