"""The verdict v2's tables (issue 38), rendered from its JSON: the docs block (power, success per variant at its
validated step, the seed-level comparisons, validation curves, ForceAugment's targets) and the README's headline
rows. ``python -m benchmarks.verdict_figures RUNS.json`` prints the block of a grid still running (its test
tables read "pending" until the first test unit is in).
"""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks import figure_text as ft
from controltac_il.cli import ArgumentParser

LINK = "[experiments](docs/experiments.md#the-verdict-v2)"


def points(c: dict) -> str:
    """A paired difference and its interval, in points."""
    return f"{c['diff'] * 100:+.1f} {ft.ci_points(c)}"


def setting_label(doc: dict, setting: str) -> str:
    """``nominal (4–7 N)``; the stress test named as such."""
    lo, hi = doc["protocol"]["settings"][setting]
    stress = ", stress test" if setting == doc["protocol"]["stress_test"] else ""
    return f"{setting} ({lo:g}–{hi:g} N{stress})"


def success_table(doc: dict) -> str:
    """Test success per variant (rows) and setting (columns) over the seeds, at each variant's chosen step."""
    settings, steps = list(doc["protocol"]["settings"]), doc.get("steps", {})
    by = {(r["variant"], r["setting"]): r for r in doc["table"]}

    def cell(r: dict | None) -> str:
        if r is None:
            return "pending"
        below = r["below_real_worst"]
        k = "" if below is None else f", {round(below * len(r['per_seed']))}/{len(r['per_seed'])} below real's worst"
        lo, hi = (ft.pct(x) for x in r["ci95"])
        return f"{ft.pct(r['mean'])} % [{lo}, {hi}], SD {ft.pct(r['sd_over_seeds'])}{k}"

    rows = [[v, steps[v]["step"] if v in steps else "pending", *(cell(by.get((v, st))) for st in settings)]
            for v in doc["protocol"]["variants"]]
    return ft.table(["variant", "step", *(setting_label(doc, st) for st in settings)], rows)


def comparisons_table(doc: dict) -> str:
    """Every comparison with real, the primary ones (Holm, a verdict) first."""
    comps = sorted(doc["comparisons"], key=lambda c: not c["primary"])
    rows = [[f"{c['variant']} vs real", setting_label(doc, c["setting"]), points(c), f"{c['p_sign_flip']:.3g}",
             f"{c['p_t']:.3g}", f"{c['p_holm']:.3g}" if c["p_holm"] is not None else "–",
             f"**{c['verdict']}**" if c["verdict"] else ("secondary" if not c["primary"] else "pending")] for c in comps]
    return ft.table(["comparison", "setting", "points [95 % CI]", "p sign-flip (seeds)", "p paired t", "p Holm",
                     "verdict"], rows) if rows else "Comparisons: pending (no test unit yet)."


def validation_table(doc: dict) -> str:
    """Mean validation success over the seeds per snapshot; the chosen step in bold."""
    snaps = doc["protocol"]["recipe"]["snapshots"]
    rows = []
    for v, s in doc.get("steps", {}).items():
        means = {k: ft.pct(s["curve"][str(k)]["mean"]) for k in snaps}
        rows.append([v, *(f"**{means[k]}**" if k == s["step"] else means[k] for k in snaps)])
    return ft.table(["validation success, %", *(f"step {k}" for k in snaps)], rows) if rows else ""


def augment_table(doc: dict) -> str:
    """Each ForceAugment variant's clamped share of contact frames and its requested target Fz."""
    rows = [[v, f"{c['clamped_fraction_of_contact'] * 100:.1f} %",
             " / ".join(f"{q:.1f}" for q in c["requested_fz_quantiles"]), c["regenerated"]]
            for v, c in doc.get("force_augment_counts", {}).items()]
    return ft.table(["variant", "clamped (of contact frames)", "requested Fz, 5 / 50 / 95 % (N)",
                     "frames regenerated"], rows)


def block(doc: dict, source: str) -> str:
    """The docs block: power, success, comparisons, validation curves, ForceAugment's targets, the source line."""
    parts = [f"*Power, stated before any result: {doc['power_statement']}.*", success_table(doc),
             comparisons_table(doc), validation_table(doc), augment_table(doc), source]
    return "\n\n".join(p for p in parts if p)


def headline_rows(doc: dict, source: str) -> list[list[str]]:
    """One README row per primary variant: its paired differences in every setting, their intervals and verdicts."""
    protocol = doc["protocol"]
    seeds, rows = len(protocol["train_seeds"]), []
    for v in dict.fromkeys(c["variant"] for c in doc["comparisons"] if c["primary"]):
        cs = [c for c in doc["comparisons"] if c["variant"] == v]
        where = " / ".join(setting_label(doc, c["setting"]) for c in cs)
        span = protocol["force_settings"].get(v, {}).get("target_range")
        what = f"{protocol['copies'][v]} copies, " + (f"targets over {span[0]:g}–{span[1]:g} N" if span
                                                      else "the paper's offsets")
        rows.append([f"the verdict (v2): ACT with ForceAugment `{v}` ({what}) vs ACT on the real demos, "
                     f"{seeds} paired training seeds",
                     " / ".join(f"{c['diff'] * 100:+.1f}" for c in cs) + f" points ({where}): "
                     + " / ".join(f"**{c['verdict'] or 'pending'}**" for c in cs),
                     " / ".join(ft.ci_points(c) for c in cs)
                     + " (95 % CI); Holm p " + " / ".join(f"{c['p_holm']:.2g}" if c["p_holm"] is not None else "–"
                                                          for c in cs), LINK, source])
    return rows


def main(argv=None) -> int:
    p = ArgumentParser(description="Print the verdict v2's docs block and README rows from a (running) "
                       "grid's --out JSON.")
    p.add_argument("json", type=Path, help="the grid's --out JSON")
    args = p.parse_args(argv)
    doc = json.loads(args.json.read_text())
    if not isinstance(doc, dict) or doc.get("benchmark") != "touch_il_verdict_v2":
        raise ValueError(f"{args.json}: not the JSON of python -m benchmarks.touch_il_verdict_v2")
    try:
        show(doc, args.json)
    except (KeyError, TypeError, IndexError) as exc:
        raise ValueError(f"{args.json}: incomplete or malformed ({type(exc).__name__}: {exc})") from None
    return 0


def show(doc: dict, path: Path) -> None:
    """Print the block and the README rows of ``doc``; steps by the protocol's rule where the grid has none yet."""
    from benchmarks.verdict import choose_step

    train = [u for u in doc["units"] if u["kind"] == "train"]
    note = f"{len(train)} train and {len(doc['units']) - len(train)} test units done"
    if "steps" not in doc:  # the rule applied to the seeds trained so far
        snaps = doc["protocol"]["recipe"]["snapshots"]
        doc["steps"] = {v: choose_step([u for u in train if u["variant"] == v], snaps)
                        for v in doc["protocol"]["variants"] if any(u["variant"] == v for u in train)}
        note += "; steps provisional: not every seed is trained"
    print(block(doc, f"*{path}: {note}.*"))
    print("\n" + ft.table(["what", "measured", "error or interval", "details", "source"], headline_rows(doc, str(path))))


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard("python -m benchmarks.verdict_figures", main))
