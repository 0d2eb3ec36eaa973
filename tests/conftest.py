"""Test-suite defaults: headless rendering and two torch threads (the 2-core CI machine; 1 thread made the suite ~12 s slower)."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import torch  # noqa: E402

torch.set_num_threads(2)
