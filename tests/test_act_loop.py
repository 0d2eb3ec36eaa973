"""ACTPolicy inside the real control loop (in-memory devices from hardware.fakes, virtual clock)."""

import numpy as np
import pytest
import torch

from act_fixtures import tiny_config
from hardware.control_loop import ControlLoop, ControlLoopConfig, PolicyError
from hardware.fakes import FAKE_WORKSPACE, FakeArm, FakeGripper, SyntheticFrameSource
from hardware.interfaces import VirtualClock
from hardware.safety import SafetyLimits
from hardware.temporal_ensembling import TemporalEnsembler
from policies.act import ACT, ACTPolicy


def _rig(cameras=("third_view", "wrist"), background=True):
    clock, log = VirtualClock(), []
    arm = FakeArm(clock=clock, log=log)
    gripper = FakeGripper(clock=clock, log=log)
    cams = {c: SyntheticFrameSource(c, (48, 64), clock) for c in cameras}
    tac = {s: SyntheticFrameSource(s, (24, 32), clock, background=background) for s in ("left", "right")}
    return clock, log, arm, gripper, cams, tac


def _policy(**kw):
    torch.manual_seed(0)
    model = ACT(tiny_config(**kw))
    # actions near the fake arm's pose so the safety filter has nothing to clamp
    model.set_stats({"qpos": {"mean": [0.0] * 5, "std": [1.0] * 5},
                     "action": {"mean": [0.4, 0.0, 0.2, 0.0, 0.5], "std": [0.001] * 5}})
    return ACTPolicy(model)


def test_act_drives_the_loop_with_ensembled_chunks():
    """Each command is the temporal ensemble (ACT's k = 0.01) of the chunks ACT predicted so far, replayed by hand:
    not the newest chunk's row, which differs from it by more than the tolerance."""
    clock, log, arm, gripper, cams, tac = _rig()
    policy, chunks = _policy(), []

    def recorded(obs):
        chunks.append(np.array(policy(obs), dtype=np.float64))
        return chunks[-1]

    size = policy.config.chunk_size
    loop = ControlLoop(arm, recorded, gripper=gripper, cameras=cams, tactile=tac, limits=SafetyLimits(**FAKE_WORKSPACE), clock=clock,
                       config=ControlLoopConfig(inference="sync", chunk_size=size))
    stats = loop.run(max_steps=5)
    servos = np.array([v for e, v in log if e == "servo"])
    assert stats.steps == 5 and len(servos) == 5 and len(chunks) == 5
    ens = TemporalEnsembler(size, 5, 0.01)
    for t, chunk in enumerate(chunks):
        ens.add_chunk(t, chunk)
    expected = np.array([ens.action(t)[:4] for t in range(5)])
    np.testing.assert_allclose(servos, expected, atol=1e-7)
    newest_rows = np.array([chunk[0, :4] for chunk in chunks])
    assert np.abs(newest_rows - expected).max() > 1e-5  # the replay tells ensembling from taking the newest row
    assert log[-2:] == [("arm-stop", None), ("gripper-stop", None)]


def test_missing_camera_stops_the_arm_before_any_motion():
    clock, log, arm, gripper, cams, tac = _rig(cameras=("third_view",))
    loop = ControlLoop(arm, _policy(), gripper=gripper, cameras=cams, tactile=tac, clock=clock, limits=SafetyLimits(**FAKE_WORKSPACE),
                       config=ControlLoopConfig(inference="sync", chunk_size=6))
    with pytest.raises(PolicyError, match="images/wrist"):
        loop.run(max_steps=5)
    assert [e for e, _ in log] == ["arm-stop", "gripper-stop"]  # stopped, never commanded


def test_sensor_without_background_uses_the_checkpoint_one_or_fails_clearly():
    clock, log, arm, gripper, cams, tac = _rig(background=False)
    loop = ControlLoop(arm, _policy(), gripper=gripper, cameras=cams, tactile=tac, clock=clock, limits=SafetyLimits(**FAKE_WORKSPACE),
                       config=ControlLoopConfig(inference="sync", chunk_size=6))
    with pytest.raises(PolicyError, match="tactile_background/left"):
        loop.run(max_steps=2)
    assert log[0] == ("arm-stop", None)
    policy = _policy()
    policy.backgrounds = {s: np.full((24, 32, 3), 100, np.uint8) for s in ("left", "right")}
    clock, log, arm, gripper, cams, tac = _rig(background=False)
    loop = ControlLoop(arm, policy, gripper=gripper, cameras=cams, tactile=tac, clock=clock, limits=SafetyLimits(**FAKE_WORKSPACE),
                       config=ControlLoopConfig(inference="sync", chunk_size=6))
    assert loop.run(max_steps=2).steps == 2


def test_an_observation_with_a_non_finite_qpos_or_a_float_background_is_refused_naming_the_key():
    """NaN in qpos would make every action NaN; a float background in [0, 1] finite but wrong actions."""
    from controltac_il.streams import LOOP, LOOP_STATE, background_key, image_key, tactile_key

    policy = _policy()
    frame = np.full((24, 32, 3), 120, np.uint8)
    good = {LOOP_STATE: np.zeros(5, np.float32), **{image_key(c, LOOP): frame for c in ("third_view", "wrist")},
            **{tactile_key(s, LOOP): frame for s in ("left", "right")},
            **{background_key(s, LOOP): frame for s in ("left", "right")}}
    assert np.isfinite(policy(good)).all()
    bad_qpos = (np.array([0, np.nan, 0, 0, 0.0]), ["a"] * 5, np.zeros(4))
    for qpos in bad_qpos:
        with pytest.raises(ValueError, match=rf"^observation\['{LOOP_STATE}'\] must be 5 finite numbers"):
            policy({**good, LOOP_STATE: qpos})
    key = background_key("left", LOOP)
    with pytest.raises(ValueError, match=rf"^observation\['{key}'\] must be uint8 \(H, W, 3\), got float32"):
        policy({**good, key: frame.astype(np.float32) / 255})
