"""Where the tool writes, and how: the cache root and atomic writers.

Every writer goes to a temporary path in the destination's folder and is renamed into place
(``os.replace`` is atomic on POSIX within one filesystem), so nothing is ever left half-written.

What a writer leaves is what any program would: files ``0o666`` and folders ``0o777`` less the umask
(``tempfile`` alone would leave ``0o600`` / ``0o700``).

A temporary path is named ``.<name>.controltac-<host>-<pid>-<random>.tmp[<suffix>]``, a pattern only this
module produces. A process killed mid-write (SIGKILL, power loss) leaves one behind; a process's first
atomic write into a folder removes every such leftover of this host whose process is no longer running
(``remove_leftovers``; writers may call it themselves, e.g. when a run starts). Nothing else is ever removed: not
a live writer's temporary path, not another host's (a shared filesystem), not a file of the user's whatever its
name.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import json
import os
import re
import shutil
import socket
import tempfile
from pathlib import Path
from typing import Iterator

_TAG = "controltac"


def cache_root() -> Path:
    """The tool's cache folder (demos, ForceAugment caches): $CONTROLTAC_CACHE, else
    $XDG_CACHE_HOME/controltac_il, else ~/.cache/controltac_il."""
    base = os.environ.get("CONTROLTAC_CACHE")
    if base:
        return Path(base)
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "controltac_il"


# --- where an output may go, and its mode ---------------------------------------------------------

def check_apart(source: str | os.PathLike, out: str | os.PathLike) -> None:
    """ValueError naming ``out`` where it is the ``source`` folder, inside it or around it: a tool's output never
    lands among the data it reads."""
    source, out = Path(source).resolve(), Path(out).resolve()
    if out == source or source in out.parents or out in source.parents:
        raise ValueError(f"out: {out} must be a folder of its own, not the source {source}, inside it or around it")


def unwritable(dest: str | os.PathLike) -> str | None:
    """Why a new file or folder ``dest`` could not be made (its nearest existing folder refuses a file: read-only,
    a pseudo file system, no permission), or None: checked before a long run, not after it."""
    parent = Path(dest).absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        return f"{parent} is not a folder"
    try:
        with tempfile.NamedTemporaryFile(dir=parent, prefix=".controltac-probe-"):
            return None
    except OSError as exc:
        return f"no file can be made in {parent} ({exc.strerror or exc})"


def current_umask() -> int:
    """The process's umask (read from /proc where possible: setting it to read it is not thread-safe)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def normal_mode(is_dir: bool) -> int:
    """The mode a plain ``open`` / ``mkdir`` would give under the current umask."""
    return (0o777 if is_dir else 0o666) & ~current_umask()


# --- temporary names and leftovers ----------------------------------------------------------------

def _host() -> str:
    return re.sub(r"[^A-Za-z0-9]", "", socket.gethostname())[:32] or "host"


_LEFTOVER = re.compile(rf"^\..+\.{_TAG}-(?P<host>[A-Za-z0-9]+)-(?P<pid>\d+)-[A-Za-z0-9_]+\.tmp(\.[A-Za-z0-9_]+)*$")


def _temp_affixes(dest: Path, suffix: str) -> tuple[str, str]:
    """(prefix, suffix) of a temporary path beside ``dest`` (``tempfile`` puts its random part between)."""
    if suffix and not re.fullmatch(r"(\.[A-Za-z0-9_]+)+", suffix):
        raise ValueError(f"suffix: expected an extension like '.png', got {suffix!r}")
    return f".{dest.name}.{_TAG}-{_host()}-{os.getpid()}-", ".tmp" + suffix


def leftover_pid(name: str) -> int | None:
    """The pid of the writer that made temporary path ``name`` on this host; None when ``name`` is not one
    of this module's temporary paths (or was made on another host)."""
    m = _LEFTOVER.match(name)
    if m is None or m["host"] != _host():
        return None
    return int(m["pid"])


def is_temporary_name(name: str) -> bool:
    """Whether ``name`` is a temporary path of this module's atomic writers (any host, live or not)."""
    return _LEFTOVER.match(name) is not None


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


_SWEPT: set[tuple[int, str]] = set()  # (pid, folder) already cleaned by this process's atomic writers


def _sweep_once(folder: Path) -> None:
    """``remove_leftovers(folder)`` on this process's first atomic write there (one scan per folder, not
    one per file: a cache of 10 000 chunks must not rescan its folder 10 000 times)."""
    key = (os.getpid(), os.path.abspath(folder))
    if key not in _SWEPT:
        remove_leftovers(folder)
        _SWEPT.add(key)


def remove_leftovers(folder: str | os.PathLike) -> list[Path]:
    """Remove the temporary paths that killed writers of this host left in ``folder``; returns them.

    Only names of this module's pattern whose pid is no longer running are touched."""
    folder = Path(folder)
    removed = []
    try:
        entries = list(os.scandir(folder))
    except (FileNotFoundError, NotADirectoryError):
        return removed
    for entry in entries:
        pid = leftover_pid(entry.name)
        if pid is None or _alive(pid):
            continue
        path = Path(entry.path)
        try:
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(path)
            else:
                path.unlink()
        except FileNotFoundError:  # another process cleaned it first
            continue
        removed.append(path)
    return removed


# --- atomic writers -------------------------------------------------------------------------------

def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False where not supported."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    at_fdcwd, rename_exchange = -100, 2
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP, errno.EPERM):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _fix_modes(root: Path) -> None:
    """Give ``root`` (made by ``tempfile``: 0o600 / 0o700) and, for a folder, everything in it the umask's normal
    mode (some writers, safetensors among them, create their files 0o600)."""
    os.chmod(root, normal_mode(root.is_dir()))
    if root.is_dir():
        files, folders = normal_mode(False), normal_mode(True)
        for parent, dirs, names in os.walk(root):
            for d in dirs:
                os.chmod(os.path.join(parent, d), folders)
            for n in names:
                os.chmod(os.path.join(parent, n), files)


@contextlib.contextmanager
def atomic_path(dest: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary file path beside ``dest``; rename it onto ``dest`` on success.

    The temporary name ends with ``suffix`` (e.g. ".png") for writers that infer the format from it.
    On an exception the temporary file is removed and ``dest`` is untouched. The file gets the
    umask's normal mode.
    """
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    _sweep_once(dest.parent)
    prefix, end = _temp_affixes(dest, suffix)
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=end, dir=dest.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        _fix_modes(tmp_path)
        os.replace(tmp_path, dest)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_dir(dest: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary folder beside ``dest``; rename it onto ``dest`` on success.

    An existing ``dest`` is replaced only after the new folder is complete (swapped in one atomic
    step where the system allows it, so ``dest`` always holds one complete version). The folder gets
    the umask's normal mode.
    """
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    _sweep_once(dest.parent)
    prefix, end = _temp_affixes(dest, "")
    tmp = Path(tempfile.mkdtemp(prefix=prefix, suffix=end, dir=dest.parent))
    try:
        yield tmp
        _fix_modes(tmp)
        if dest.exists():
            if not _exchange(tmp, dest):  # two renames: a kill in between leaves dest missing, never mixed
                old = Path(tempfile.mkdtemp(prefix=prefix, suffix=end, dir=dest.parent))
                os.replace(dest, old)
                os.replace(tmp, dest)
                tmp = old
            shutil.rmtree(tmp, ignore_errors=True)  # now the previous version
        else:
            os.replace(tmp, dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_json(dest: str | os.PathLike, obj) -> None:
    """Write ``obj`` as indented JSON, atomically."""
    with atomic_path(dest) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")
