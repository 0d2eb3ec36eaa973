"""controltac_il.io: atomic writers give normal permissions (the umask's) and clean up what a killed writer
left behind, never touching a file the tool did not write."""

import os
import signal
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch
from safetensors.torch import save_file

from controltac_il import io

REPO = Path(__file__).resolve().parents[1]


def mode(p: Path) -> int:
    return stat.S_IMODE(p.stat().st_mode)


@pytest.fixture
def umask():
    """Set a umask for one test and restore the previous one."""
    old = os.umask(0o022)
    yield lambda m: os.umask(m)
    os.umask(old)


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o002])
def test_atomic_writers_respect_the_umask(tmp_path, umask, mask):
    umask(mask)
    with io.atomic_path(tmp_path / "a.bin") as tmp:
        tmp.write_bytes(b"x")
    io.write_json(tmp_path / "b.json", {"a": 1})
    with io.atomic_dir(tmp_path / "folder") as tmp:
        (tmp / "plain.txt").write_text("x")
        io.write_json(tmp / "nested.json", [1])  # an atomic writer inside an atomic folder
        (tmp / "sub").mkdir()
        save_file({"w": torch.zeros(2)}, str(tmp / "sub" / "w.safetensors"))  # safetensors writes 0o600 itself
    want_file, want_dir = 0o666 & ~mask, 0o777 & ~mask
    for p in (tmp_path / "a.bin", tmp_path / "b.json", tmp_path / "folder" / "plain.txt",
              tmp_path / "folder" / "nested.json", tmp_path / "folder" / "sub" / "w.safetensors"):
        assert mode(p) == want_file, (p.name, oct(mode(p)))
    for p in (tmp_path / "folder", tmp_path / "folder" / "sub"):
        assert mode(p) == want_dir, (p.name, oct(mode(p)))


def test_replacing_a_folder_leaves_nothing_behind(tmp_path, umask):
    with io.atomic_dir(tmp_path / "d") as tmp:
        (tmp / "one").write_text("1")
    with io.atomic_dir(tmp_path / "d") as tmp:
        (tmp / "two").write_text("2")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == ["two"]
    with pytest.raises(RuntimeError):
        with io.atomic_dir(tmp_path / "d") as tmp:
            (tmp / "three").write_text("3")
            raise RuntimeError("writer failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == ["two"]  # untouched on failure


KILLED_WRITER = textwrap.dedent("""
    import os, signal, sys
    from pathlib import Path
    from controltac_il import io
    folder = Path(sys.argv[1])
    with io.atomic_dir(folder / "result") as tmp:
        (tmp / "part.bin").write_bytes(b"half")
        with io.atomic_path(folder / "file.json") as f:
            f.write_text("{")
            os.kill(os.getpid(), signal.SIGKILL)
""")


def killed_writer(folder: Path) -> list[str]:
    """Run a writer that is SIGKILLed mid-write; the names of what it left in ``folder``."""
    res = subprocess.run([sys.executable, "-c", KILLED_WRITER, str(folder)], cwd=REPO,
                         env={**os.environ, "PYTHONPATH": str(REPO)}, capture_output=True)
    assert res.returncode == -signal.SIGKILL, res.stderr.decode()
    return sorted(p.name for p in folder.iterdir())


def test_leftovers_of_a_killed_writer_are_removed_by_the_next_write(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    mine = {".result.killed.tmp": b"user", ".file.json.1.tmp": b"user", "notes.tmp": b"user"}
    for name, data in mine.items():  # the user's files, even with names like ours
        (folder / name).write_bytes(data)
    (folder / ".user_dir.tmp").mkdir()
    left = killed_writer(folder)
    ours = [n for n in left if n not in mine and n != ".user_dir.tmp"]
    assert len(ours) == 2 and all(n.endswith(".tmp") for n in ours), left  # a folder and a file
    io.write_json(folder / "other.json", {})  # any later write in that folder cleans up
    assert sorted(p.name for p in folder.iterdir()) == sorted([*mine, ".user_dir.tmp", "other.json"])
    for name, data in mine.items():
        assert (folder / name).read_bytes() == data


def test_leftovers_of_a_live_writer_are_kept(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    left = killed_writer(folder)
    ours = [folder / n for n in left]
    assert ours  # the killed writer left its temporary files
    # pretend they belong to a process that is still running (this one's parent)
    alive = []
    for p in ours:
        name = p.name.replace(f"-{io.leftover_pid(p.name)}-", f"-{os.getppid()}-")
        p.rename(folder / name)
        alive.append(name)
    io.remove_leftovers(folder)
    assert sorted(p.name for p in folder.iterdir()) == sorted(alive)
    assert io.leftover_pid("results.json") is None and io.leftover_pid(".x.killed.tmp") is None


def test_an_output_that_could_not_be_made_is_told_before_the_run_and_the_probe_leaves_nothing(tmp_path):
    from controltac_il.io import unwritable

    assert unwritable(tmp_path / "new" / "deeper" / "result.json") is None  # made later, under tmp_path
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "file").write_text("x")
    assert unwritable(tmp_path / "file" / "result.json") == f"{tmp_path / 'file'} is not a folder"
    if Path("/proc/self").is_dir():  # a pseudo file system refuses new files, even to root
        assert unwritable("/proc/result.json").startswith("no file can be made in /proc")
