"""Deployment in the MuJoCo scene through the control loop, and the end-to-end pipeline."""

import json

import pytest
import torch

from controltac_il.app import PipelineConfig, evaluate_in_sim, run_pipeline
from controltac_il.metrics import wilson_interval
from policies.act import ACT, ACTConfig, ACTPolicy

SCENE_SMALL = dict(camera_size=(32, 40), tactile_size=(24, 32), max_steps=4)


def _policy(cameras=("third_view", "wrist"), tactile=("left", "right")):
    torch.manual_seed(0)
    cfg = ACTConfig.from_preset("cpu", camera_names=cameras, tactile_names=tactile, dim_model=32, n_heads=2, dim_feedforward=64,
                                n_encoder_layers=1, n_vae_encoder_layers=1, camera_size=(24, 32),
                                tactile_size=(24, 32))
    model = ACT(cfg)
    # start from the scene's home pose, gripper open: the untrained policy barely moves
    model.set_stats({"qpos": {"mean": [0.0] * 5, "std": [1.0] * 5},
                     "action": {"mean": [0.0, 0.0, 0.15, 0.0, 0.0], "std": [1e-3] * 5}})
    return ACTPolicy(model)


def test_seeded_sim_episodes_run_through_the_control_loop():
    result = evaluate_in_sim(_policy(), episodes=2, seed=7, env_overrides=SCENE_SMALL, progress=False)
    assert [o["seed"] for o in result["outcomes"]] == [7, 8]
    assert all(o["steps"] == 4 and o["error"] is None and not o["success"] for o in result["outcomes"])
    assert result["successes"] == 0 and result["wilson95"] == pytest.approx(list(wilson_interval(0, 2)))
    assert result["grip_force_range_n"] == [3.0, 9.0] and result["inference_ms_p50"] > 0
    shifted = evaluate_in_sim(_policy(), episodes=1, seed=7, grip_force_range=(10.0, 12.0),
                              env_overrides=SCENE_SMALL, progress=False)
    assert shifted["grip_force_range_n"] == [10.0, 12.0]


def test_sim_episodes_are_deterministic_and_step_once_per_cycle():
    a = evaluate_in_sim(_policy(), episodes=1, seed=3, env_overrides=SCENE_SMALL, progress=False)
    b = evaluate_in_sim(_policy(), episodes=1, seed=3, env_overrides=SCENE_SMALL, progress=False)
    assert a["outcomes"] == b["outcomes"] and a["outcomes"][0]["steps"] == 4


def test_the_scene_renders_only_the_streams_the_policy_reads(monkeypatch):
    """A wrist-camera policy: the third view is not rendered for it, and for one without touch no tactile optics
    run either."""
    import envs.peg_in_hole as scene

    built, init = [], scene.PegInHoleEnv.__init__

    def recording(self, config=None, *a, **k):
        built.append(config)
        init(self, config, *a, **k)

    monkeypatch.setattr(scene.PegInHoleEnv, "__init__", recording)
    for tactile in (("left", "right"), ()):
        out = evaluate_in_sim(_policy(("wrist",), tactile), episodes=1, seed=3, env_overrides=SCENE_SMALL,
                              progress=False)
        assert out["outcomes"][0]["steps"] == 4 and out["outcomes"][0]["error"] is None
    assert [(c.cameras, c.tactile) for c in built] == [(("wrist",), True), (("wrist",), False)]


def test_a_policy_for_other_cameras_is_refused_before_the_scene_starts():
    with pytest.raises(ValueError, match="camera 'top'"):
        evaluate_in_sim(_policy(cameras=("top", "wrist")), episodes=1, env_overrides=SCENE_SMALL, progress=False)


def test_pipeline_config_validation():
    with pytest.raises(ValueError, match="copies"):
        PipelineConfig(copies=10)
    with pytest.raises(ValueError, match="demos"):
        PipelineConfig(demos=0)


@pytest.mark.slow
def test_tiny_pipeline_end_to_end(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("CONTROLTAC_CACHE", str(tmp_path / "cache"))
    report = run_pipeline(tmp_path / "out", PipelineConfig(demos=2, copies=0, steps=4, batch_size=4,
                                                           eval_episodes=1), progress=False)
    assert report["training"]["steps"] == 4 and report["evaluation"]["episodes"] == 1
    log = capsys.readouterr().out
    assert f"collected 2 scripted demos in {report['demos']} (" in log and ".tmp" not in log  # the final folder
    assert set(report["seconds"]) == {"collect", "train", "deploy", "total"}
    assert json.loads((tmp_path / "out" / "pipeline.json").read_text())["evaluation"]["episodes"] == 1


def test_the_augment_line_reads_as_a_sentence():
    from controltac_il.app.job import augment_sentence

    counts = {"tactile_frames": 2484, "no_contact": 1200, "regenerated": 1240, "clamped": 40, "skipped": 4,
              "fraction_regenerated": 0.52}
    assert augment_sentence(1, counts) == ("1 ForceAugment copy: 2484 tactile frames, 1280 generated (40 of them at "
                                           "a target clamped to the validated range), 1200 without contact kept as "
                                           "recorded, 4 skipped")
