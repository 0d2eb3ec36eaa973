"""LeRobot v3.0 dataset folders without LeRobot: read, served as ACT's training data, and written augmented.

Modules, one job each (after LeRobot's own ``datasets/``): ``reader`` (``LeRobotFolder``: a folder's items, as
``LeRobotDataset`` returns them), ``video`` (mp4 decoding and encoding with PyAV), ``stats`` (per-episode and
dataset stats, as LeRobot computes them), ``writer`` (data parquet, PNG bytes and ``meta/`` files), ``episodes``
(``LeRobotEpisodes``: a folder as ACT's training data), ``provenance`` (the ``augment.*`` features' names),
``export`` (``LeRobotExport``: the augmented folder's episodes from a ForceAugment cache) and ``publish`` (``write_lerobot``: staging, resuming and publishing that
folder). Format facts: ``docs/lerobot_v3_format.md``.
"""

from controltac_il.lazy import exports

_EXPORTS = {"LeRobotEpisodes": "controltac_il.lerobot.episodes",
            "LeRobotExport": "controltac_il.lerobot.export",
            **dict.fromkeys(("COPY", "PREFIX"), "controltac_il.lerobot.provenance"),
            **dict.fromkeys(("ChunkGate", "check_destination", "read_record", "staging_dir", "write_lerobot"),
                            "controltac_il.lerobot.publish"),
            **dict.fromkeys(("LeRobotFolder", "decode_png", "numbers", "read_episode_stats", "read_episodes",
                             "read_info", "read_tasks", "readable_parquet"), "controltac_il.lerobot.reader"),
            **dict.fromkeys(("QUANTILES", "STAT_NAMES", "aggregate_stats", "complete_stats", "frame_histograms",
                             "histogram_stats", "image_stats", "sample_indices", "vector_stats"),
                            "controltac_il.lerobot.stats"),
            **dict.fromkeys(("ENCODERS", "TOLERANCE_S", "FrameTimestampError", "VideoFrames", "decode_video",
                             "encode_video", "readable_video", "video_codec"), "controltac_il.lerobot.video"),
            **dict.fromkeys(("INFO_KEYS", "episodes_table", "info_json", "png_bytes", "write_data_parquet",
                             "write_meta", "write_parquet"), "controltac_il.lerobot.writer")}
__getattr__, __dir__ = exports(__name__, _EXPORTS)
__all__ = list(_EXPORTS)
