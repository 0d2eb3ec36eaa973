"""Scripted peg-in-hole demos from the MuJoCo scene, collected once and reused from the cache."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import envs
from controltac_il.io import atomic_dir, cache_root
from controltac_il.tactile import optics, sensor
from envs import collect
from envs.config import DEMO_EPISODES


def scene_fingerprint() -> str:
    """Short hash of everything that shapes a recorded demo: the scene's MJCF, its code and the expert."""
    h = hashlib.sha1()
    root = Path(envs.__file__).resolve().parent
    for path in sorted([*root.glob("*.py"), *root.glob("assets/*")]):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    for module in (optics, sensor):
        h.update(Path(module.__file__).read_bytes())
    return h.hexdigest()[:10]


def default_demos(episodes: int = DEMO_EPISODES, seed: int = 0, root: str | Path | None = None, scene: str = "default") -> Path:
    """Folder of ``episodes`` scripted-expert peg-in-hole demos (collected once, then reused).

    scene: "default" or "touch_critical" (``envs.config.SCENES``). The cache folder is keyed by the
    scene's fingerprint, so demos recorded by an older scene are never reused. Written atomically: an
    interrupted collection leaves no half folder behind.
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    prefix = "peg_in_hole" if scene == "default" else f"peg_in_hole_{scene}"
    name = f"{prefix}-n{episodes}-seed{seed}-{scene_fingerprint()}"
    folder = Path(root) if root is not None else cache_root() / "demos" / name
    info = folder / "collect_info.json"
    if info.is_file():
        try:
            if json.loads(info.read_text()).get("episodes") == episodes:
                return folder
        except (OSError, json.JSONDecodeError):
            pass
    with atomic_dir(folder) as tmp:
        code = collect.main(["--episodes", str(episodes), "--out", str(tmp), "--seed", str(seed), "--scene", scene,
                             "--quiet"])
        if code != 0:
            raise RuntimeError(f"demo collection failed (exit code {code}); see the messages above")
    done = json.loads(info.read_text())
    print(f"collected {done['episodes']} scripted demos in {folder} ({done['attempts']} attempts, "
          f"{len(done['failed_seeds'])} expert failures)")
    return folder
