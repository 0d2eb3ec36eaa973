"""The docs blocks of the generator where ForceAugment uses it: the presets on ForceAugment's pairs
(``generator.json``'s ``forceaugment_split``, written by ``benchmarks.generator``) and the levers chosen on
validation objects and tested once (``generator_levers.json``). Reads committed JSONs only.
"""

from __future__ import annotations

import math

from benchmarks import figure_text as ft

DFZ_BINS = ((0.0, 2.0), (2.0, 5.0), (5.0, math.inf))  # |ΔFz| N: benchmarks.generator_fa's breakdown


def bin_label(lo: float, hi: float) -> str:
    """The JSON key of the |ΔFz| bin (lo, hi] N."""
    return f"|dFz| {lo:g}-{hi:g} N"


# the targets on ForceAugment's pairs of the held-out objects, 240×320, nominal sensor (MSE ÷ a copy's)
TARGETS = {"increase": 0.40, "all": 0.30, "worst_object": 0.60}
LABELS = {"increase": "pressing harder", "all": "all pairs", "worst_object": "worst object"}


def worst_object(s: dict) -> tuple[str, float]:
    """The object of a generator's scores with the highest MSE ÷ a copy's, and that ratio."""
    name = max(s["objects"], key=lambda o: s["objects"][o]["ratio"])
    return name, s["objects"][name]["ratio"]


def against_targets(s: dict) -> dict:
    """A generator's scores on ForceAugment's pairs: its figures for ``TARGETS``, its worst object and whether each
    target is met."""
    name, ratio = worst_object(s)
    figures = {"increase": s["increase"]["ratio"], "all": s["all"]["ratio"], "worst_object": ratio}
    return {"figures": figures, "worst_object": name, "meets": {k: bool(figures[k] <= t) for k, t in TARGETS.items()}}


def _against(t: dict) -> list[str]:
    return [f"{t['figures'][k]:.3f} ({'met' if t['meets'][k] else 'missed'})" for k in TARGETS]


def _target_header(first: str) -> list[str]:
    return [first, *(f"{LABELS[k]} ≤ {bound:.2f}×" for k, bound in TARGETS.items())]


def _ratio(s: dict, key: str) -> str:
    return f"{s[key]['ratio']:.3f} ({s[key]['pairs']})" if s[key] else "–"  # None: no pair in the cell


def forceaugment_split() -> str:
    """Per frame size and sensor, each preset's MSE ÷ a copy's on ForceAugment's pairs, broken down; the targets of
    the nominal 240×320 pairs; the contact split; the real frames' read-back."""
    doc = ft.load("generator.json")
    split = doc["forceaugment_split"]
    rows, nominal = [], None
    for r in split["rows"]:
        if (r["size"], r["sensor"]) == ("240", "nominal"):
            nominal = r
        for name, s in r["presets"].items():
            obj, ratio = worst_object(s)
            rows.append([f"{r['size']}, {r['sensor']}", f"`{name}`", f"**{s['all']['ratio']:.3f}**",
                         _ratio(s, "increase"), _ratio(s, "decrease"), *(_ratio(s, bin_label(*b)) for b in DFZ_BINS),
                         f"{obj} {ratio:.2f}", f"{r['noise_ratio_to_copy']:.3f}"])
    header = ["frames, sensor", "preset", "all", "pressing harder (pairs)", "easing (pairs)", "|ΔFz| ≤ 2 N",
              "2–5 N", "> 5 N", "worst object", "noise floor"]
    return "\n\n".join([ft.table(header, rows), _targets(nominal), _contact(nominal), _real(split["real"]),
                        ft.source("generator.json", doc)])


def _targets(row: dict) -> str:
    rows = [[f"`{name}`", *_against(against_targets(s))] for name, s in row["presets"].items()]
    return ft.table(_target_header("240×320, nominal: preset"), rows)


def _contact(row: dict) -> str:
    rows = [[f"`{name}`", f"{s['generator_reference_contact_mse']:.1f}", f"{s['copy_reference_contact_mse']:.1f}",
             f"{s['generator_new_contact_mse']:.1f}", f"{s['copy_new_contact_mse']:.1f}"]
            for name, s in row["presets"].items()]
    return ft.table(["240×320, nominal: preset", "MSE on the reference's contact", "a copy's there",
                     "MSE on new contact", "a copy's there"], rows)


def _real(real: dict) -> str:
    rows = [[f"`{name}`", " / ".join(f"{x:+.2f}" for x in r["readback_rise_n"]), f"{r['slope_n_per_n']:.3f}"]
            for name, r in real.items() if r]
    dfz = next(r["dfz"] for r in real.values() if r)
    return ft.table(["real frames: preset", f"read-back rise (N) at ΔFz {' / '.join(f'{x:+g}' for x in dfz)} N",
                     "slope (N per N; 1 is exact)"], rows)


def levers() -> str:
    """Each candidate's training and its ForceAugment split on the validation objects, the choice, and the test of
    the chosen one and ``default`` on the held-out objects against the targets."""
    doc = ft.load("generator_levers.json")
    val, runs = doc["validation"]["generators"], doc["variants"]
    rows = [[f"`{k}`" + (" (chosen)" if k == doc["chosen"] else ""),
             " ".join(doc["settings"]["variants"].get(k, [])) or ("none (the steps alone)" if k in runs else
                                                                   "shipped, not fine-tuned"),
             f"{runs[k]['wall_s'] / 60:.0f}" if k in runs else "–",
             (f"{runs[k]['symmetric_validation']['ratio_to_copy']:.3f} (step {runs[k]['symmetric_validation']['step']})"
              if k in runs else "–"),
             f"{s['all']['ratio']:.4f}", f"{s['increase']['ratio']:.4f}"] for k, s in val.items()]
    objects = len(doc["settings"]["validation_objects"])
    val_table = ft.table(["candidate", f"lever (fine-tune of {doc['settings']['steps']} steps)", "training (min)",
                          "its run's symmetric validation (best)",
                          f"validation: all ({doc['settings']['val_pairs']} pairs, {objects} objects)",
                          "validation: pressing harder"], rows)
    trows = [[f"`{k}`", *_against(t), t["worst_object"]] for k, t in doc["targets"].items()]
    test_table = ft.table([*_target_header(f"test, {doc['settings']['pairs']} held-out pairs"), "worst object"], trows)
    return "\n\n".join([val_table, test_table, f"Noise floor of the test pairs: "
                        f"{doc['test']['floors']['noise_ratio_to_copy']:.3f}× a copy's.",
                        ft.source("generator_levers.json", doc)])


BLOCKS = {"generator-forceaugment": forceaugment_split, "generator-levers": levers}
