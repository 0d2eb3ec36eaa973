"""ACT (Action Chunking with Transformers) for controltac-il: config, network, checkpoints, policy."""

from policies.act.checkpoint import CheckpointError, load_checkpoint, read_config, save_checkpoint
from policies.act.configuration_act import ACTConfig
from policies.act.modeling_act import ACT
from policies.act.policy import ACTPolicy

__all__ = ["ACTConfig", "ACT", "ACTPolicy", "CheckpointError", "save_checkpoint", "load_checkpoint", "read_config"]
