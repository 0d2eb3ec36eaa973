"""Test-suite defaults: headless rendering and two torch threads (the 2-core CI machine; 1 thread made the suite ~12 s slower)."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(2)


@pytest.fixture
def clock():
    """A virtual clock (``hardware.interfaces.VirtualClock``) attached to this test's thread: time moves only when
    every attached thread (this one, a streaming or control thread it starts) sleeps on it."""
    from hardware.interfaces import VirtualClock

    c = VirtualClock()
    c.attach()
    yield c
    c.detach()


@pytest.fixture(scope="session")
def written(tmp_path_factory):
    """A LeRobot source folder and one clean augmented write of it (``test_lerobot_v3_write.write_clean``), shared by
    the LeRobot writer's test modules."""
    from test_lerobot_v3_write import write_clean

    return write_clean(tmp_path_factory.mktemp("lerobot_write"))
