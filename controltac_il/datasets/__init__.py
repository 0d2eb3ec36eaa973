"""Episode datasets: ACT HDF5 episodes extended with tactile streams, the ACT training dataset, and the interfaces a
training run meets its data through (``stage``)."""

from controltac_il.datasets.act_dataset import EpisodeDataset, EpisodeSubset
from controltac_il.datasets.background import estimate_background
from controltac_il.datasets.episodes import Episode, episode_index, episode_paths, read_episode, write_episode
from controltac_il.datasets.stage import Augmented, AugmentStage, FrameTable

__all__ = ["Episode", "write_episode", "read_episode", "episode_paths", "episode_index", "EpisodeDataset",
           "EpisodeSubset", "estimate_background", "Augmented", "AugmentStage", "FrameTable"]
