"""Peg-in-hole scene benchmark: step rate and real-time factor per rendering setting, per-part render
costs, and the scripted expert's success rate.

    python -m benchmarks.env --out env.json            # 3 timed episodes per setting, 50 expert seeds
    python -m benchmarks.env --quick                   # 1 timed episode per setting, 10 seeds

Step times are measured over scripted-expert episodes (free motion and contact both count); the
real-time factor is the control period (0.1 s) over the median step time. Wall time depends on
what else runs on the machine, so the process CPU time per step is reported beside it.
Targets: >= 5x real time with both cameras at 96x128 and both tactile sensors at 120x160;
expert success >= 95 % over 50 seeds.
"""

from __future__ import annotations

import os
import statistics
import time

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import mujoco  # noqa: E402
from tqdm import tqdm  # noqa: E402

from benchmarks.common import base_parser, median_time, print_table, quartiles, write_results  # noqa: E402
from envs.config import CAMERAS, PegInHoleConfig  # noqa: E402
from envs.expert import ScriptedExpert  # noqa: E402
from envs.peg_in_hole import PegInHoleEnv  # noqa: E402

SETTINGS = {
    "physics only": dict(cameras=(), tactile=False),
    "2 cameras 96x128": dict(cameras=CAMERAS, tactile=False),
    "2 tactile 120x160": dict(cameras=(), tactile=True),
    "2 cameras + 2 tactile": dict(cameras=CAMERAS, tactile=True),
}

PROG = "python -m benchmarks.env"


def time_steps(config: PegInHoleConfig, seeds: list[int]) -> dict:
    """Median wall and CPU ms per control step over expert episodes."""
    wall, cpu = [], []
    with PegInHoleEnv(config) as env:
        expert = ScriptedExpert(env)
        for seed in seeds:
            env.reset(seed=seed)
            expert.reset(seed)
            for _ in range(config.max_steps):
                action = expert.act()
                t0, c0 = time.perf_counter(), time.process_time()
                _, _, terminated, truncated, _ = env.step(action)
                wall.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
                if terminated or truncated:
                    break
    period = 1.0 / config.control_hz
    w, c = statistics.median(wall), statistics.median(cpu)
    return {"steps": len(wall), "ms_per_step": w * 1e3, "ms_quartiles": [q * 1e3 for q in quartiles(wall)],
            "cpu_ms_per_step": c * 1e3, "steps_per_s": 1.0 / w,
            "realtime_factor": period / w, "realtime_factor_cpu": period / c}


def time_parts(repeats: int) -> list[dict]:
    """Median cost of each part of a step, measured while the peg is held (tactile in contact)."""
    config = PegInHoleConfig()
    rows = []
    with PegInHoleEnv(config) as env:
        expert = ScriptedExpert(env)
        env.reset(seed=0)
        expert.reset(0)
        while expert.phase != "carry":
            env.step(expert.act())
        m, d = env.model, env.data
        state = mujoco.MjData(m)
        mujoco.mj_copyData(state, m, d)

        def physics():
            mujoco.mj_copyData(d, m, state)
            for _ in range(config.substeps):
                mujoco.mj_step(m, d)

        parts = [
            (f"physics ({config.substeps} substeps)", physics),
            ("camera third_view 96x128", lambda: env.render_camera("third_view")),
            ("camera wrist 96x128", lambda: env.render_camera("wrist")),
            ("tactile rays (1 pad)", lambda: env.penetration_mm("left")),
            ("tactile optics (1 pad)", lambda: env.tactile_sensor("left").render_penetration(
                env.penetration_mm("left"), shear=(0.1, -0.2), noise_seed=1)),
            ("tactile total (1 pad)", lambda: env.render_tactile("left")),
            ("pad forces (2 pads)", env.pad_forces),
        ]
        for name, fn in parts:
            rows.append({"part": name, "ms": median_time(fn, repeats=repeats, warmup=2) * 1e3})
        mujoco.mj_copyData(d, m, state)
    return rows


def expert_success(seeds: list[int], hole_diameter_mm: float) -> dict:
    """Scripted expert success over ``seeds`` (physics only; rendering does not change the physics)."""
    config = PegInHoleConfig(cameras=(), tactile=False, hole_diameter_mm=hole_diameter_mm)
    failures, lengths = [], []
    with PegInHoleEnv(config) as env:
        expert = ScriptedExpert(env)
        for seed in tqdm(seeds, desc=f"expert Ø{hole_diameter_mm:g} mm", unit="ep", disable=None):
            env.reset(seed=seed)
            expert.reset(seed)
            for t in range(config.max_steps):
                _, _, terminated, truncated, info = env.step(expert.act())
                if terminated or truncated:
                    break
            if info["success"]:
                lengths.append(t + 1)
            else:
                failures.append(seed)
    n = len(seeds)
    return {"hole_diameter_mm": hole_diameter_mm, "episodes": n, "successes": n - len(failures),
            "success_rate": (n - len(failures)) / n, "failed_seeds": failures,
            "median_steps_to_success": statistics.median(lengths) if lengths else None}


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=None, help="expert episodes for the success rate (default 50, quick 10)")
    p.add_argument("--tight", action="store_true", help="also measure the expert on a tight Ø27 mm hole")
    args = p.parse_args(argv)
    if args.seeds is not None and args.seeds < 1:
        p.error(f"--seeds must be an int >= 1 (expert episodes), got {args.seeds}")
    n_seeds = args.seeds or (10 if args.quick else 50)
    timed = [0] if args.quick else [0, 1, 2]
    repeats = 5 if args.quick else 15

    rows = []
    for name, kwargs in tqdm(SETTINGS.items(), desc="step timing", unit="setting", disable=None):
        rows.append({"setting": name, **time_steps(PegInHoleConfig(**kwargs), timed)})
    parts = time_parts(repeats)
    success = [expert_success(list(range(n_seeds)), 30.0)]
    if args.tight:
        success.append(expert_success(list(range(n_seeds)), 27.0))

    print_table(rows, ["setting", "steps", "ms_per_step", "cpu_ms_per_step", "steps_per_s", "realtime_factor",
                       "realtime_factor_cpu"], title="Control step (10 Hz, 500 Hz physics), medians over expert episodes")
    print_table(parts, ["part", "ms"], title="Parts of a step (medians, peg held)")
    print_table(success, ["hole_diameter_mm", "episodes", "successes", "success_rate", "median_steps_to_success"],
                title="Scripted expert")
    load = os.getloadavg()
    print(f"\nload average during the run: {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} on {os.cpu_count()} cores")
    return write_results(args.out, {
        "benchmark": "env", "quick": args.quick, "load_average": list(load),
        "step_timing": rows, "parts": parts, "expert": success,
        "targets": {"realtime_factor_full": 5.0, "expert_success_rate": 0.95},
    })


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
