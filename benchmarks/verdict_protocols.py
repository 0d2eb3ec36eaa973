"""The verdict's protocols as values: what each grid trains, validates and tests, and how it decides.

``python -m benchmarks.verdict --protocol NAME`` runs one of them. Each protocol was committed before any of
its units ran; its JSON's ``protocol`` repeats this record and the commit that fixed it.

- ``v1`` (retired): 5 seeds, a recipe tuned on ``real`` alone, the grip shift chosen on validation episodes,
  episode-level CMH with Holm. Its runner is ``python -m benchmarks.touch_il_verdict`` at commit 7c17277, the
  commit that ran ``touch_il_verdict.json``; it is not runnable from this one.
- ``v2`` (exploratory): 12 paired seeds, four variants, Holm over six primary comparisons. The comparison that
  came out strongest (``fa2`` at the demos' grip) was one of six looked at, so v2 cannot confirm it.
- ``v3`` (confirmatory): one question fixed before any of its units ran, on fresh seeds, in a design that may
  stop at its first look.

PROTOCOL v3

1. Primary hypothesis, one: ``fa2`` (2 ForceAugment copies, the paper's offsets U[-3, 10] N and jitter
   {0, +-0.5, +-1} N clamped to Fz 1-10 N, the shipped default generator, hash pinned in ``generator``) against
   ``real`` at the demos' grip (4-7 N). Statistic: the mean over training seeds of the seed-paired difference in
   test success. Test: the exact two-sided sign-flip test over seeds. One primary comparison: no Holm.
2. Seeds: training seeds 12-35, disjoint from v1's and v2's 0-11. Two looks, fixed here:
   look 1 at seeds 12-23 (12 paired seeds), look 2 at seeds 12-35 (24).
   - Look 1 rejects when p < 0.001; look 2 when p < 0.049. By the union bound the overall two-sided alpha is at
     most 0.001 + 0.049 = 0.05 whatever the joint law of the two p-values (Haybittle-Peto's split).
   - Futility (non-binding on alpha: it only removes rejections): if look 1 does not reject and the mean paired
     difference there is <= 0, the design stops with "no detectable effect". It gives up a "hurts" verdict that
     only look 2 could reach; the question is whether ForceAugment helps.
   - The power at each look is in the record (``power``), simulated with Normal per-seed differences at the SDs
     of v2's paired differences (0.16-0.21; fa2 vs real at nominal: 0.202 at 50 episodes a seed; v3's 100
     episodes a seed make it smaller).
3. Variants: ``real`` and ``fa2``. ``fa2_range`` and ``image_aug`` answered their questions in v2 and are not
   re-run. 50 demos (scene seeds [0, 50)), the cpu preset, batch 16, AdamW 3e-4 with 50 warm-up steps then
   constant, demos split seed 0, one ForceAugment draw (its seed 0) for every training seed.
4. Budget and checkpoint: every (variant, seed) trains to 8000 steps with a snapshot every 1000, each validated
   on episodes [700000, 700030) at the demos' grip. Rule (v2's): per variant, the snapshot with the best mean
   validation success over that variant's look-1 seeds (ties: fewer steps). The steps are fixed at look 1 and
   kept for look 2, so look 2 adds seeds to look 1's statistic without changing it. Test episodes never choose.
   A train unit also runs the test episodes at its last snapshot (8000): that result counts only where its
   variant's chosen step is 8000; otherwise a test unit runs the chosen snapshot (trained again to it when the
   session that trained it is gone: the same recipe, seed and step).
5. Test episodes: a new range, disjoint from every earlier test, validation and demo range: 100 per unit at
   the demos' grip (seeds [1000000, 1000100), the primary) and 50 per unit in each grip shift (seeds
   [1000000, 1000050)).
6. Secondary, reported without a verdict: the two grip shifts (0.8-1.5 N; 11-14 N, the stress test beyond the
   generator's validated 10 N) and the episode-level CMH at every setting.
7. An episode that raises stops the grid and is never counted. Every unit is saved as it finishes;
   ``--resume`` continues. A look is analysed only when every unit of its seeds is tested.

Verdict wording: "helps" / "hurts" (the sign of the mean difference) only when the primary test rejects at its
look; otherwise "no detectable effect", with the interval.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from functools import lru_cache

NOMINAL = "nominal"
SETTINGS = {NOMINAL: (4.0, 7.0), "grip_0.8-1.5": (0.8, 1.5), "grip_11-14": (11.0, 14.0)}
STRESS = "grip_11-14"
DEMO_SEEDS = (0, 50)
VALIDATION_SEEDS = (700_000, 700_030)
COPIES = {"fa2": 2, "fa2_range": 2, "image_aug": 2}
FORCE_SETTINGS = {"fa2": {}, "fa2_range": {"target_range": (1.0, 10.0)}}
# every test range any grid has looked at: a new protocol's must miss them all
LOOKED_AT = {"v3 test": (1_000_000, 1_000_100), "v2 test": (900_000, 900_050), "v1 test": (800_000, 800_050),
             "touch_il test": (200_000, 200_050), "earlier test": (100_000, 100_050)}
USED_TRAIN_SEEDS = {"v1": tuple(range(5)), "v2": tuple(range(12))}


@dataclass(frozen=True)
class Look:
    """One analysis of a group-sequential design: after the first ``seeds`` paired seeds, reject when the exact
    sign-flip p < ``alpha``; ``futility``: otherwise stop when the mean paired difference is <= 0."""

    seeds: int
    alpha: float
    futility: bool = False


@dataclass(frozen=True)
class Protocol:
    """One verdict grid. Seeds are (start, stop) ranges; ``test_episodes`` counts per setting from ``test_start``."""

    name: str
    variants: tuple[str, ...]
    train_seeds: tuple[int, ...]
    snapshots: tuple[int, ...]
    test_start: int
    test_episodes: dict[str, int]
    primary: tuple[tuple[str, str], ...]  # (variant, setting) compared with real, each with a verdict
    correction: str  # "holm" over ``primary``, or "sequential" (one primary, ``looks``)
    looks: tuple[Look, ...] = ()
    min_seeds: int = 10
    validation_episodes: int = VALIDATION_SEEDS[1] - VALIDATION_SEEDS[0]
    test_last_in_train: bool = False
    fresh_from: tuple[str, ...] = ()  # earlier protocols none of whose training seeds may be reused
    not_rerun: dict[str, str] = field(default_factory=dict)
    retired_at: str | None = None  # the commit whose runner runs a retired protocol

    @property
    def settings(self) -> dict[str, tuple[float, float]]:
        return {s: SETTINGS[s] for s in self.test_episodes}

    def test_seeds(self, setting: str) -> tuple[int, int]:
        return self.test_start, self.test_start + self.test_episodes[setting]

    @property
    def validation_seeds(self) -> tuple[int, int]:
        return VALIDATION_SEEDS[0], VALIDATION_SEEDS[0] + self.validation_episodes

    def look_seeds(self, seeds) -> list[list[int]]:
        """The seeds each look analyses (cumulative), from the run's ``seeds`` in order; one look without looks."""
        return [list(seeds[:look.seeds]) for look in self.looks] or [list(seeds)]


V2 = Protocol(name="v2", variants=("real", "fa2", "fa2_range", "image_aug"), train_seeds=tuple(range(12)),
              snapshots=(1000, 2000, 3000, 4000, 5000, 6000), test_start=900_000,
              test_episodes={NOMINAL: 50, "grip_0.8-1.5": 50, STRESS: 50},
              primary=tuple((v, s) for v in ("fa2", "fa2_range") for s in SETTINGS), correction="holm")
V3 = Protocol(name="v3", variants=("real", "fa2"), train_seeds=tuple(range(12, 36)),
              snapshots=tuple(range(1000, 8001, 1000)), test_start=1_000_000,
              test_episodes={NOMINAL: 100, "grip_0.8-1.5": 50, STRESS: 50}, primary=(("fa2", NOMINAL),),
              correction="sequential", looks=(Look(12, 0.001, futility=True), Look(24, 0.049)), min_seeds=24,
              test_last_in_train=True, fresh_from=("v1", "v2"),
              not_rerun={"fa2_range": "v2: +10.8 points at nominal, no closer to a verdict than fa2",
                         "image_aug": "v2: -2.0 points at nominal, photometric copies do not help here"})
V1 = Protocol(name="v1", variants=("vision_only", "real", "fa2", "fa4", "image_aug"), train_seeds=tuple(range(5)),
              snapshots=(1000, 2000, 3000, 4000, 5000, 6000), test_start=800_000, test_episodes={NOMINAL: 50},
              primary=(), correction="holm", min_seeds=5, retired_at="7c17277")
PROTOCOLS = {p.name: p for p in (V1, V2, V3)}


def v2_paired_sd(setting: str = NOMINAL) -> float:
    """SD over seeds of v2's paired fa2 - real differences at ``setting`` (its committed JSON)."""
    import numpy as np

    from benchmarks.figure_text import load

    comps = load("touch_il_verdict_v2.json")["comparisons"]
    diffs = next(c["per_seed_diff"] for c in comps if c["variant"] == "fa2" and c["setting"] == setting)
    return round(float(np.std(diffs, ddof=1)), 3)


@lru_cache(maxsize=4)
def sequential_design_power(looks: tuple[Look, ...], reps: int = 2000) -> dict:
    """The design's power statement: rejection and stopping probabilities at 10 and 13 points for SDs 0.16, v2's
    and 0.21, the type-I error at no effect, and the effect detected with 80 % power at v2's SD."""
    from benchmarks.verdict_report import sequential_mde, sequential_power

    spec = tuple((look.seeds, look.alpha, look.futility) for look in looks)
    sd = v2_paired_sd()
    rows = [sequential_power(e, s, spec, reps) for e in (0.10, 0.13) for s in (0.16, sd, 0.21)]
    null = sequential_power(0.0, sd, spec, reps)
    mde = sequential_mde(sd, spec, reps=reps)
    power = {"v2_paired_sd": sd, "rows": rows, "no_effect": null, "mde_80": mde, "reps": reps}
    return {**power, "statement": sequential_statement(power)}


def sequential_statement(power: dict) -> str:
    """The sentence of a sequential design's power record (``sequential_design_power`` without its statement)."""
    sd = power["v2_paired_sd"]
    at = {(r["effect"], r["sd"]): r for r in power["rows"]}
    return (f"at v2's SD of paired differences ({sd}), the design rejects a 10-point effect with "
            f"{at[0.10, sd]['power']:.0%} probability and a 13-point one with {at[0.13, sd]['power']:.0%} "
            f"({at[0.13, sd]['look_1_efficacy']:.0%} at look 1); 80 % power at a {power['mde_80'] * 100:.0f}-point "
            f"effect; simulated type-I error {power['no_effect']['power']:.3f} (bound 0.05)")


def holm_power(n: int) -> dict:
    """v2's power statement: minimum detectable effects (80 % power) from v1's spread, for ``n`` seeds."""
    from benchmarks.verdict_report import sign_flip_mde

    sd, k = 0.253, len(V2.primary)  # pooled SD of v1's per-seed paired differences (fa2, fa4, image_aug vs real)
    p = {"seeds": n, "v1_paired_sd": sd, "primary_comparisons": k, "power": 0.8,
         "mde_holm_first": sign_flip_mde(sd, n, 0.05 / k), "mde_alpha": sign_flip_mde(sd, n, 0.05)}
    p["statement"] = (f"with {n} seeds the exact sign-flip test detects, with 80 % power, a mean paired difference "
                      f"of {p['mde_holm_first']:.0%} at Holm's strictest step (alpha 0.05/{k}) and of "
                      f"{p['mde_alpha']:.0%} at alpha 0.05 (Normal per-seed differences with v1's SD {sd})")
    return p


def record(protocol: Protocol, seeds, demos: int, batch_size: int, snapshots, generator: str,
           power_reps: int = 2000) -> dict:
    """The JSON record of a run of ``protocol`` with the default generator of hash ``generator`` (hashed into its
    signature; a resumed grid must match it)."""
    from controltac_il.app.experiment import touch_scene

    looks = tuple(protocol.looks)
    power = (holm_power(len(seeds)) if protocol.correction == "holm"
             else sequential_design_power(looks, power_reps))
    return {"version": protocol.name, "demo_seeds": list(DEMO_SEEDS), "validation_seeds": list(protocol.validation_seeds),
            "test_episodes": {s: list(protocol.test_seeds(s)) for s in protocol.test_episodes},
            "train_seeds": list(seeds), "demos": demos, "variants": list(protocol.variants),
            "copies": {v: COPIES.get(v, 0) for v in protocol.variants},
            "force_settings": {v: {k: list(x) for k, x in FORCE_SETTINGS[v].items()}
                               for v in protocol.variants if v in FORCE_SETTINGS},
            "generator": generator,
            "recipe": {"preset": "cpu", "batch_size": batch_size, "lr": "3e-4 (preset), 50 warm-up steps, constant",
                       "split_seed": 0, "snapshots": list(snapshots)},
            "checkpoint_rule": "per variant: the snapshot with the highest mean validation success over its seeds "
                               + ("of look 1, kept for every look" if looks else "") + " (ties: fewer steps)",
            "settings": {k: list(v) for k, v in protocol.settings.items()}, "stress_test": STRESS,
            "primary": [list(p) for p in protocol.primary], "correction": protocol.correction,
            "looks": [asdict(look) for look in looks], "test_last_in_train": protocol.test_last_in_train, "fresh_from": list(protocol.fresh_from),
            "not_rerun": protocol.not_rerun, "power": power, "scene": "PegInHoleConfig.touch_critical()",
            "scene_config": repr(touch_scene())}


def signature_of(record_: dict) -> str:
    """12 hex digits fixing a protocol record; its ``power`` is left out (derived by simulation, not chosen)."""
    import hashlib

    fixed = {k: v for k, v in record_.items() if k != "power"}
    return hashlib.sha1(json.dumps(fixed, sort_keys=True).encode()).hexdigest()[:12]
