"""``python -m benchmarks.robustness --out FILE.json [--only SURFACE]``: run the probes, write the verdict table."""

from __future__ import annotations

import tempfile
import time
from collections import Counter
from pathlib import Path

from tqdm import tqdm

from benchmarks.common import base_parser, print_table, write_results
from benchmarks.robustness import probes_hardware, probes_models, probes_training  # noqa: F401 - register
from benchmarks.robustness.harness import PROBES, UNCLEAR, VERDICTS


def main(argv=None) -> dict:
    p = base_parser(__doc__.split(":", 1)[1].strip())
    p.add_argument("--only", default=None, help="run only the probes of surfaces whose name contains this")
    args = p.parse_args(argv)
    probes = [pr for pr in PROBES if args.only is None or args.only in pr.surface]
    rows = []
    for pr in tqdm(probes, desc="probes", dynamic_ncols=True):
        t = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix="probe-") as tmp:
            try:
                verdict, detail = pr.run(Path(tmp))
            except Exception as exc:  # the probe itself failed: that is an unclear surface, not a crash of the table
                verdict, detail = UNCLEAR, f"probe raised {type(exc).__name__}: {exc}"[:240]
        rows.append({"surface": pr.surface, "probe": pr.name, "verdict": verdict, "detail": detail,
                     "seconds": round(time.perf_counter() - t, 2)})
    counts = Counter(r["verdict"] for r in rows)
    results = {"benchmark": "robustness", "probes": len(rows), "counts": {v: counts.get(v, 0) for v in VERDICTS},
               "rows": rows}
    print_table(rows, ["surface", "probe", "verdict", "detail"], title="robustness probes")
    print("verdicts: " + ", ".join(f"{v} {n}" for v, n in results["counts"].items()))
    if args.out:
        write_results(args.out, results)
    return results


if __name__ == "__main__":
    main()
