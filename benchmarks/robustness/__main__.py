"""``python -m benchmarks.robustness --out FILE.json [--only SURFACE] [--faults]``: run the probes, write the verdict
table (per probe: verdict, detail and, for a command, its exit code and whether it reported on one line)."""

from __future__ import annotations

import tempfile
import time
from collections import Counter
from pathlib import Path

from tqdm import tqdm

from benchmarks.common import base_parser, print_table, write_results
from benchmarks.robustness import probes_faults, probes_hardware, probes_models, probes_training  # noqa: F401
from benchmarks.robustness.harness import PROBES, UNCLEAR, VERDICTS

PROG = "python -m benchmarks.robustness"


def run_probe(pr) -> dict:
    """One probe in a fresh folder: its row (surface, probe, verdict, detail, seconds; for a command, its exit
    code and whether it reported on one line)."""
    t = time.perf_counter()
    extra: dict = {}
    with tempfile.TemporaryDirectory(prefix="probe-") as tmp:
        try:
            verdict, detail, *more = pr.run(Path(tmp))
            extra = more[0] if more else {}
        except Exception as exc:  # the probe itself failed: that is an unclear surface, not a crash of the table
            verdict, detail = UNCLEAR, f"probe raised {type(exc).__name__}: {exc}"[:240]
    return {"surface": pr.surface, "probe": pr.name, "kind": "fault" if pr.fault else "input", "verdict": verdict,
            "detail": detail,
            "exit_code": extra.get("exit_code"), "one_line": extra.get("one_line"),
            "seconds": round(time.perf_counter() - t, 2)}


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.split(":", 1)[1].strip())
    p.add_argument("--only", default=None, help="run only the probes of surfaces whose name contains this")
    p.add_argument("--faults", action="store_true", help="run only the runtime-fault probes of the CLIs")
    args = p.parse_args(argv)
    probes = [pr for pr in PROBES if (args.only is None or args.only in pr.surface)
              and (not args.faults or pr.fault)]
    rows = [run_probe(pr) for pr in tqdm(probes, desc="probes", dynamic_ncols=True, disable=None)]
    counts = Counter(r["verdict"] for r in rows)
    results = {"benchmark": "robustness", "probes": len(rows), "counts": {v: counts.get(v, 0) for v in VERDICTS},
               "rows": rows}
    print_table(rows, ["surface", "probe", "verdict", "exit_code", "one_line", "detail"], title="robustness probes")
    print("verdicts: " + ", ".join(f"{v} {n}" for v, n in results["counts"].items()))
    if args.out:
        write_results(args.out, results)
    return results


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
