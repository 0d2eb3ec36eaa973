"""ACT (Action Chunking with Transformers) for controltac-il: config, network, checkpoints, policy."""

from controltac_il.lazy import exports

_EXPORTS = {**dict.fromkeys(("CheckpointError", "load_checkpoint", "read_config", "save_checkpoint"),
                            "policies.act.checkpoint"),
            "ACTConfig": "policies.act.configuration_act", "ACT": "policies.act.modeling_act",
            "ACTPolicy": "policies.act.policy"}
__getattr__, __dir__ = exports(__name__, _EXPORTS)
__all__ = list(_EXPORTS)
