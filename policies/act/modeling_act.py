"""ACT: a CVAE whose decoder is a transformer predicting a chunk of N_a actions.

Training (``forward``): the CVAE encoder reads [CLS, qpos, action chunk] and gives q(z | a, s);
z is sampled, then the main transformer encoder reads [z, qpos, image tokens of every stream] and
a one-layer decoder turns N_a learned queries into the action chunk.
Loss = L1(actions, masked where the episode has ended) + kl_weight * KL(q || N(0, I)).
Inference (``predict``): z = 0 (the prior mean).

Positions are added once at the transformer inputs: 2-D sine codes plus a learned per-stream
embedding for image tokens, learned embeddings for the z and qpos tokens, 1-D sine codes in the
CVAE encoder. Inputs and targets are normalised with per-dimension mean/std kept as buffers.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from controltac_il.streams import HDF5, HDF5_STATE, background_key, image_key, tactile_key
from policies.act.backbone import build_backbone, sine_positions_1d, sine_positions_2d
from policies.act.configuration_act import ACTConfig

# the smallest normalisation std accepted: at 1e-12 a tiny model's actions stay finite, at 1e-20 its LayerNorm
# overflows and every action is NaN (qpos ~ 1 rad); the stats writers floor theirs at 1e-2
MIN_STD = 1e-6


def _encoder(cfg: ACTConfig, layers: int) -> nn.TransformerEncoder:
    layer = nn.TransformerEncoderLayer(cfg.dim_model, cfg.n_heads, cfg.dim_feedforward, cfg.dropout,
                                       activation="relu", batch_first=True)
    return nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)


class ACT(nn.Module):
    """The ACT network. Batches are dicts with LeRobot-style keys (see ``ACTConfig.input_keys``):

    ``observation.qpos`` float (B, D); ``observation.images.<cam>`` uint8 (B, 3, H, W);
    ``observation.tactile.<s>`` and ``observation.tactile_background.<s>`` uint8 (B, 3, H, W);
    for training also ``action`` float (B, N_a, A) and ``action_is_pad`` bool (B, N_a).
    Frames of any size are resized to ``camera_size`` / ``tactile_size``.
    """

    def __init__(self, config: ACTConfig) -> None:
        super().__init__()
        self.config = cfg = config
        d = cfg.dim_model
        # image streams
        self.camera_backbone = build_backbone(cfg.backbone) if cfg.camera_names else None
        self.tactile_backbone = build_backbone(cfg.backbone) if cfg.tactile_names else None
        feat = (self.camera_backbone or self.tactile_backbone).out_channels
        self.camera_proj = nn.Conv2d(feat, d, 1) if cfg.camera_names else None
        self.tactile_proj = nn.Conv2d(feat, d, 1) if cfg.tactile_names else None
        self.stream_embed = nn.Parameter(torch.zeros(len(cfg.camera_names) + len(cfg.tactile_names), d))
        # CVAE encoder over [CLS, qpos, actions]
        self.vae_cls = nn.Parameter(torch.zeros(1, d))
        self.vae_qpos_proj = nn.Linear(cfg.state_dim, d)
        self.vae_action_proj = nn.Linear(cfg.action_dim, d)
        self.vae_encoder = _encoder(cfg, cfg.n_vae_encoder_layers)
        self.vae_to_latent = nn.Linear(d, 2 * cfg.latent_dim)
        # main transformer
        self.latent_proj = nn.Linear(cfg.latent_dim, d)
        self.qpos_proj = nn.Linear(cfg.state_dim, d)
        self.token_pos = nn.Parameter(torch.zeros(2, d))  # z token, qpos token
        self.encoder = _encoder(cfg, cfg.n_encoder_layers)
        dec_layer = nn.TransformerDecoderLayer(d, cfg.n_heads, cfg.dim_feedforward, cfg.dropout,
                                               activation="relu", batch_first=True)
        self.decoder = nn.TransformerDecoder(dec_layer, cfg.n_decoder_layers)
        self.queries = nn.Parameter(torch.zeros(cfg.chunk_size, d))
        self.action_head = nn.Linear(d, cfg.action_dim)
        for p in (self.stream_embed, self.vae_cls, self.token_pos, self.queries):
            nn.init.normal_(p, std=0.02)
        # normalisation (set from dataset statistics; identity until then)
        self.register_buffer("qpos_mean", torch.zeros(cfg.state_dim), persistent=False)
        self.register_buffer("qpos_std", torch.ones(cfg.state_dim), persistent=False)
        self.register_buffer("action_mean", torch.zeros(cfg.action_dim), persistent=False)
        self.register_buffer("action_std", torch.ones(cfg.action_dim), persistent=False)

    # ------------------------------------------------------------------ normalisation
    def set_stats(self, stats: dict) -> None:
        """Load ``{"qpos": {"mean": [D], "std": [D]}, "action": {"mean": [A], "std": [A]}}``; ValueError for a
        missing or misshaped entry, a non-finite value or a std below MIN_STD."""
        for key, dim in (("qpos", self.config.state_dim), ("action", self.config.action_dim)):
            try:
                mean = torch.as_tensor(stats[key]["mean"], dtype=torch.float32).reshape(-1)
                std = torch.as_tensor(stats[key]["std"], dtype=torch.float32).reshape(-1)
            except (KeyError, TypeError) as e:
                raise ValueError(f"normalisation stats need {key!r} with 'mean' and 'std' lists: {e}") from None
            if mean.numel() != dim or std.numel() != dim:
                raise ValueError(f"normalisation stats {key!r}: expected {dim} values, got mean {mean.numel()}, "
                                 f"std {std.numel()}")
            if not torch.isfinite(mean).all() or not ((std >= MIN_STD) & torch.isfinite(std)).all():
                raise ValueError(f"normalisation stats {key!r}: mean must be finite and std finite and >= {MIN_STD:g} "
                                 "(a smaller one overflows the normalised input)")
            getattr(self, f"{key}_mean").copy_(mean)
            getattr(self, f"{key}_std").copy_(std)

    def get_stats(self) -> dict:
        return {k: {"mean": getattr(self, f"{k}_mean").tolist(), "std": getattr(self, f"{k}_std").tolist()}
                for k in ("qpos", "action")}

    # ------------------------------------------------------------------ inputs
    def check_batch(self, batch: dict, training: bool) -> int:
        """Raise ValueError naming the first missing or misshaped key; return the batch size."""
        cfg = self.config
        keys = cfg.input_keys + (["action", "action_is_pad"] if training else [])
        missing = [k for k in keys if k not in batch]
        if missing:
            raise ValueError(f"batch is missing {missing}; the policy expects cameras {list(cfg.camera_names)} "
                             f"and tactile sensors {list(cfg.tactile_names)}")
        qpos = batch[HDF5_STATE]
        if qpos.ndim != 2 or qpos.shape[1] != cfg.state_dim:
            raise ValueError(f"{HDF5_STATE} must be (B, {cfg.state_dim}), got {tuple(qpos.shape)}")
        b = qpos.shape[0]
        for k in keys[1:len(cfg.input_keys)]:
            x = batch[k]
            if x.ndim != 4 or x.shape[0] != b or x.shape[1] != 3:
                raise ValueError(f"{k} must be (B={b}, 3, H, W), got {tuple(x.shape)}")
        if training:
            a = batch["action"]
            if a.ndim != 3 or a.shape[0] != b or a.shape[1:] != (cfg.chunk_size, cfg.action_dim):
                raise ValueError(f"action must be (B={b}, chunk={cfg.chunk_size}, A={cfg.action_dim}), "
                                 f"got {tuple(a.shape)}")
            if tuple(batch["action_is_pad"].shape) != (b, cfg.chunk_size):
                raise ValueError(f"action_is_pad must be (B={b}, {cfg.chunk_size}), "
                                 f"got {tuple(batch['action_is_pad'].shape)}")
        return b

    def _stream_tokens(self, x: torch.Tensor, backbone: nn.Module, proj: nn.Module, index: int) -> torch.Tensor:
        feat = proj(backbone(x))  # (B, d, h, w)
        b, d, h, w = feat.shape
        tokens = feat.flatten(2).transpose(1, 2)  # (B, h*w, d)
        return tokens + sine_positions_2d(d, h, w, feat.device) + self.stream_embed[index]

    def _image_tokens(self, batch: dict) -> torch.Tensor:
        cfg = self.config
        dtype = self.queries.dtype
        streams = []
        for i, cam in enumerate(cfg.camera_names):
            x = batch[image_key(cam, HDF5)].to(self.queries.device, dtype) / 255.0
            x = F.interpolate(x, size=cfg.camera_size, mode="bilinear", align_corners=False)
            streams.append(self._stream_tokens((x - 0.5) / 0.25, self.camera_backbone, self.camera_proj, i))
        for j, s in enumerate(cfg.tactile_names):
            img = batch[tactile_key(s, HDF5)].to(self.queries.device, dtype)
            bg = batch[background_key(s, HDF5)].to(self.queries.device, dtype)
            if bg.shape != img.shape:
                raise ValueError(f"{background_key(s, HDF5)} {tuple(bg.shape)} must match "
                                 f"{tactile_key(s, HDF5)} {tuple(img.shape)}")
            x = F.interpolate((img - bg) / 255.0, size=cfg.tactile_size, mode="bilinear", align_corners=False)
            streams.append(self._stream_tokens(x * 4.0, self.tactile_backbone, self.tactile_proj,
                                               len(cfg.camera_names) + j))
        return torch.cat(streams, dim=1)

    # ------------------------------------------------------------------ network
    def _decode(self, batch: dict, z: torch.Tensor, qpos_n: torch.Tensor) -> torch.Tensor:
        tokens = torch.cat([
            (self.latent_proj(z) + self.token_pos[0])[:, None],
            (self.qpos_proj(qpos_n) + self.token_pos[1])[:, None],
            self._image_tokens(batch),
        ], dim=1)
        memory = self.encoder(tokens)
        queries = self.queries.unsqueeze(0).expand(z.shape[0], -1, -1)
        return self.action_head(self.decoder(queries, memory))  # (B, N_a, A), normalised units

    def forward(self, batch: dict) -> dict[str, torch.Tensor]:
        """Training loss: ``{"loss", "l1", "kl"}`` (scalars) for a batch with actions."""
        cfg = self.config
        b = self.check_batch(batch, training=True)
        dev, dtype = self.queries.device, self.queries.dtype
        qpos_n = (batch[HDF5_STATE].to(dev, dtype) - self.qpos_mean) / self.qpos_std
        action_n = (batch["action"].to(dev, dtype) - self.action_mean) / self.action_std
        is_pad = batch["action_is_pad"].to(dev, torch.bool)
        seq = torch.cat([self.vae_cls.expand(b, 1, -1), self.vae_qpos_proj(qpos_n)[:, None],
                         self.vae_action_proj(action_n)], dim=1)
        seq = seq + sine_positions_1d(cfg.dim_model, seq.shape[1], dev)
        pad_mask = torch.cat([torch.zeros(b, 2, dtype=torch.bool, device=dev), is_pad], dim=1)
        stats = self.vae_to_latent(self.vae_encoder(seq, src_key_padding_mask=pad_mask)[:, 0])
        mu, logvar = stats[:, :cfg.latent_dim], stats[:, cfg.latent_dim:]
        z = mu + torch.randn_like(mu) * torch.exp(0.5 * logvar)
        pred = self._decode(batch, z, qpos_n)
        valid = (~is_pad).unsqueeze(-1).to(dtype)
        l1 = ((pred - action_n).abs() * valid).sum() / (valid.sum() * cfg.action_dim).clamp(min=1.0)
        kl = (-0.5 * (1 + logvar - mu.pow(2) - logvar.exp())).sum(dim=1).mean()
        return {"loss": l1 + cfg.kl_weight * kl, "l1": l1, "kl": kl}

    @torch.no_grad()
    def predict(self, batch: dict) -> torch.Tensor:
        """Action chunks (B, N_a, A) in the dataset's units (z = 0)."""
        b = self.check_batch(batch, training=False)
        dev, dtype = self.queries.device, self.queries.dtype
        qpos_n = (batch[HDF5_STATE].to(dev, dtype) - self.qpos_mean) / self.qpos_std
        z = torch.zeros(b, self.config.latent_dim, device=dev, dtype=dtype)
        return self._decode(batch, z, qpos_n) * self.action_std + self.action_mean
