"""Test-suite defaults: headless rendering and one torch thread (the machine is small and shared)."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import torch  # noqa: E402

torch.set_num_threads(1)
