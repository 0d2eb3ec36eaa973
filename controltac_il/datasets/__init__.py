"""Episode datasets: ACT HDF5 episodes extended with tactile streams, the ACT training dataset, and the interfaces a
training run meets its data through (``stage``)."""

from controltac_il.lazy import exports

_EXPORTS = {**dict.fromkeys(("EpisodeDataset", "EpisodeSubset"), "controltac_il.datasets.act_dataset"),
            **dict.fromkeys(("estimate_background", "read_background_image"), "controltac_il.datasets.background"),
            **dict.fromkeys(("Episode", "episode_index", "episode_paths", "read_episode", "write_episode"),
                            "controltac_il.datasets.episodes"),
            **dict.fromkeys(("Augmented", "AugmentStage", "FrameTable"), "controltac_il.datasets.stage")}
__getattr__, __dir__ = exports(__name__, _EXPORTS)
__all__ = list(_EXPORTS)
