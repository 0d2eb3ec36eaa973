"""Episode datasets: ACT HDF5 episodes extended with tactile streams, and the ACT training dataset."""

from controltac_il.datasets.act_dataset import EpisodeDataset
from controltac_il.datasets.background import estimate_background
from controltac_il.datasets.episodes import Episode, episode_index, episode_paths, read_episode, write_episode

__all__ = ["Episode", "write_episode", "read_episode", "episode_paths", "episode_index", "EpisodeDataset",
           "estimate_background"]
