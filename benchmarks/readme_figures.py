"""The README's and the docs pages' result tables, rendered from the committed JSONs in ``benchmarks/results/``.

``python -m benchmarks.readme_figures`` rewrites every block between ``<!-- figures:NAME -->`` and
``<!-- /figures:NAME -->`` in README.md, every page docs/*.md and benchmarks/results/README.md (``DOCS``) with
what ``BLOCKS[NAME]`` renders from the JSON(s) behind it; ``--check`` changes nothing and exits 1 naming each
block that differs, and each model card whose ``benchmark`` figures differ from the JSON of the same run
(``tests/test_readme_figures.py``). Each block appears once, in one of those files; the render functions of the
docs pages' own blocks and of the README's headline table are in ``benchmarks.docs_figures``;
the pieces all blocks share (table, provenance line) in ``benchmarks.figure_text``.

Each block ends with a line naming its file, commit, date and generator; it reads *History (not reproducible
from committed files)* when the file was measured on a dirty tree (``-dirty`` commit) or with a generator
other than the shipped default, so a clean re-run with the shipped models lifts the mark by itself.
"""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Callable
from statistics import mean

from controltac_il.cli import ArgumentParser
from controltac_il.generator.shipped import FRONTIER_SIZES, SHIPPED
from controltac_il.io import atomic_path

from benchmarks import docs_figures, generator_fa_figures
from benchmarks.figure_text import (RESULTS, ROOT, SHIPPED_GENERATOR, ci_points, load, pct, provenance,
                                    recorded_generator, table)

DOCS = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), RESULTS / "README.md")  # every page with blocks
HISTORY_KEYS = ("source", "history", "history_note")  # added to a card's figures, not measured
MARKER = re.compile(r"<!-- (/?)figures:([A-Za-z0-9_-]+) -->")

PROG = "python -m benchmarks.readme_figures"


def ms(s: dict) -> str:
    return f"{s['mse']:.1f} ± {s['mse_sd']:.1f}"


def wilson(k: int, n: int, interval: list) -> str:
    return f"{k}/{n} [{pct(interval[0])}, {pct(interval[1])}]"


def span(values, fmt: str = ".2f") -> str:
    lo, hi = format(min(values), fmt), format(max(values), fmt)
    return lo if lo == hi else f"{lo}–{hi}"


# -- generator (benchmarks.generator) ---------------------------------------------------------------

def _generator_hash(doc: dict) -> str:
    return doc["settings"]["checkpoints"]["default"]["hash"]


def generator() -> str:
    doc = load("generator.json")
    m = {x["method"]: x for x in doc["methods"]}
    rows = []
    for label, method in (("reference copy", "reference copy"), ("physics re-render", "physics re-render"),
                          ("*bound: target through 128×160*", "target through the model size"),
                          ("**default**", "default DDIM-1"), ("default DDIM-5", "default DDIM-5"),
                          ("default DDIM-50", "default DDIM-50"), ("fast", "fast DDIM-1")):
        r = m[method]
        rb = r["unseen_240"]
        speed = [f"{r[k]:.1f}" if r.get(k) is not None and r["kind"] not in ("copy", "roundtrip") else "–"
                 for k in ("img_per_s_b32", "img_per_s_b32_240")]
        rows.append([label, ms(r["seen"]), ms(r["unseen"]), f"{r['unseen']['ssim']:.3f}", ms(rb), f"{rb['ssim']:.3f}",
                     ms(r["unseen_sensor"]), f"{rb['readback_fz_mae']:.2f} ({rb['true_readback_fz_mae']:.2f})",
                     f"{r['unseen']['bare_noise_ratio']:.2f}", *speed])
    header = ["method", "seen MSE", "unseen MSE", "unseen SSIM", "unseen 240 MSE", "unseen 240 SSIM",
              "unseen sensor MSE", "unseen 240 read-back (N)", "noise", "img/s b32", "img/s b32 at 240"]
    return table(header, rows) + "\n\n" + provenance("generator.json", doc, _generator_hash(doc))


def generator_ratios() -> str:
    doc = load("generator.json")
    m, t = {x["method"]: x for x in doc["methods"]}, doc["targets"]
    seen = m["default DDIM-1"]["seen"]["mse"] / m["reference copy"]["seen"]["mse"]
    rows = [["MSE × a reference copy's", f"{seen:.3f}", f"{t['unseen_mse_ratio_to_copy']:.3f}",
             f"{t['unseen_240_mse_ratio_to_copy']:.3f}", f"{t['unseen_sensor_mse_ratio_to_copy']:.3f}"],
            ["force read-back error × the true frames'", f"{t['seen_readback_ratio_to_true']:.2f}",
             f"{t['unseen_readback_ratio_to_true']:.2f}", f"{t['unseen_240_readback_ratio_to_true']:.2f}", "–"]]
    return (table(["default (DDIM-1)", "seen", "unseen", "unseen 240", "unseen sensor"], rows) + "\n\n"
            + provenance("generator.json", doc, _generator_hash(doc)))


def response() -> str:
    doc = load("response.json")
    refs = doc["references"]
    rows = []
    for k in ("bead", "key", "seed"):
        r = refs[f"real/{k}"]
        rows.append([f"real {k}", f"{r['max_drop_pp']:.2f}" if r["max_drop_pp"] else "0",
                     f"{r['growth_pp']:.2f}", f"{r['detail_kept']:.2f}"])
    for group, size in (("sim120", "120×160"), ("sim240", "240×320")):
        rs = [r for key, r in refs.items() if key.startswith(group + "/")]
        fall = span([r["max_drop_pp"] for r in rs])
        kept = [r["detail_kept"] for r in rs if r["detail_kept"] is not None]
        growth = span([r["growth_pp"] for r in rs], ".1f")
        rows.append([f"sensor model, {len(rs)} objects, {size}", f"0 on all {len(rs)}" if fall == "0.00" else fall,
                     "0–" + growth.removeprefix("0.0–") if growth.startswith("0.0–") else growth,
                     span(kept) if kept else "–"])
    header = ["reference", "largest fall (pp)", "growth 0 → +8 N (pp)", "fine detail kept at +2 N"]
    return table(header, rows) + "\n\n" + provenance("response.json", doc, doc["generator_hash"])


# -- stage 2 (benchmarks.pose) ----------------------------------------------------------------------

def _pose_source(doc: dict) -> str:
    return provenance("pose.json", doc, doc["stage1_hash"], f", adapter `{doc['adapter']}`")


def _mse_ssim(r: dict) -> str:
    return f"{r['mse']:.1f} ({r['ssim']:.3f})"


def pose() -> str:
    doc = load("pose.json")
    rows = []
    for split in ("seen", "unseen"):
        s = doc["splits"][split]
        copy = s["copy"]["mse"]
        rows.append([f"{split} objects", _mse_ssim(s["copy"]), _mse_ssim(s["stage1_only"]),
                     f"**{_mse_ssim(s['pose_control'])}**, {s['pose_control']['mse'] / copy:.3f}× a copy",
                     f"{_mse_ssim(s['pose_control_image_mask'])}, {s['pose_control_image_mask']['mse'] / copy:.3f}×"])
    header = ["MSE (SSIM)", "reference copy", "stage 1 alone (ΔF)", "stage 2, moved footprint",
              "stage 2, moved contact pixels"]
    return table(header, rows) + "\n\n" + _pose_source(doc)


def pose_robustness() -> str:
    doc = load("pose.json")
    r = {k: f"{v['ratio_to_copy']:.3f}" for k, v in doc["robustness"].items()}
    row = ["× a copy", r["none"], " / ".join(r[f"scale {s}"] for s in ("0.8", "0.9", "1.1", "1.2")),
           " / ".join(r[f"shift {p} px"] for p in (2, 4, 6)), " / ".join(r[f"rotate {d}°"] for d in (2, 4, 6)),
           " / ".join(r[f"combined {s}, 6 px, 6°"] for s in ("0.8", "1.2"))]
    header = ["mask", "as given", "scale 0.8 / 0.9 / 1.1 / 1.2", "shift 2 / 4 / 6 px", "rotate 2 / 4 / 6°",
              "0.8 or 1.2 scale + 6 px + 6°"]
    return table(header, [row]) + "\n\n" + _pose_source(doc)


def pose_speed() -> str:
    doc = load("pose.json")
    s, grid = doc["speed"], doc["speed"]["steps_grid"]
    rows = [[f"img/s, batch {s['batch']}", *(f"{g['img_per_s']:.0f}" for g in grid)],
            ["unseen MSE × a copy", *(f"{g['unseen_mse_ratio_to_copy']:.3f}" for g in grid)]]
    return (table(["DDIM steps", *(str(g["steps"]) for g in grid)], rows)
            + f"\n\nSide by side on one batch: stage 1 alone {s['stage1_img_per_s']:.0f} img/s, stage 2 "
            f"{s['pose_img_per_s']:.0f} img/s.\n\n" + _pose_source(doc))


def pose_moved() -> str:
    doc = load("pose.json")
    mc = doc["moved_contacts_240"]

    def means(r: dict) -> dict:
        keys = ("energy_in_target", "energy_left_behind", "iou", "area_ratio", "centroid_error_px")
        return {k: mean(mv[k] for mv in r["moves"].values()) for k in keys} | {"own": r["reference_energy_in_contact"]}

    real = [means(mc[f"real/{k}"]) for k in ("bead", "key", "seed")]
    sim = [means(r) for k, r in mc.items() if not k.startswith("real/")]

    def f2(rs: list[dict], k: str) -> str:
        return " / ".join(f"{r[k]:.2f}" for r in rs)

    rows = [["real bead / key / seed", f"{f2(real, 'energy_in_target')} ({f2(real, 'own')})",
             f2(real, "energy_left_behind"), f2(real, "iou"), f2(real, "area_ratio"),
             " / ".join(f"{r['centroid_error_px']:.0f}" for r in real)],
            [f"sensor model, {len(sim)} held-out objects",
             f"{span([r['energy_in_target'] for r in sim])} ({span([r['own'] for r in sim])})",
             span([r["energy_left_behind"] for r in sim]), span([r["iou"] for r in sim]),
             span([r["area_ratio"] for r in sim]), span([r["centroid_error_px"] for r in sim], ".0f")]]
    header = ["references (mean of 4 moves)", "signal in the moved mask (reference: in its own)", "left behind",
              "IoU", "area ratio", "centroid error px"]
    return table(header, rows) + "\n\n" + _pose_source(doc)


def pose_estimation() -> str:
    doc = load("pose.json")
    pe = doc["pose_estimation"]
    labels = {"real": f"{pe['frames']['real']} real frames", "generated": f"{pe['frames']['generated']} generated frames",
              "real + generated": "real + generated", "pca baseline": "PCA baseline"}
    rows = [[label, *(f"{pe[k][s]['xy_mm']:.2f} / {pe[k][s]['theta_deg']:.1f}" for s in ("seen", "unseen"))]
            for k, label in labels.items()]
    return (table(["trained on", "seen objects: xy mm / θ °", "unseen objects: xy mm / θ °"], rows) + "\n\n"
            + _pose_source(doc))


# -- policies (benchmarks.act, benchmarks.touch_il) --------------------------------------------------

ACT_GENERATOR = ("e87cbc3c3742019b", (" (act.json does not record it: the shipped default when it ran, "
                                      "per benchmarks/results/README.md)"))


def act_speed() -> str:
    """ACT's latency per chunk and training throughput per preset (``act_speed.json``: ``benchmarks.act
    --skip-experiment``, measured apart from the experiment, on a quiet machine)."""
    doc = load("act_speed.json")
    thr = {t["preset"]: t for t in ([doc["training_throughput"]] if isinstance(doc["training_throughput"], dict)
                                    else doc["training_throughput"])}
    rows = [[r["preset"], f"{r['params_M']:.2f} M",
             f"{r['ms_per_chunk']:.1f}" + (f" (target {r['target_ms']:.0f})" if r["target_ms"] else ""),
             docs_figures.timing_spread(r, "call", "calls"),
             f"{thr[r['preset']]['samples_per_s']:.0f}" if r["preset"] in thr else "–", r["threads"]]
            for r in doc["latency"]]
    header = ["preset", "parameters", f"ms per chunk of {doc['latency'][0]['chunk']} (CPU, median)", "spread",
              f"training samples/s (batch {doc['settings']['batch_size']})", "torch threads"]
    return table(header, rows) + "\n\n" + provenance("act_speed.json", doc, None)


def act() -> str:
    doc = load("act.json")
    labels = {0: "real only", 1: "+ ForceAugment 1 copy", 2: "+ ForceAugment 2 copies", 4: "+ ForceAugment 4 copies"}

    def cell(r: dict, s: str) -> str:
        lo, hi = r[s + "_wilson95"]
        return f"{pct(r[s + '_success'])} % [{pct(lo)}, {pct(hi)}]"

    rows = [[labels[r["copies"]], cell(r, "nominal"), cell(r, "shifted")] for r in doc["experiment"]]
    g = doc["experiment"][0]
    header = ["training data", f"grip {g['nominal_grip_n'][0]:.0f}–{g['nominal_grip_n'][1]:.0f} N (as in the demos)",
              f"grip {g['shifted_grip_n'][0]:.0f}–{g['shifted_grip_n'][1]:.0f} N (shifted)"]
    return table(header, rows) + "\n\n" + provenance("act.json", doc, *ACT_GENERATOR)


def touch_il_verdict() -> str:
    doc = load("touch_il_verdict.json")
    settings = list(dict.fromkeys(r["setting"] for r in doc["table"]))
    variants = list(dict.fromkeys(r["variant"] for r in doc["table"]))
    by = {(r["variant"], r["setting"]): r for r in doc["table"]}

    def cell(r: dict) -> str:
        return f"{pct(r['mean'])} % [{pct(r['ci95'][0])}, {pct(r['ci95'][1])}] ({' '.join(str(pct(x)) for x in r['per_seed'])})"

    rows = [[v, *(cell(by[(v, st)]) if (v, st) in by else "–" for st in settings)] for v in variants]
    policies = [u for u in doc["units"] if u["kind"] == "policy"]
    grip = {st: policies[0]["settings"].get(st) for st in settings}
    header = ["variant", *(f"{st} ({'–'.join(f'{g:g}' for g in grip[st])} N)" if grip[st] else st for st in settings)]
    comps = [[c["variant"], c["setting"], f"{c['diff'] * 100:+.1f} {ci_points(c)}",
              f"{c['p_holm']:.3g}", f"{c['p_sign_flip']:.3g}", f"**{c['verdict']}**"] for c in doc["comparisons"]]
    chead = ["variant", "setting", "vs real, points [95 % CI]", "p (CMH, Holm)", "p (sign-flip, seeds)", "verdict"]
    return (table(header, rows) + "\n\n" + table(chead, comps) + "\n\n"
            + provenance("touch_il_verdict.json", doc, None, note=f", {len(policies)} policies"))


def estimator() -> str:
    doc = load("estimator.json")
    rows = doc["estimators"]
    cells = [c for c in next(iter(rows.values())) if "/" in c]

    def mae(r: dict) -> str:
        return f"{r['mae_fz']:.2f} ({' / '.join(f'{v:.2f}' for v in r['mae'][:2])})"

    body = [[name, *(mae(r[c]) for c in cells), f"{r['unseen_vs_seen_sensor']:.2f}",
             "; ".join(f"{k} {v['force_n'][2]:.1f} N" + ("" if v["plausible"] else " ✗") for k, v in r["real_presses"].items())
             if "real_presses" in r else "–"] for name, r in rows.items()]
    header = ["estimator", *(c.replace("_", " ").replace("/", ", ") for c in cells), "unseen ÷ seen sensor",
              "real presses, Fz (✗: implausible)"]
    return table(header, body) + "\n\n" + provenance("estimator.json", doc, None)


def augment_lerobot_write() -> str:
    doc = load("augment_lerobot_write.json")
    r, gen = doc["lerobot_write"], load("generator.json")
    default = next(m for m in gen["methods"] if m["kind"] == "default" and m["steps"] == r["steps"])
    summary = [[r["regenerated_frames"], r["episodes_written"], r["rounds"], f"{r['generator_seconds']:.1f}",
                f"{r['generator_frames_per_s']:.1f}", f"{r['video_round_trip_mse']:.2f}",
                f"{default['unseen_240']['mse']:.1f}"]]
    head = ["regenerated frames", "episodes written", "rounds", "generator alone s", "generator frames/s",
            "video round trip MSE", f"generator's own MSE (unseen, 240×320, DDIM-{r['steps']})"]
    names = {"openmp_default": "OpenMP's default wait policy", "passive": "OMP_WAIT_POLICY=PASSIVE"}
    variants = [(f"export beside the build, {names[k]}", t) for k, t in r["wait_policies"].items()]
    variants += [(f"export after the build, {names[r['export_after_build']['wait_policy']]}", r["export_after_build"]),
                 (f"beside, {names[r['cli_wait_policy']]}, with --video-round-trip (one run)", r["with_round_trip"])]
    rows = [[name, f"{t['write_seconds']:.1f}", f"{t['writer_vs_generator']:.2f}",
             f"{t['writer_vs_generator_cpu']:.2f}"] for name, t in variants]
    return (table(head, summary) + "\n\n" + table(["write", "s (median)", "writer ÷ generator (target 0.80)",
                                                     "in CPU s"], rows)
            + "\n\n" + provenance("augment_lerobot_write.json", doc, doc["generator_hash"]))


def _p(cell: dict) -> str:
    p = cell["p_vs_real"]
    if cell["variant"] == "vision_only":
        return f"p={p:.1e}"
    return "p<0.005" if p < 0.005 else f"p={p:.2f}"


def _touch_cell(c: dict) -> str:
    s = wilson(c["successes"], c["episodes"], c["wilson95"])
    return s if c["variant"] == "real" else f"{s}, {_p(c)}"


def touch_il() -> str:
    doc = load("touch_il.json")
    st = doc["settings"]
    cells = {(c["demos"], c["variant"], c["setting"]): c for c in doc["cells"]}
    bands = list(st["grip_bands_n"])
    rows = [[d, f"{v} ({st['copies'][v]} copies)" if v == "image_aug" else v,
             *(_touch_cell(cells[d, v, b]) for b in bands)]
            for d in st["budgets"] for v in st["variants"]]
    header = ["demos", "variant", *(f"{b} ({lo:g}–{hi:g} N)" for b, (lo, hi) in st["grip_bands_n"].items())]
    return table(header, rows) + "\n\n" + provenance("touch_il.json", doc, st["generator_hash"])


def touch_il_reruns() -> str:
    out, sources = [], []
    for name, what in (("touch_il_seed1.json", "training seed 1"), ("touch_il_symmetric.json", "offset U[−5, 5] N")):
        doc = load(name)
        cells = {}
        for c in doc["cells"]:
            cells.setdefault(c["variant"], {})[c["setting"]] = c
        for v, by_band in cells.items():
            bands = [by_band[b] for b in doc["settings"]["grip_bands_n"]]
            out.append([f"{what} (`{name}`)", bands[0]["demos"], v,
                        *(wilson(b["successes"], b["episodes"], b["wilson95"]) for b in bands)])
        sources.append(provenance(name, doc, doc["settings"]["generator_hash"]))
    header = ["run", "demos", "variant", "nominal (4–7 N)", "shifted_low (1.5–3 N)", "shifted_high (8–10 N)"]
    return table(header, out) + "\n\n" + "\n\n".join(sources)


# -- benchmarks/results/README.md -------------------------------------------------------------------

def results_provenance() -> str:
    rows = []
    for path in sorted(RESULTS.glob("*.json")):
        doc = json.loads(path.read_text())
        gen = recorded_generator(doc) or (ACT_GENERATOR[0] if path.name == "act.json" else None)
        commit = doc["machine"]["git_commit"]
        why = (["dirty tree"] if commit.endswith("-dirty") else []) + (
            ["earlier generator"] if gen is not None and gen != SHIPPED_GENERATOR else [])
        rows.append([f"`{path.name}`", commit, doc["machine"]["date_utc"][:10], doc["machine"]["cpu"],
                     (gen + (" (not recorded in the file)" if path.name == "act.json" else "")) if gen else "–",
                     f"history: {', '.join(why)}" if why else "current"])
    return table(["file", "machine.git_commit", "date", "cpu", "generator", "status"], rows)


BLOCKS: dict[str, Callable[[], str]] = {
    "generator": generator, "generator-ratios": generator_ratios, "response": response,
    "pose": pose, "pose-robustness": pose_robustness, "pose-speed": pose_speed, "pose-moved": pose_moved,
    "pose-estimation": pose_estimation, "act-speed": act_speed, "act": act, "touch-il": touch_il,
    "touch-il-reruns": touch_il_reruns, "results-provenance": results_provenance,
    "augment-lerobot-write": augment_lerobot_write, "touch-il-verdict": touch_il_verdict,
    "estimator": estimator, **docs_figures.BLOCKS, **generator_fa_figures.BLOCKS,
}

# model cards whose ``benchmark`` copies the figures of one JSON: card -> (JSON, the card's view of it)
CARDS: dict[str, tuple[str, Callable[[dict], dict]]] = {
    f"controltac_il/generator/checkpoints/{key}/model_card.json": (
        "generator.json", lambda doc, key=key: {
            "machine": doc["machine"], "settings": doc["settings"], "targets": doc["targets"],
            "methods": [m for m in doc["methods"] if m["kind"] in ("copy", "rerender", key)]})
    for key in (*SHIPPED, *FRONTIER_SIZES)
} | {"controltac_il/generator/checkpoints/pose/model_card.json": (
    "pose.json", lambda doc: {k: doc[k] for k in ("machine", "pose_control", "robustness", "speed")})}


# -- the blocks ---------------------------------------------------------------------------------------

def blocks(text: str) -> list[tuple[str, int, int]]:
    """(name, start, end) of each block's body; ValueError on an unpaired, nested, repeated or unknown marker."""
    found, open_name, start, seen = [], None, 0, set()
    for m in MARKER.finditer(text):
        closing, name = m.group(1) == "/", m.group(2)
        if not closing:
            if open_name is not None:
                raise ValueError(f"figures:{name} opens inside figures:{open_name}")
            if name in seen:
                raise ValueError(f"figures:{name} appears twice")
            if name not in BLOCKS:
                raise ValueError(f"figures:{name}: no render function in benchmarks.readme_figures.BLOCKS")
            open_name, start = name, m.end()
        else:
            if name != open_name:
                raise ValueError(f"/figures:{name} closes " + (f"figures:{open_name}" if open_name else "nothing"))
            found.append((name, start, m.start()))
            seen.add(name)
            open_name = None
    if open_name is not None:
        raise ValueError(f"figures:{open_name} is never closed")
    return found


def rendered(text: str) -> tuple[str, list[str]]:
    """``text`` with every block re-rendered, and the names of the blocks that changed."""
    out, changed, last = [], [], 0
    for name, start, end in blocks(text):
        body = "\n" + BLOCKS[name]() + "\n"
        if text[start:end] != body:
            changed.append(name)
        out += [text[last:start], body]
        last = end
    return "".join(out) + text[last:], changed


def card_mismatches() -> list[str]:
    """Model cards whose ``benchmark`` figures differ from the JSON of the same run."""
    bad = []
    for card_path, (name, view) in CARDS.items():
        card = json.loads((ROOT / card_path).read_text()).get("benchmark", {})
        figures = {k: v for k, v in card.items() if k not in ("command", *HISTORY_KEYS)}
        if figures != view(load(name)):
            bad.append(f"{card_path} (benchmark vs benchmarks/results/{name})")
    return bad


def check() -> list[str]:
    """What disagrees with the JSONs: 'FILE: figures:NAME' per stale block, then the model cards."""
    return [f"{doc.relative_to(ROOT) if doc.is_relative_to(ROOT) else doc}: figures:{name}" for doc in DOCS
            for name in rendered(doc.read_text())[1]] + card_mismatches()


def main(argv=None) -> int:
    p = ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--check", action="store_true", help="change nothing; exit 1 naming each block that differs")
    a = p.parse_args(argv)
    return _run(a.check)  # a malformed marker: ValueError, one line and exit 2 under guard


def _run(check_only: bool) -> int:
    if check_only:
        bad = check()
        for b in bad:
            print(f"differs from its JSON: {b}", file=sys.stderr)
        return 1 if bad else 0
    for doc in DOCS:
        text, changed = rendered(doc.read_text())
        if changed:
            with atomic_path(doc) as tmp:  # a stopped rewrite never leaves a README half written
                tmp.write_text(text)
            print(f"{doc.relative_to(ROOT)}: rewrote {', '.join(changed)}")
    bad = card_mismatches()
    for b in bad:
        print(f"differs from its JSON (not rewritten): {b}", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, main))
