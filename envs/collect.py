"""Record scripted-expert demonstrations of the peg-in-hole scene as ACT HDF5 episodes.

    python -m envs.collect --episodes 50 --out data/sim_peg

writes ``episode_0.hdf5`` ... ``episode_49.hdf5`` (``controltac_il.datasets.episodes`` layout):
third-view and wrist RGB, one tactile stream per finger with its no-contact background, per-pad
force labels [Fx, Fy, Fz] N (sensor frame), qpos [x, y, z, yaw, gripper] and the commanded action.
Frame t holds the observation before action t (ACT's convention). An episode ends ``hold_steps``
frames after the peg is inserted; failed attempts are skipped (or kept with ``--keep-failures``),
so the folder holds exactly ``--episodes`` files. Episode ``i``'s attributes record the scene seed.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

from controltac_il.cli import ArgumentParser  # noqa: E402
from controltac_il.streams import LOOP, LOOP_STATE, force_key, image_key, tactile_key  # noqa: E402
from envs.config import CAMERAS, OPTICS, SCENES, SENSORS, PegInHoleConfig, scene_config  # noqa: E402

if TYPE_CHECKING:  # MuJoCo is imported by the job, after the options: --help stays light
    from envs.expert import ScriptedExpert
    from envs.peg_in_hole import PegInHoleEnv


def record_episode(env: PegInHoleEnv, expert: ScriptedExpert, seed: int, hold_steps: int = 3):
    """Run the expert for one episode; returns (Episode, success)."""
    from controltac_il.datasets.episodes import Episode

    obs, info = env.reset(seed=seed)
    expert.reset(seed + 7919)  # the expert's noise stream, distinct from the scene's draws
    frames: list[dict] = []
    actions: list[np.ndarray] = []
    success_at = None
    for t in range(env.config.max_steps):
        action = expert.act()
        frames.append(obs)
        actions.append(action)
        obs, _, terminated, truncated, info = env.step(action)
        if success_at is None and info["success"]:
            success_at = t
        if success_at is not None and t - success_at >= hold_steps:
            break
        if truncated:
            break
    cfg = env.config
    tactile = {s: np.stack([f[tactile_key(s, LOOP)] for f in frames]) for s in SENSORS} if cfg.tactile else {}
    episode = Episode(
        qpos=np.stack([f[LOOP_STATE] for f in frames]),
        action=np.stack(actions),
        images={c: np.stack([f[image_key(c, LOOP)] for f in frames]) for c in cfg.cameras},
        tactile=tactile,
        tactile_background={s: env.tactile_background(s) for s in tactile},
        force={s: np.stack([f[force_key(s, LOOP)] for f in frames]) for s in SENSORS},
        sim=True,
        attrs={
            "task": "peg_in_hole",
            "seed": int(seed),
            "success": bool(success_at is not None),
            "control_hz": float(cfg.control_hz),
            "grip_force_n": float(env.grip_force_n),
            "hole_xy_m": np.asarray(env.hole_xy, dtype=np.float64),
            "hole_diameter_mm": float(cfg.hole_diameter_mm),
            **({"in_hand_offset_mm": float(env.in_hand_offset_m * 1000.0)} if cfg.peg_in_hand else {}),
            "action_space": "tcp x y z (m), yaw (rad), gripper [0 open, 1 closed]",
            "qpos_space": "tcp x y z (m), yaw (rad), gripper closure [0, 1]",
        },
    )
    return episode, success_at is not None


# the scene fields the flags set: a config error names the flag
PROG = "python -m envs.collect"
FLAG_OF_FIELD = {"cameras": "--cameras", "camera_size": "--camera-size", "tactile_size": "--tactile-size",
                 "tactile_optics": "--optics", "tactile": "--no-tactile", "grip_force_range_n": "--grip-force",
                 "hole_diameter_mm": "--hole-diameter"}


def build_parser() -> argparse.ArgumentParser:
    """The command line, its defaults the scene's (``PegInHoleConfig``)."""
    d = PegInHoleConfig()
    p = ArgumentParser(
        prog=PROG,
        description="Record scripted peg-in-hole demonstrations (cameras, tactile, forces) as ACT HDF5 "
                    "episodes episode_<i>.hdf5 in --out.",
    )
    p.add_argument("--episodes", type=int, default=50, help="number of episode files to write (default 50)")
    p.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an earlier collection in --out (only files this tool wrote; default: refuse to touch it)")
    p.add_argument("--seed", type=int, default=0, help="first scene seed; later episodes use the next seeds (default 0)")
    p.add_argument("--cameras", nargs="*", default=list(CAMERAS), choices=CAMERAS,
                   help="cameras to record (default: third_view wrist; none: no images)")
    p.add_argument("--camera-size", type=int, nargs=2, default=d.camera_size, metavar=("H", "W"),
                   help=f"camera image size in pixels (default {d.camera_size[0]} {d.camera_size[1]})")
    p.add_argument("--tactile-size", type=int, nargs=2, default=None, metavar=("H", "W"),
                   help=f"tactile image size in pixels, GelSight Mini aspect 3:4 (default {d.tactile_size[0]} {d.tactile_size[1]})")
    p.add_argument("--optics", default=None, choices=OPTICS,
                   help=f"tactile optics model (default {d.tactile_optics}, as the generator's training data)")
    p.add_argument("--no-tactile", action="store_true", help="record no tactile images (forces are still recorded)")
    p.add_argument("--scene", default="default", choices=SCENES,
                   help="default: pick the peg from the table; touch_critical: the peg starts in the hand "
                        "off-centre and the cameras cannot see it (PegInHoleConfig.touch_critical)")
    p.add_argument("--grip-force", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
                   help="per-finger grip force range in N, drawn per episode (default: the scene's, 3 9 / 4 7)")
    p.add_argument("--hole-diameter", type=float, default=None,
                   help="hole diameter in mm (default: the scene's, 30 = paper)")
    p.add_argument("--hold-steps", type=int, default=3, help="frames recorded after the insertion succeeds (default 3)")
    p.add_argument("--keep-failures", action="store_true", help="also write episodes where the expert failed")
    p.add_argument("--max-attempts", type=int, default=None,
                   help="give up after this many attempts, at least --episodes (default: 2 x episodes + 10)")
    p.add_argument("--compression", default=None, choices=("gzip", "lzf"), help="HDF5 image compression (default none)")
    p.add_argument("--quiet", action="store_true", help="no closing summary line (a caller that moves --out says where)")
    return p


def parse_args(argv=None) -> argparse.Namespace:
    """Parse and validate the command line; ``args.config`` is the scene. Exits 2 with one line naming
    the flag on any invalid value."""
    p = build_parser()
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error(f"--episodes must be an int >= 1, got {args.episodes}")
    if args.seed < 0:
        p.error(f"--seed must be an int >= 0 (the first scene seed), got {args.seed}")
    if args.hold_steps < 0:
        p.error(f"--hold-steps must be an int >= 0, got {args.hold_steps}")
    if args.max_attempts is not None and args.max_attempts < args.episodes:
        p.error(f"--max-attempts must be an int >= --episodes ({args.episodes}), got {args.max_attempts}")
    if args.out.exists() and not args.out.is_dir():
        p.error(f"--out {args.out} exists and is not a folder; give a folder for the episode files")
    tactile_only = [f for f, v in (("--tactile-size", args.tactile_size), ("--optics", args.optics)) if v is not None]
    if args.no_tactile and tactile_only:
        p.error(f"{tactile_only[0]}: sets the tactile images, which --no-tactile leaves out")
    d = PegInHoleConfig()
    args.tactile_size = args.tactile_size or d.tactile_size
    args.optics = args.optics or d.tactile_optics
    try:
        overrides = dict(cameras=tuple(args.cameras), camera_size=tuple(args.camera_size),
                         tactile=not args.no_tactile, tactile_size=tuple(args.tactile_size), tactile_optics=args.optics)
        if args.grip_force is not None:
            overrides["grip_force_range_n"] = tuple(args.grip_force)
        if args.hole_diameter is not None:
            overrides["hole_diameter_mm"] = args.hole_diameter
        args.config = scene_config(args.scene, **overrides)
    except ValueError as exc:
        msg = str(exc)
        field = next((f for f in sorted(FLAG_OF_FIELD, key=len, reverse=True) if msg.startswith(f)), None)
        p.error(f"{FLAG_OF_FIELD[field]}: {msg}" if field else f"--scene {args.scene} with these flags: {msg}")
    return args


INFO_KEYS = ("episodes", "attempts", "failed_seeds", "config", "expert")  # collect_info.json, in order


def own_episode(path: Path) -> str | None:
    """None for an episode file this tool wrote (a simulated peg-in-hole episode), else why not."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            sim, task = bool(f.attrs.get("sim", False)), f.attrs.get("task")
    except OSError:
        return "not an HDF5 file"
    task = task.decode() if isinstance(task, bytes) else task
    return None if sim and task == "peg_in_hole" else "not a simulated peg_in_hole episode"


def main(argv=None) -> int:
    args = parse_args(argv)
    from tqdm import tqdm

    from controltac_il.datasets.episodes import episode_index, episode_paths, write_episode
    from controltac_il.io import write_json
    from controltac_il.outputs import OutputInUse, claim_output, own_json
    from envs.expert import ExpertConfig, ScriptedExpert
    from envs.peg_in_hole import PegInHoleEnv

    config = args.config
    max_attempts = 2 * args.episodes + 10 if args.max_attempts is None else args.max_attempts
    existing = episode_paths(args.out) if args.out.is_dir() else []
    info = args.out / "collect_info.json"
    try:  # only checks: files of the user's under our names are never replaced, not even with --overwrite
        claim_output(args.out, {info.name: own_json(*INFO_KEYS), **{p.name: own_episode for p in existing}},
                     resume=True, tool=PROG)
    except OutputInUse as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    if (existing or info.exists()) and not args.overwrite:
        what = f"{len(existing)} episode files" if existing else f"a {info.name} of an earlier collection"
        print(f"{PROG}: error: --out {args.out} already holds {what}; pass --overwrite to replace them",
              file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    written, attempts, failures = 0, 0, []
    with PegInHoleEnv(config) as env:
        expert = ScriptedExpert(env, ExpertConfig())
        with tqdm(total=args.episodes, desc="episodes", unit="ep", disable=None) as bar:
            while written < args.episodes and attempts < max_attempts:
                seed = args.seed + attempts
                attempts += 1
                episode, ok = record_episode(env, expert, seed, args.hold_steps)
                if not ok:
                    failures.append(seed)
                    if not args.keep_failures:
                        bar.set_postfix(failed=len(failures))
                        continue
                write_episode(args.out / f"episode_{written}.hdf5", episode, compression=args.compression,
                              overwrite=args.overwrite)
                written += 1
                bar.update(1)
    for old in existing:  # --overwrite: the folder holds exactly the new episodes
        if episode_index(old) >= written:
            old.unlink()
    write_json(info, dict(zip(INFO_KEYS, (written, attempts, failures, dict(vars(config)), vars(ExpertConfig())))))
    if not args.quiet:
        print(f"wrote {written} episodes to {args.out} ({attempts} attempts, {len(failures)} expert failures)")
    if written < args.episodes:
        print(f"{PROG}: error: only {written} of {args.episodes} episodes succeeded within {max_attempts} attempts",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    from controltac_il.cli import guard

    sys.exit(guard(PROG, main, "interrupted (Ctrl-C): the episode files written so far are complete"))
