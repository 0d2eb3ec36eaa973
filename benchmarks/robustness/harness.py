"""Verdicts, fixtures and the probe registry of the robustness benchmark."""

from __future__ import annotations

import hashlib
import os
import re
import signal
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

REPO = Path(__file__).resolve().parents[2]
CLEAR, HANDLED, UNCLEAR, SILENT, LOSS = "clear error", "handled", "unclear error", "silent wrong", "data loss"
VERDICTS = (CLEAR, HANDLED, UNCLEAR, SILENT, LOSS)
# exceptions that only ever mean "a bug met bad input", whatever their message says
BUG_TYPES = (IndexError, AttributeError, UnboundLocalError, ZeroDivisionError, AssertionError, NameError)


@dataclass(frozen=True)
class Probe:
    """One probe: ``run(tmp) -> (verdict, detail[, outcome])`` in a fresh folder ``tmp`` (``outcome``: a command's
    exit code and whether it reported on one line, :func:`outcome`). ``fault``: a runtime fault the user can
    cause or meet (a missing or corrupt file, an unreachable robot, Ctrl-C, an unwritable output), not bad input."""

    surface: str
    name: str
    run: Callable[[Path], tuple]
    fault: bool = False


PROBES: list[Probe] = []


def probe(surface: str, name: str, fault: bool = False):
    """Register the decorated ``fn(tmp) -> (verdict, detail[, outcome])`` as a probe of ``surface``."""
    def register(fn):
        PROBES.append(Probe(surface, name, fn, fault))
        return fn
    return register


def last_line(text: str) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return lines[-1][:240] if lines else ""


def run_cli(args: list[str], cwd: Path = REPO, timeout: float = 300, env: dict | None = None,
            cache: Path | None = None) -> subprocess.CompletedProcess:
    """``python ARGS`` in ``cwd`` with one torch thread, headless MuJoCo and (optionally) its own cache."""
    full_env = {**os.environ, "OMP_NUM_THREADS": "1", "MUJOCO_GL": "egl", "PYTHONPATH": str(REPO),
                **({"CONTROLTAC_CACHE": str(cache)} if cache else {}), **(env or {})}
    return subprocess.run([sys.executable, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env=full_env, stdin=subprocess.DEVNULL)


def _names_all(text: str, names: tuple[str, ...]) -> bool:
    """Every name occurs in ``text`` (case-insensitive); "a|b" accepts either spelling (flag or field)."""
    return all(any(alt.lower() in text.lower() for alt in n.split("|")) for n in names)


_BAR = re.compile(r"^.*?\[(\d+:)?\d\d:\d\d[^\]]*\]")  # a tqdm bar: ... [elapsed<remaining, rate]


def error_lines(stderr: str) -> list[str]:
    """The lines of ``stderr`` as a terminal shows them (the text after a line's last carriage return: tqdm
    redraws its bar with them, and a message printed while a bar is open continues its line), progress bars
    left out."""
    shown = [ln.split("\r")[-1] for ln in stderr.split("\n")]
    return [rest for ln in shown if (rest := ln[m.end():] if (m := _BAR.match(ln)) else ln).strip()]


def outcome(res: subprocess.CompletedProcess) -> dict:
    """What the table records of a command: its exit code and whether it reported on one line (stderr,
    progress bars aside, is one line and holds no traceback)."""
    lines = error_lines(res.stderr)
    return {"exit_code": res.returncode,
            "one_line": len(lines) == 1 and "Traceback (most recent call last)" not in res.stderr}


def judge_cli(res: subprocess.CompletedProcess, *names: str) -> tuple[str, str, dict]:
    """A refused command: clear when it exits 2 without a traceback and its stderr names ``names``."""
    err, out = res.stderr, outcome(res)
    if res.returncode == 0:
        return SILENT, "exit 0: " + last_line(res.stdout or err), out
    if "Traceback (most recent call last)" in err:
        return UNCLEAR, f"exit {res.returncode}, traceback: {last_line(err)}", out
    if res.returncode == 2 and _names_all(err, names):
        return CLEAR, last_line(err), out
    return UNCLEAR, f"exit {res.returncode}: {last_line(err)}", out


def judge_fault(res: subprocess.CompletedProcess, *names: str, code: int | None = None) -> tuple[str, str, dict]:
    """A runtime fault a command met (a missing or corrupt file, a robot that does not answer, Ctrl-C, an output
    it cannot write): clear when it exits non-zero (``code`` when given) with one line on stderr that names
    ``names`` and no traceback; the row records the exit code and whether the report was one line."""
    out, lines = outcome(res), error_lines(res.stderr)
    if res.returncode == 0:
        return SILENT, "exit 0: " + last_line(res.stdout or res.stderr), out
    if "Traceback (most recent call last)" in res.stderr:
        return UNCLEAR, f"exit {res.returncode}, traceback: {last_line(res.stderr)}", out
    if not out["one_line"]:
        return UNCLEAR, f"exit {res.returncode}, {len(lines)} lines: {last_line(res.stderr)}", out
    if (code is None or res.returncode == code) and _names_all(lines[0], names):
        return CLEAR, f"exit {res.returncode}: {lines[0][:220]}", out
    return UNCLEAR, f"exit {res.returncode}: {lines[0][:220]}", out


def run_cli_interrupted(args: list[str], wait_for: str, after_s: float = 2.0, timeout: float = 300,
                        cache: Path | None = None) -> subprocess.CompletedProcess:
    """``python ARGS`` as :func:`run_cli`, sent Ctrl-C (SIGINT) ``after_s`` seconds after ``wait_for`` (a regular
    expression) first shows in its output. A command that never shows it is killed at ``timeout`` (exit -9);
    one that finishes first gets no Ctrl-C; either way a line on ``stderr`` says so."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MUJOCO_GL": "egl", "PYTHONPATH": str(REPO), "PYTHONUNBUFFERED": "1",
           **({"CONTROLTAC_CACHE": str(cache)} if cache else {})}
    folder = Path(os.environ.get("TMPDIR", "/tmp"))
    with (open(folder / f"probe-out-{os.getpid()}.txt", "w+") as out,
          open(folder / f"probe-err-{os.getpid()}.txt", "w+") as err):
        proc = subprocess.Popen([sys.executable, *args], cwd=REPO, env=env, stdout=out, stderr=err,
                                stdin=subprocess.DEVNULL,
                                # a background shell starts us with SIGINT ignored; Ctrl-C must reach the child
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        note = _interrupt_when(proc, re.compile(wait_for), after_s, timeout, (out.name, err.name))
        out.seek(0), err.seek(0)
        stdout, stderr = out.read(), err.read() + note
    for f in (out.name, err.name):
        os.unlink(f)
    return subprocess.CompletedProcess(args, proc.returncode, stdout, stderr)


def _interrupt_when(proc: subprocess.Popen, pattern: re.Pattern, after_s: float, timeout: float,
                    logs: tuple[str, str]) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        if any(pattern.search(Path(f).read_text(errors="replace")) for f in logs):
            time.sleep(after_s)
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=max(deadline - time.monotonic(), 30))
            except subprocess.TimeoutExpired:
                proc.kill(), proc.wait()
                return "\n[probe: still running 30 s after Ctrl-C, killed]"
            return ""
        time.sleep(0.5)
    if proc.poll() is None:
        proc.kill(), proc.wait()
        return f"\n[probe: {pattern.pattern!r} never showed within {timeout:g} s, killed]"
    return f"\n[probe: finished before {pattern.pattern!r} showed; no Ctrl-C sent]"


def judge_call(fn: Callable[[], object], *names: str) -> tuple[str, str]:
    """A refused call: clear when it raises a one-line message naming ``names`` (not a bug's exception)."""
    try:
        fn()
    except BaseException as exc:  # noqa: BLE001 - classifying is the point
        if isinstance(exc, (KeyboardInterrupt, SystemExit)):
            raise
        msg = f"{type(exc).__name__}: {exc}"
        if isinstance(exc, BUG_TYPES):
            return UNCLEAR, msg[:240] + " @ " + traceback.extract_tb(exc.__traceback__)[-1].name
        if "\n" not in str(exc).strip() and _names_all(str(exc), names):
            return CLEAR, msg[:240]
        return UNCLEAR, msg[:240]
    return SILENT, "accepted"


def snapshot(root: Path) -> dict[str, str]:
    """sha1 of every file under ``root`` by relative path (what the user owns before a command)."""
    return {str(p.relative_to(root)): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def lost(before: dict[str, str], root: Path) -> list[str]:
    """Files of ``before`` that are now changed or gone under ``root``."""
    now = snapshot(root)
    return [p for p, h in before.items() if now.get(p) != h]


def demo_episodes(folder: Path, n: int = 4, frames: int = 30, size=(24, 32), seed: int = 0, **changes) -> Path:
    """``n`` small synthetic ACT episodes (two cameras, two tactile sensors with backgrounds and forces), written
    over the probe's own earlier ones in ``folder``.

    changes: ``drop_tactile_in=(e, ...)`` leaves the right sensor out of those episodes.
    """
    from controltac_il.datasets.episodes import Episode, write_episode

    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    for e in range(n):
        t = np.linspace(0, 1, frames, dtype=np.float32)[:, None]
        qpos = np.concatenate([0.4 + 0.1 * t, 0.05 * t, 0.2 - 0.1 * t, 0 * t, (t > 0.3).astype(np.float32)], 1)
        bg = np.full((*size, 3), 120, np.uint8)
        tactile = {s: np.repeat(bg[None], frames, 0).copy() for s in ("left", "right")}
        force = {s: np.zeros((frames, 3), np.float32) for s in ("left", "right")}
        for s in tactile:
            tactile[s][frames // 2:, 8:16, 10:20] = 160 + rng.integers(0, 20)
            force[s][frames // 2:, 2] = 4.0 + e
        if e in changes.get("drop_tactile_in", ()):
            tactile.pop("right"), force.pop("right")
        images = {c: rng.integers(0, 255, (frames, *size, 3), dtype=np.uint8) for c in ("third_view", "wrist")}
        write_episode(folder / f"episode_{e}.hdf5", Episode(
            qpos=qpos, action=qpos + 0.01, images=images, tactile=tactile,
            tactile_background={s: bg for s in tactile}, force=force, sim=True), overwrite=True)
    return folder


def edit_episode(path: Path, key: str, value) -> None:
    """Replace dataset ``key`` of an episode file in place (bypassing the writer's validation)."""
    import h5py

    with h5py.File(path, "r+") as f:
        del f[key]
        if value is not None:
            f[key] = value


def tiny_checkpoint(folder: Path, size=(24, 32)) -> Path:
    """A small untrained ACT checkpoint for the synthetic episodes (cameras and tactile at ``size``)."""
    import torch

    from policies.act import ACT, ACTConfig, save_checkpoint

    torch.manual_seed(0)
    cfg = ACTConfig.from_preset("cpu", camera_names=("third_view", "wrist"), tactile_names=("left", "right"),
                                dim_model=32, n_heads=2, dim_feedforward=64, n_encoder_layers=1,
                                n_vae_encoder_layers=1, chunk_size=6, camera_size=size, tactile_size=size)
    return save_checkpoint(folder, ACT(cfg))


SETUP = {
    "name": "probe", "robot": {"type": "xarm", "ip": "127.0.0.1", "tool_rpy": [3.14159265, 0.0]},
    "gripper": {"type": "xarm", "open_position": 850, "closed_position": 0},
    "cameras": {"third_view": {"device": "/dev/video0", "size": [240, 320], "fps": 30}},
    "tactile": {"left": {"device": "GelSight Mini"}},
    "limits": {"workspace_min": [0.25, -0.25, 0.02], "workspace_max": [0.65, 0.25, 0.40],
               "max_step_m": 0.02, "max_rotation_rad": 0.1},
    "control": {"rate_hz": 10},
}


def setup_yaml(tmp: Path, edit: Callable[[dict], None] | None = None, text: str | None = None) -> Path:
    """A valid xArm setup file, changed by ``edit(setup_dict)`` (or replaced by raw ``text``)."""
    import copy

    import yaml

    cfg = copy.deepcopy(SETUP)
    if edit:
        edit(cfg)
    path = tmp / "setup.yaml"
    path.write_text(text if text is not None else yaml.safe_dump(cfg, sort_keys=False))
    return path
