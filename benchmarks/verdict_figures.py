"""The verdict's tables, rendered from a grid's JSON (``benchmarks.verdict``): the docs block (power, the looks of a
sequential design, success per variant at its validated step, the seed-level comparisons, validation curves,
ForceAugment's targets) and the README's headline rows.

``python -m benchmarks.verdict_figures RUNS.json`` prints a grid's block, running or decided: test tables read
"pending" until a look is complete, and a look's statistics exist only then; ``--look K`` refuses, in one line,
a look whose units are not all tested; ``--pictures`` draws the grid's pictures from the JSON (a grid that goes on
after a look draws them only when it ends).
"""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks import figure_text as ft
from benchmarks.verdict_protocols import sequential_statement
from controltac_il.cli import ArgumentParser

LINK = "[experiments](docs/experiments.md#the-verdict-v2)"
LINK_V3 = "[experiments](docs/experiments.md#the-verdict-v3-confirmatory)"
BENCHMARKS = ("touch_il_verdict_v2", "touch_il_verdict_v3")

PROG = "python -m benchmarks.verdict_figures"


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
                     "verdict"], rows) if rows else "Comparisons: pending (no look complete yet)."


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


def seed_ranges(seeds) -> str:
    """Seeds as runs of consecutive ones: [12, 13, 14, 20] -> "12–14, 20"."""
    runs: list[list[int]] = []
    for s in sorted(set(seeds)):
        if runs and s == runs[-1][1] + 1:
            runs[-1][1] = s
        else:
            runs.append([s, s])
    return ", ".join(f"{a}–{b}" if b > a else str(a) for a, b in runs) or "–"


def cache_table(doc: dict) -> str:
    """Where a grid's augmented policies trained on more than one ForceAugment cache (a machine that rebuilt it):
    per cache digest, the seeds whose tested policy (at the variant's step: its test units, or its training run
    where it is tested at the last step) and whose full training run trained on it. Empty for one cache."""
    digests = doc.get("augment_digests") or []
    if len(digests) < 2:
        return ""
    rows = []
    for v in doc.get("force_augment_counts", {}):
        units = [u for u in doc["units"] if u["variant"] == v]
        runs = [u for u in units if u["kind"] == "train"]
        tested = [u for u in units if u["kind"] == "test"] or [u for u in runs if "test" in u]
        step = doc.get("steps", {}).get(v, {}).get("step")
        rows += [[f"`{d}`", v if step is None else f"{v} (step {step})",
                  seed_ranges(u["seed"] for u in tested if u.get("augment_digest") == d),
                  seed_ranges(u["seed"] for u in runs if u.get("augment_digest") == d)] for d in digests]
    return ft.table(["ForceAugment cache", "variant (tested step)", "seeds whose tested policy trained on it",
                     "seeds whose full-length training run did"], rows) if rows else ""


def block(doc: dict, source: str) -> str:
    """The docs block: power, the looks (a sequential design), success, comparisons, validation curves,
    ForceAugment's targets and caches, the source line."""
    power = doc["protocol"].get("power", {})
    statement = sequential_statement(power) if "mde_80" in power else doc["power_statement"]
    parts = [f"*Power, stated before any result: {statement}.*", looks_table(doc), success_table(doc),
             comparisons_table(doc), validation_table(doc), augment_table(doc), cache_table(doc), source]
    return "\n\n".join(p for p in parts if p)


def looks_table(doc: dict) -> str:
    """A sequential design's looks: seeds, the alpha it rejects below, futility, and the decision once complete."""
    looks = doc["protocol"].get("looks") or []
    done = {lk["look"]: lk for lk in doc.get("looks", [])}
    seeds, rows = doc["protocol"]["train_seeds"], []
    for k, look in enumerate(looks, start=1):
        lk = done.get(k, {"complete": False, "tested_units": 0, "units": _units(doc, look)})
        trained = sum(u["kind"] == "train" and u["seed"] in seeds[:look["seeds"]] for u in doc["units"])
        status = (f"{lk['stop']}: p {lk['p']:.3g}, {lk['diff'] * 100:+.1f} points {ft.ci_points(lk)}"
                  if lk["complete"] else
                  f"pending: {trained} of {lk['units']} units trained, {lk['tested_units']} tested at their step")
        rows.append([k, look["seeds"], f"p < {look['alpha']:g}", "mean <= 0 stops" if look["futility"] else "–", status])
    return ft.table(["look", "paired seeds", "rejects at", "futility", "decision"], rows) if rows else ""


def _units(doc: dict, look: dict) -> int:
    """How many (variant, seed) units a look analyses."""
    return len(doc["protocol"]["variants"]) * look["seeds"]


def _augmentation(protocol: dict, variant: str) -> str:
    """``2 copies, the paper's offsets`` or ``2 copies, targets over 1–10 N``: what a ForceAugment variant draws."""
    span = protocol["force_settings"].get(variant, {}).get("target_range")
    return f"{protocol['copies'][variant]} copies, " + (f"targets over {span[0]:g}–{span[1]:g} N" if span
                                                         else "the paper's offsets")


def headline_rows(doc: dict, source: str) -> list[list[str]]:
    """One README row per primary variant: its paired differences in every setting, their intervals and verdicts."""
    protocol = doc["protocol"]
    seeds, rows = len(protocol["train_seeds"]), []
    primaries = sum(bool(c["primary"]) for c in doc["comparisons"])
    for v in dict.fromkeys(c["variant"] for c in doc["comparisons"] if c["primary"]):
        cs = [c for c in doc["comparisons"] if c["variant"] == v]
        where = " / ".join(setting_label(doc, c["setting"]) for c in cs)
        rows.append([f"the verdict (v2, exploratory): ACT with ForceAugment `{v}` ({_augmentation(protocol, v)}) "
                     "vs ACT on the real demos, "
                     f"{seeds} paired training seeds",
                     " / ".join(f"{c['diff'] * 100:+.1f}" for c in cs) + f" points ({where}): "
                     + " / ".join(f"**{c['verdict'] or 'pending'}**" for c in cs),
                     " / ".join(ft.ci_points(c) for c in cs)
                     + f" (95 % CI, each alone); Holm p over the {primaries} primary comparisons "
                     + " / ".join(f"{c['p_holm']:.2g}" if c["p_holm"] is not None else "–"
                                                          for c in cs), LINK, source])
    return rows


def headline_rows_v3(doc: dict, source: str) -> list[list[str]]:
    """The README row of the confirmatory verdict: its primary comparison at the look where the design stopped."""
    stopped = [lk for lk in doc.get("looks", []) if lk.get("complete") and lk["stop"] != "continue"]
    variant, setting = doc["protocol"]["primary"][0]
    what = (f"the verdict (v3, confirmatory): ACT with ForceAugment `{variant}` "
            f"({_augmentation(doc['protocol'], variant)}) vs ACT on the real demos, {setting_label(doc, setting)}, "
            "fresh seeds")
    if not stopped:
        went_on = [lk["look"] for lk in doc.get("looks", []) if lk.get("complete")]
        status = (f"running: look {went_on[-1]} continued to look {went_on[-1] + 1} (no stop at its boundary)"
                  if went_on else "running: no look complete yet")
        return [[what, status, "–", LINK_V3, source]]
    lk = stopped[-1]
    return [[f"{what}, {len(lk['seeds'])} paired (look {lk['look']})",
             f"{lk['diff'] * 100:+.1f} points: **{lk['verdict']}**",
             f"{ft.ci_points(lk)} (95 % CI); sign-flip p {lk['p']:.3g} against {lk['alpha']:g} ({lk['stop']})",
             LINK_V3, source]]


def main(argv=None) -> int:
    p = ArgumentParser(prog=PROG, description="Print the verdict's docs block and README rows from a grid's --out JSON, "
                       "running or decided (python -m benchmarks.verdict).")
    p.add_argument("json", type=Path, help="the grid's --out JSON")
    p.add_argument("--look", type=int, default=None, help="print look K's decision; refused until its units are tested")
    p.add_argument("--pictures", action="store_true",
                   help="draw the pictures beside the JSON instead, as the grid draws them when it ends: success per "
                        "variant (JSON.png) and each complete look's seed-paired differences (JSON_paired.png)")
    args = p.parse_args(argv)
    doc = json.loads(args.json.read_text())
    if not isinstance(doc, dict) or doc.get("benchmark") not in BENCHMARKS:
        raise ValueError(f"{args.json}: not the JSON of python -m benchmarks.verdict")
    if args.pictures:
        drawn = pictures(doc, args.json)
        print("\n".join(f"wrote {path}" for path in drawn) or "no picture yet: no look is complete")
        return 0
    if args.look is not None:
        return _show_look(p, doc, args.look)
    try:
        show(doc, args.json)
    except (KeyError, TypeError, IndexError) as exc:
        raise ValueError(f"{args.json}: incomplete or malformed ({type(exc).__name__}: {exc})") from None
    return 0


def pictures(doc: dict, path: Path) -> list[Path]:
    """The grid's pictures from its JSON (``verdict_report.plot``, ``plot_paired``), for a grid that goes on after
    a complete look; none before its first look is complete."""
    from benchmarks.verdict_report import plot, plot_paired

    if not doc.get("table"):
        return []
    protocol, out = doc["protocol"], [path.with_suffix(".png")]
    plot(doc["table"], out[0], list(protocol["variants"]), list(protocol["settings"]))
    if protocol.get("looks"):
        out.append(path.with_name(path.stem + "_paired.png"))
        plot_paired(doc["looks"], doc["comparisons"], out[1])
    return out


def _show_look(p, doc: dict, k: int) -> int:
    """Print look ``k``'s decision, or refuse it (one line naming --look) while its units are not all tested."""
    looks = doc["protocol"].get("looks") or []
    if not 1 <= k <= len(looks):
        p.error(f"--look: the protocol has {len(looks)} looks, got {k}")
    lk = next((x for x in doc.get("looks", []) if x["look"] == k), None)
    if lk is None or not lk["complete"]:
        n = 0 if lk is None else lk["tested_units"]
        p.error(f"--look: look {k} is analysed once its {_units(doc, looks[k - 1])} units are tested; {n} are")
    print(f"look {k} ({len(lk['seeds'])} paired seeds): {lk['sentence']}")
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
    rows = headline_rows_v3(doc, str(path)) if doc["benchmark"].endswith("v3") else headline_rows(doc, str(path))
    print("\n" + ft.table(["what", "measured", "error or interval", "details", "source"], rows))


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, main))
