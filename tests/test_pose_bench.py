"""benchmarks.pose: its estimation helpers on known cases and the --quick run CI relies on."""

import json

import numpy as np
import pytest

from benchmarks.pose import cross_pose_pairs, main, perturbed
from benchmarks.pose_estimation import decode_poses, encode_poses, fit_pca, pose_errors, predict_pca
from controltac_il.generator.training.pose_data import render_scenes
from controltac_il.tactile import contact_mask


def test_pose_codes_round_trip_and_errors_wrap_at_pi():
    poses = np.array([[1.0, -2.0, 0.1], [0.0, 3.0, 3.1]])
    assert np.allclose(decode_poses(encode_poses(poses, (4.0, 5.0)), (4.0, 5.0)), poses)
    e = pose_errors(np.array([[0.0, 0.0, np.pi - 0.01]]), np.array([[3.0, 4.0, 0.01]]))
    assert e["xy_mm"] == pytest.approx(5.0) and e["theta_deg"] == pytest.approx(np.degrees(0.02))


def test_pca_baseline_recovers_poses_of_an_elongated_contact():
    scenes = render_scenes(["slim_cylinder"], 1, 8, 1, seed=4, family=None, progress=False)
    masks = np.stack([contact_mask(r) for r in scenes.residuals])
    objects = ["slim_cylinder"] * len(masks)
    pred = predict_pca(masks, objects, fit_pca(masks, scenes.poses, objects), scenes.mm_per_px)
    assert pose_errors(pred, scenes.poses)["theta_deg"] < 3.0
    inside = ~(masks[:, [0, -1]].any((1, 2)) | masks[:, :, [0, -1]].any((1, 2)))  # a cut contact moves its centroid
    assert inside.sum() >= 2 and pose_errors(pred[inside], scenes.poses[inside])["xy_mm"] < 0.3


def test_cross_pose_pairs_move_the_contact_and_perturbed_masks_stay_binary():
    scenes = render_scenes(["t_shape"], 2, 3, 2, seed=1, family=None, progress=False)
    pairs = cross_pose_pairs(scenes, 10, seed=0)
    assert len(pairs) == 10
    assert all(scenes.scene[i] == scenes.scene[j] and not np.array_equal(scenes.poses[i], scenes.poses[j]) for i, j in pairs)
    m = perturbed(scenes.masks[:4], 1.2, 6, 6, seed=0)
    assert m.dtype == bool and (m.sum((1, 2)) > scenes.masks[:4].sum((1, 2))).all()


@pytest.mark.slow  # the whole --quick benchmark (9 s idle): its pairs and masks are tested above; with -m slow
def test_quick_run_writes_the_tables_json_and_sheet(tmp_path, capsys):
    out = tmp_path / "pose.json"
    doc = main(["--quick", "--out", str(out)])
    assert json.loads(out.read_text()) == json.loads(json.dumps(doc))
    pc = doc["pose_control"]
    assert {"unseen_mse", "stage1_only_unseen_mse", "copy_unseen_mse"} <= set(pc)
    assert pc["unseen_mse"] < pc["stage1_only_unseen_mse"]  # the adapter moves the contact; stage 1 cannot
    assert set(doc["robustness"]) == {"none", "combined 1.2, 6 px, 6°"}
    assert set(doc["pose_estimation"]) >= {"real", "generated", "real + generated", "pca baseline"}
    assert doc["speed"]["pose_img_per_s"] > 0 and out.with_suffix(".png").is_file()
    moved = doc["moved_contacts_240"]["sim240/usb_c"]["moves"]["right 40 px"]
    assert 0 <= moved["iou"] <= 1 and 0 <= moved["energy_left_behind"] < moved["energy_in_target"] <= 1
    assert "pose-conditioned generation" in capsys.readouterr().out
