"""The LeRobot export beside the cache build: a copy is exported while later chunks are still being generated, with the
same files as before (the session's ``written`` clean write, conftest); an export error stops the build at its next
chunk; ``ChunkGate``'s rule; a source's own per-episode stats reused for the features copies hold unchanged where
complete, computed where not; worker processes writing the same files, a worker's error raised in one line.
Source folder and tiny generator: ``lerobot_fixtures``."""

import shutil
import threading

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from files import tree_bytes
from lerobot_fixtures import LEFT, LENGTHS, RIGHT, WRIST, augment, write_lerobot

from controltac_il.augment import main
from controltac_il.augment.provenance import PROVENANCE, StaleCacheError, chunk_dir, chunk_done
from controltac_il.lerobot import (STAT_NAMES, ChunkGate, LeRobotExport, LeRobotFolder, read_episode_stats,
                                   staging_dir)

EPISODES_META = "meta/episodes/chunk-000/file-000.parquet"


class Gated:
    """The generator; its ``stall``-th ``generate_at`` call first waits for ``release`` (at most 60 s) and records
    whether it came."""

    def __init__(self, generator, stall: int, release: threading.Event):
        self.generator, self.stall, self.release, self.calls, self.released = generator, stall, release, 0, None

    def __getattr__(self, name):
        return getattr(self.generator, name)

    def generate_at(self, *args, **kwargs):
        self.calls += 1
        if self.calls == self.stall:
            self.released = self.release.wait(timeout=60)
        return self.generator.generate_at(*args, **kwargs)


def test_a_copy_is_exported_while_later_chunks_are_generated(written, tmp_path, monkeypatch):
    root, clean, _, reference = written
    exported, E = threading.Event(), len(LENGTHS)
    original = LeRobotExport._write_episode

    def spy(self, j, *args):
        row = original(self, j, *args)
        if j == E:  # copy 1 of source episode 0
            exported.set()
        return row

    monkeypatch.setattr(LeRobotExport, "_write_episode", spy)
    gated = Gated(reference.generator, stall=2, release=exported)  # chunk (0, 1), then (0, 2) waits
    out = tmp_path / "out"
    write_lerobot(augment(root, out, generator=gated), LeRobotFolder(root), out, progress=False)
    assert gated.released is True and gated.calls == 4
    assert tree_bytes(out) == tree_bytes(clean)


def test_an_export_error_stops_the_build_at_its_next_chunk(written, tmp_path, monkeypatch):
    root, _, _, reference = written
    failed = threading.Event()

    def broken(self, j, *args):
        raise ValueError("dataset: a broken source file")

    def fail(self, error):
        original(self, error)
        failed.set()

    original = ChunkGate.fail
    monkeypatch.setattr(LeRobotExport, "_write_episode", broken)
    monkeypatch.setattr(ChunkGate, "fail", fail)
    gated = Gated(reference.generator, stall=2, release=failed)  # the original fails once chunk (0, 1) is built
    out = tmp_path / "out"
    with pytest.raises(ValueError, match="^dataset: a broken source file$"):
        write_lerobot(augment(root, out, generator=gated), LeRobotFolder(root), out, progress=False)
    assert gated.released is True and gated.calls == 2  # chunks (1, 1) and (1, 2) never generated
    assert not out.exists() and not list((staging_dir(out) / "done").glob("*.json"))


def test_the_gate_opens_on_a_chunk_or_the_builds_end(tmp_path):
    gate = ChunkGate(tmp_path, chunk_done)
    for e, k in ((3, 1), (3, 2), (7, 1)):
        chunk_dir(tmp_path, e, k).mkdir(parents=True)
        (chunk_dir(tmp_path, e, k) / PROVENANCE).write_text("{}")
    assert gate.wait(3, 2) is True and gate.wait(7, 1) is True  # built, the build still on
    results = []
    waiter = threading.Thread(target=lambda: results.append(gate.wait(7, 2)))  # never built
    waiter.start()
    gate.built()
    gate.close()
    waiter.join(timeout=60)
    assert results == [False] and gate.wait(3, 1) is True
    gate.close(aborted=True)  # a failed build: nothing more is exported
    assert gate.wait(3, 1) is False


def _with_stats(root, tmp_path):
    """A copy of the source whose meta/episodes holds stats: complete for the wrist camera and the state (values
    no frame has, so that reuse shows), without q99 for the action."""
    src = tmp_path / "with_stats"
    shutil.copytree(root, src)
    table = pq.read_table(src / EPISODES_META)
    given = {}
    for e in range(len(LENGTHS)):
        camera = {s: [[[0.1 * (e + 1) + 0.01 * c]] for c in range(3)] for s in STAT_NAMES if s != "count"}
        state = {s: [1000.0 + e, 2000.0, 3000.0] for s in STAT_NAMES if s != "count"}
        action = {s: [0.5, 0.5] for s in STAT_NAMES if s not in ("count", "q99")}
        given[e] = {WRIST: {**camera, "count": [LENGTHS[e]]}, "observation.state": {**state, "count": [LENGTHS[e]]},
                    "action": {**action, "count": [LENGTHS[e]]}}
    for key in (WRIST, "observation.state", "action"):
        for stat in given[0][key]:
            table = table.append_column(f"stats/{key}/{stat}", pa.array([given[e][key][stat] for e in given]))
    pq.write_table(table, src / EPISODES_META)
    return src, given


def test_a_sources_complete_stats_are_reused_for_unchanged_features(written, tmp_path):
    root, clean, _, reference = written
    src, given = _with_stats(root, tmp_path)
    assert read_episode_stats(src, [WRIST, "action"]) == {e: {k: given[e][k] for k in (WRIST, "action")}
                                                          for e in given}
    out = tmp_path / "out"
    write_lerobot(augment(src, out, generator=reference.generator), LeRobotFolder(src), out, progress=False)
    rows = pq.read_table(out / EPISODES_META).to_pylist()
    before = pq.read_table(clean / EPISODES_META).to_pylist()
    E = len(LENGTHS)
    for j, (row, old) in enumerate(zip(rows, before)):
        for key in (WRIST, "observation.state"):  # the source's, originals and copies alike
            assert {s: row[f"stats/{key}/{s}"] for s in STAT_NAMES} == given[j % E][key]
        for s in STAT_NAMES:  # incomplete: computed from the frames, as without any
            assert row[f"stats/action/{s}"] == old[f"stats/action/{s}"]
            assert row[f"stats/{LEFT}/{s}"] == old[f"stats/{LEFT}/{s}"]
            assert row[f"stats/{RIGHT}/{s}"] == old[f"stats/{RIGHT}/{s}"]
    state = np.asarray([row["stats/observation.state/mean"] for row in rows])
    assert np.all(state >= 1000.0)



def test_only_complete_plausible_stats_count_as_given():
    from controltac_il.lerobot import complete_stats, image_stats, vector_stats

    camera = {"dtype": "video", "shape": (4, 4, 3)}
    frames = np.random.default_rng(0).integers(0, 256, (5, 4, 4, 3), dtype=np.uint8)
    good = image_stats(frames)
    assert complete_stats(good, camera)
    in_levels = {k: (np.asarray(v) * 255).tolist() if k != "count" else v for k, v in good.items()}
    assert not complete_stats(in_levels, camera)  # 0-255, not LeRobot's [0, 1]
    assert not complete_stats({k: v for k, v in good.items() if k != "q99"}, camera)
    assert not complete_stats({**good, "mean": [[[2.0]]] * 3}, camera)  # above its max
    vector = {"dtype": "float32", "shape": (2,)}
    stats = vector_stats(np.array([[0.0, 1.0], [2.0, 3.0]]), "x")
    assert complete_stats(stats, vector)
    assert not complete_stats({**stats, "std": [float("nan"), 1.0]}, vector)
    assert not complete_stats({**stats, "count": [0]}, vector)
    assert not complete_stats({**stats, "mean": [1.0]}, vector)  # the feature's size is 2


def test_rank_0_writes_what_another_ranks_export_left(written, tmp_path):
    root, clean, _, reference = written
    out = tmp_path / "three_ranks"
    # 3 ranks, 2 episodes x 2 copies: episode 1 is rank 1's to export, its copy 2 rank 2's to build; rank 1 runs
    # before rank 2 has built it, so its export stops short and rank 0 finishes it
    for rank in (1, 2):
        write_lerobot(augment(root, out, generator=reference.generator), LeRobotFolder(root), out, rank=rank,
                      world_size=3, progress=False, poll_s=0.0)
    assert sorted(p.name for p in (staging_dir(out) / "done").iterdir()) == ["episode-000001.json",
                                                                             "episode-000003.json"]
    finished = []
    last = threading.Thread(target=lambda: finished.append(write_lerobot(
        augment(root, out, generator=reference.generator), LeRobotFolder(root), out, rank=0, world_size=3,
        progress=False, poll_s=0.0)["published"]), daemon=True)  # a hang fails the test, not the run
    last.start()
    last.join(timeout=120)
    assert finished == [True] and tree_bytes(out) == tree_bytes(clean)


def test_worker_processes_write_the_same_files(written, tmp_path):
    root, clean, _, reference = written
    out = tmp_path / "out"
    write_lerobot(augment(root, out, generator=reference.generator), LeRobotFolder(root), out, progress=False,
                  export_workers=2)
    assert tree_bytes(out) == tree_bytes(clean)


@pytest.mark.slow  # a spawned worker imports torch: about 6 s on two cores
def test_a_workers_error_is_raised_with_its_message(written, tmp_path):
    root, _, _, reference = written
    out, cache = tmp_path / "out", staging_dir(tmp_path / "out") / "cache"
    shutil.copytree(reference.cache_dir, cache)  # a built cache of these settings
    images = chunk_dir(cache, 1, 2) / "tactile_0.npy"
    images.write_bytes(images.read_bytes()[:-1])  # truncated after the build
    aug = augment(root, out, generator=reference.generator)
    export = LeRobotExport(aug, LeRobotFolder(root), tmp_path / "dataset", tmp_path / "done", workers=2)
    with pytest.raises(StaleCacheError, match=r"^cache chunk .*: tactile_0\.npy has \d+ bytes") as raised:
        export.write(rank=1, world_size=2, progress=False)  # source episode 1 alone: one worker process
    assert "\n" not in str(raised.value)


def test_export_workers_below_one_are_refused_naming_the_flag(written, tmp_path, capsys):
    root = written[0]
    assert main(["--dataset", str(root), "--out", str(tmp_path / "out"), "--export-workers", "0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("python -m controltac_il.augment: error: --export-workers: ") and err.count("\n") == 1
