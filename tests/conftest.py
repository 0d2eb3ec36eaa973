"""Test-suite defaults: headless rendering and the 2-core CI machine's two torch threads, shared by the xdist workers."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import pytest  # noqa: E402
import torch  # noqa: E402

THREADS = max(1, 2 // int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", 1)))  # 2 cores over the xdist workers
torch.set_num_threads(THREADS)


@pytest.fixture(autouse=True)
def _torch_threads():
    """Each test starts at THREADS: one that sets torch's thread count (a CLI's ``--threads``) does not leak it into
    the next, whose bytes may depend on it (a ForceAugment record holds ``intra_op_threads``)."""
    yield
    if torch.get_num_threads() != THREADS:
        torch.set_num_threads(THREADS)


@pytest.fixture(autouse=True, scope="session")
def _cache_in_tmp(tmp_path_factory):
    """The tool's cache (normalisation stats, demos, ForceAugment caches) in this session's temporary folder, for
    the tests and the commands they start: a test never writes the user's ~/.cache."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("CONTROLTAC_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


@pytest.fixture
def clock():
    """A virtual clock (``hardware.interfaces.VirtualClock``) attached to this test's thread: time moves only when
    every attached thread (this one, a streaming or control thread it starts) sleeps on it."""
    from hardware.interfaces import VirtualClock

    c = VirtualClock()
    c.attach()
    yield c
    c.detach()


@pytest.fixture
def dynamixel_latency(monkeypatch):
    """dynamixel_sdk times a reply out after two USB latency timers (16 ms each, its FTDI default); an emulated servo
    (``hardware.fake_serial.FakeDynamixelServo``) is a thread of the test process, which a loaded machine may not
    schedule within 34 ms: the SDK gets a 100 ms latency timer (a reply within ~200 ms). A module global, read at
    each packet."""
    import dynamixel_sdk.port_handler

    monkeypatch.setattr(dynamixel_sdk.port_handler, "LATENCY_TIMER", 100)


@pytest.fixture(scope="session")
def written(tmp_path_factory):
    """A LeRobot source folder and one clean augmented write of it (``lerobot_fixtures.write_clean``), shared by
    the LeRobot writer's test modules."""
    from lerobot_fixtures import write_clean

    return write_clean(tmp_path_factory.mktemp("lerobot_write"))
