"""``ACTPolicy``: a trained ACT behind the control loop's protocol ``predict_chunk(observation)``.

Observations are the scene's / robot's flat dict of numpy arrays:
    ``qpos`` (D,), ``images/<cam>`` uint8 (H, W, 3), ``tactile/<sensor>`` uint8 (H, W, 3) and,
    optionally, ``tactile_background/<sensor>`` uint8 (H, W, 3). Without it the background stored in
    the checkpoint (the training data's no-contact frame) is used.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from controltac_il.streams import LOOP, LOOP_STATE, background_key, image_key, loop_to_hdf5, tactile_key
from policies.act.checkpoint import load_checkpoint
from policies.act.configuration_act import ACTConfig
from policies.act.modeling_act import ACT


class ACTPolicy:
    """Inference wrapper: numpy observation in, (N_a, A) float32 action chunk out."""

    def __init__(self, model: ACT, backgrounds: dict[str, np.ndarray] | None = None) -> None:
        self.model = model.eval()
        self.backgrounds = dict(backgrounds or {})

    @classmethod
    def from_pretrained(cls, path: str | Path, device: str = "cpu") -> "ACTPolicy":
        """Load a checkpoint folder (raises ``CheckpointError`` on any problem)."""
        model, backgrounds, _ = load_checkpoint(path, device)
        return cls(model, backgrounds)

    @property
    def config(self) -> ACTConfig:
        return self.model.config

    def _image_keys(self) -> list[str]:
        """The observation keys of the policy's cameras and tactile images, in the batch's order."""
        cfg = self.config
        return [image_key(c, LOOP) for c in cfg.camera_names] + [tactile_key(s, LOOP) for s in cfg.tactile_names]

    def check_observation(self, observation: dict) -> None:
        """Raise ValueError if ``observation`` lacks a stream the policy needs or has the wrong sizes."""
        cfg = self.config
        missing = [k for k in [LOOP_STATE, *self._image_keys()] if k not in observation]
        missing += [background_key(s, LOOP) for s in cfg.tactile_names
                    if background_key(s, LOOP) not in observation and s not in self.backgrounds]
        if missing:
            raise ValueError(f"observation is missing {missing}; the checkpoint expects cameras "
                             f"{list(cfg.camera_names)} and tactile sensors {list(cfg.tactile_names)}")
        qpos = np.asarray(observation[LOOP_STATE])
        if qpos.shape != (cfg.state_dim,) or not np.issubdtype(qpos.dtype, np.number) or not np.isfinite(qpos).all():
            raise ValueError(f"observation[{LOOP_STATE!r}] must be {cfg.state_dim} finite numbers, got "
                             f"{qpos.dtype} {qpos.shape}: {qpos.tolist()}")
        images = {key: np.asarray(observation[key]) for key in self._image_keys()}
        images.update({background_key(s, LOOP): self._background(observation, s) for s in cfg.tactile_names})
        for key, img in images.items():  # a float background in [0, 1] would give finite but wrong actions
            if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
                raise ValueError(f"observation[{key!r}] must be uint8 (H, W, 3), got {img.dtype} {img.shape}")

    def _background(self, observation: dict, sensor: str) -> np.ndarray:
        return np.asarray(observation.get(background_key(sensor, LOOP), self.backgrounds.get(sensor)))

    def to_batch(self, observation: dict) -> dict[str, torch.Tensor]:
        """One observation as a batch of one in the model's key layout."""
        self.check_observation(observation)
        cfg = self.config

        def chw(a) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(np.asarray(a).transpose(2, 0, 1)))[None]

        qpos = torch.as_tensor(np.asarray(observation[LOOP_STATE], np.float32))[None]
        batch = {loop_to_hdf5(LOOP_STATE): qpos}
        for c in cfg.camera_names:
            batch[loop_to_hdf5(image_key(c, LOOP))] = chw(observation[image_key(c, LOOP)])
        for s in cfg.tactile_names:
            batch[loop_to_hdf5(tactile_key(s, LOOP))] = chw(observation[tactile_key(s, LOOP)])
            batch[loop_to_hdf5(background_key(s, LOOP))] = chw(self._background(observation, s))
        return batch

    def predict_chunk(self, observation: dict) -> np.ndarray:
        """(N_a, A) float32 actions (absolute targets in the training data's units)."""
        return self.model.predict(self.to_batch(observation))[0].cpu().numpy().astype(np.float32)

    def __call__(self, observation: dict) -> np.ndarray:
        """The control loop's policy protocol (any callable observation -> chunk): :meth:`predict_chunk`."""
        return self.predict_chunk(observation)
