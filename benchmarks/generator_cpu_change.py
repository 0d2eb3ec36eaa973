"""The generator on the CPU before and after a change of its code: speed interleaved in one run, and its bytes.

    python -m benchmarks.generator_cpu_change --baseline DIR --out FILE.json [--rounds 3] [--threads 2]

DIR holds the earlier code (``git archive REV controltac_il benchmarks | tar -x -C DIR``; its checkpoints folder
may be left out, the shipped checkpoints are then linked from this tree, unchanged weights assumed and checked by
hash). Each round runs ``benchmarks.generator_speed`` for one round in a fresh process of each tree, their order
alternating round to round, so that a drift of the machine's speed falls on both; reported per (checkpoint,
frames, steps): the median img/s at batch 32 over rounds for each tree, each round's figure, and after ÷ before.
Then both trees generate the same frames (the speed benchmark's presses, ΔF +1 and +3 N, seed 0) and their
outputs are compared byte for byte: the largest and the mean grey-level difference and the share of values that
differ.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.common import base_parser, print_table, write_results
from benchmarks.generator_frontier import b32
from controltac_il.generator.shipped import CHECKPOINT_ROOT

HERE = Path(__file__).resolve().parents[1]
EXTRA = {"before": [], "after": ["--pairs", "0"]}  # the speed alone: no error pairs (flags the earlier code lacks)
# the bytes check, run in either tree: the same frames and forces through each tree's generator
OUTPUTS = """
import sys, numpy as np, torch
from benchmarks.generator_speed import frames
from controltac_il.generator import ForceGenerator
torch.set_num_threads(int(sys.argv[2]))
out = {}
for name in sys.argv[3:]:
    gen = ForceGenerator.from_pretrained(name)
    for size, hw in (("240", (240, 320)), ("120", (120, 160))):
        refs, delta = frames(hw, 32)
        out[f"{name}_{size}_{gen.checkpoint_hash}"] = gen.generate(refs, delta * np.float32([1, 1, 3]), seed=0)
np.savez(sys.argv[1], **out)
"""

PROG = "python -m benchmarks.generator_cpu_change"


def _run(tree: Path, args: list[str]) -> None:
    """``python args`` in ``tree``, its code first on the path; one line naming the tree if it fails."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, *args], cwd=tree, env=env, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"{tree}: {' '.join(args[:3])} failed: {done.stderr.strip().splitlines()[-1:]}")


def speed_round(tree: Path, a, out: Path, extra: list[str]) -> dict:
    """{(checkpoint, frames, steps): img/s} of one round of ``benchmarks.generator_speed`` in ``tree`` (``extra``:
    flags only that tree's benchmark knows)."""
    _run(tree, ["-m", "benchmarks.generator_speed", "--checkpoints", *a.checkpoints, "--threads", str(a.threads),
                "--rounds", "1", "--repeats", str(a.repeats), "--out", str(out), *extra])
    rows = json.loads(out.read_text())["rows"]
    return {(r["checkpoint"], r["frames"], r["steps"]): r.get("img_per_s", r.get("img_per_s_b32")) for r in rows
            if b32(r)}


def byte_change(trees: dict, a, tmp: Path) -> list[dict]:
    """Per output array (checkpoint, frames): max and mean |after - before| in grey levels, share that differ."""
    outs = {}
    for name, tree in trees.items():
        _run(tree, ["-c", OUTPUTS, str(tmp / f"{name}.npz"), str(a.threads), *a.checkpoints])
        outs[name] = np.load(tmp / f"{name}.npz")
    rows = []
    for key in outs["before"].files:
        if key not in outs["after"].files:
            raise RuntimeError(f"{key}: the trees' checkpoints differ (hash in the key)")
        d = np.abs(outs["after"][key].astype(np.int16) - outs["before"][key])
        rows.append({"output": key.rsplit("_", 1)[0], "values": int(d.size), "max_diff": int(d.max()),
                     "mean_diff": float(d.mean()), "share_differing": float(np.mean(d > 0))})
    return rows


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.splitlines()[0])
    p.add_argument("--baseline", type=Path, required=True, help="folder holding the earlier code (module docstring)")
    p.add_argument("--checkpoints", nargs="+", default=["fast", "default", "quality"], help="default: the presets")
    p.add_argument("--threads", type=int, default=2, help="torch threads (default 2, the target machine's)")
    p.add_argument("--rounds", type=int, default=3, help="rounds, each timing both trees (default 3)")
    p.add_argument("--repeats", type=int, default=5, help="timed calls per setting and round (default 5)")
    a = p.parse_args(argv)
    base = a.baseline.resolve()
    linked = base / "controltac_il/generator/checkpoints"
    if not linked.exists():
        linked.symlink_to(CHECKPOINT_ROOT)
    trees = {"before": base, "after": HERE}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        rounds = []
        for r in range(a.rounds):
            order = list(trees) if r % 2 == 0 else list(trees)[::-1]
            rounds.append({name: speed_round(trees[name], a, tmp / f"{name}{r}.json", EXTRA[name]) for name in order})
        bytes_rows = byte_change(trees, a, tmp)
    rows = []
    for key in rounds[0]["before"]:
        before, after = ([r[t][key] for r in rounds] for t in ("before", "after"))
        rows.append({"checkpoint": key[0], "frames": key[1], "steps": key[2], "before_img_per_s": float(np.median(before)),
                     "after_img_per_s": float(np.median(after)), "before_rounds": before, "after_rounds": after,
                     "after_over_before": float(np.median(after) / np.median(before))})
    print_table(rows, ["checkpoint", "frames", "steps", "before_img_per_s", "after_img_per_s", "after_over_before"],
                title=f"generator on {a.threads} CPU threads, before and after")
    print_table(bytes_rows, list(bytes_rows[0]), title="output bytes, after against before")
    return write_results(a.out, {"settings": {"baseline": str(a.baseline), "threads": a.threads, "rounds": a.rounds,
                                              "repeats": a.repeats, "checkpoints": a.checkpoints, "batch": 32},
                                 "speed": rows, "bytes": bytes_rows})


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
