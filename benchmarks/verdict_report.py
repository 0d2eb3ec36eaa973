"""Statistics and the picture of a multi-seed policy comparison: per-episode outcomes grouped by training seed.

``outcomes`` below is always a list with one 0/1 array per training seed (the episodes that seed's policy
ran); two such lists compared are paired by position (the same training seed, the same episode seeds).

- :func:`seed_episode_ci`: the mean success over seeds with a two-level bootstrap interval (resample the
  seeds, then the episodes within each drawn seed), so it carries both sources of variance.
- :func:`paired_diff`: the mean of the seed-paired differences with the same two-level interval.
- :func:`cmh_p`: the Cochran-Mantel-Haenszel test with one 2x2 table (variant / real x success / failure)
  per training seed. scipy has no CMH test; the statistic is six lines (Agresti, Categorical Data Analysis,
  section 6.3), so no statsmodels dependency for it.
- :func:`sign_flip_p`: the exact sign-flip test on the per-seed differences (seeds as the units; with n seeds
  its smallest two-sided p is 2 / 2**n, 0.0625 at five).
- :func:`sequential_power`: the power of a group-sequential sign-flip design (looks, their alphas, a futility
  rule) under Normal per-seed differences.
- :func:`holm`: Holm's step-down adjustment (five lines; scipy has only Benjamini-Hochberg).
- :func:`look_decision`, :func:`sequential_outcome`: a group-sequential design's stop at each look.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.common import save_figure


def _as_seeds(outcomes) -> list[np.ndarray]:
    out = [np.asarray(o, dtype=np.float64).reshape(-1) for o in outcomes]
    if not out or any(o.size == 0 for o in out):
        raise ValueError("outcomes: need at least one seed, each with at least one episode")
    bad = [i for i, o in enumerate(out) if not np.isfinite(o).all()]
    if bad:
        raise ValueError(f"outcomes: seed {bad[0]} holds NaN or inf; expected episode successes 0 or 1")
    return out


def _finite_diffs(diffs, least: int) -> np.ndarray:
    """Per-seed differences (n,) as float64; ValueError for a non-finite one or fewer than ``least``."""
    d = np.asarray(diffs, dtype=np.float64).reshape(-1)
    if d.size < least or not np.isfinite(d).all():
        raise ValueError(f"diffs: expected at least {least} finite per-seed differences, got {d.tolist()}")
    return d


def _two_level(per_seed_stat, n_seeds: int, sizes: list[int], reps: int, rng: np.random.Generator) -> np.ndarray:
    """``reps`` bootstrap draws of the mean over seeds of ``per_seed_stat(seed, episode indices)``."""
    draws = np.empty(reps)
    for r in range(reps):
        seeds = rng.integers(0, n_seeds, n_seeds)
        draws[r] = np.mean([per_seed_stat(s, rng.integers(0, sizes[s], sizes[s])) for s in seeds])
    return draws


def seed_episode_ci(outcomes, reps: int = 4000, seed: int = 0) -> tuple[float, tuple[float, float]]:
    """(mean over seeds of each seed's success rate, its 95 % two-level bootstrap interval)."""
    o = _as_seeds(outcomes)
    draws = _two_level(lambda s, idx: o[s][idx].mean(), len(o), [x.size for x in o], reps,
                       np.random.default_rng(seed))
    lo, hi = np.percentile(draws, [2.5, 97.5])
    return float(np.mean([x.mean() for x in o])), (float(lo), float(hi))


def paired_diff(a, b, reps: int = 4000, seed: int = 0) -> tuple[float, tuple[float, float], list[float]]:
    """(mean over seeds of rate(a) - rate(b), its 95 % two-level bootstrap interval, the per-seed differences).

    Within a drawn seed the two policies' episodes are resampled together (same episode seeds)."""
    a, b = _as_seeds(a), _as_seeds(b)
    if len(a) != len(b) or any(x.size != y.size for x, y in zip(a, b)):
        raise ValueError("paired_diff: a and b must have the same seeds and the same episodes per seed")
    d = [x - y for x, y in zip(a, b)]
    draws = _two_level(lambda s, idx: d[s][idx].mean(), len(d), [x.size for x in d], reps,
                       np.random.default_rng(seed))
    lo, hi = np.percentile(draws, [2.5, 97.5])
    per_seed = [float(x.mean()) for x in d]
    return float(np.mean(per_seed)), (float(lo), float(hi)), per_seed


def cmh_p(a, b) -> float:
    """Two-sided Cochran-Mantel-Haenszel p-value (with continuity correction) that a and b differ in success
    odds, one 2x2 table per seed; 1.0 when no seed's table has any variance (e.g. all successes)."""
    from scipy.stats import chi2

    a, b = _as_seeds(a), _as_seeds(b)
    num, var = 0.0, 0.0
    for x, y in zip(a, b, strict=True):
        n1, n2, s1, s2 = x.size, y.size, x.sum(), y.sum()
        n, m1 = n1 + n2, s1 + s2
        num += s1 - n1 * m1 / n
        var += n1 * n2 * m1 * (n - m1) / (n * n * (n - 1)) if n > 1 else 0.0
    if var <= 0:
        return 1.0
    stat = max(abs(num) - 0.5, 0.0) ** 2 / var
    return float(chi2.sf(stat, 1))


def sign_flip_p(diffs) -> float:
    """Two-sided exact p-value of the per-seed differences' mean under random sign flips (seeds as units): the
    share of the 2**n sign patterns whose |mean| reaches the observed one. Counted by meeting in the middle (the
    sums of each half's 2**(n/2) patterns, one sorted): milliseconds at n = 24, where scipy's exact
    ``permutation_test`` enumerates 2**24 patterns (4 min on the 2-core CPU) and its default resampling is random."""
    d = np.abs(_finite_diffs(diffs, 1))
    if np.all(d == 0):
        return 1.0
    observed = abs(float(np.sum(diffs))) - 1e-9 * float(d.sum())  # ties within rounding count as reaching it
    if observed <= 0:
        return 1.0
    half = d.size // 2
    left, right = _pattern_sums(d[:half]), np.sort(_pattern_sums(d[half:]))
    at_least = right.size - np.searchsorted(right, observed - left, side="left")
    at_most = np.searchsorted(right, -observed - left, side="right")
    return float((at_least.sum() + at_most.sum()) / 2.0 ** d.size)


def _pattern_sums(d: np.ndarray) -> np.ndarray:
    """Sum of ``d`` under each of its 2**len(d) sign patterns."""
    sums = np.zeros(1)
    for x in d:
        sums = np.concatenate([sums + x, sums - x])
    return sums


def paired_t_p(diffs) -> float:
    """Two-sided paired t-test p of the per-seed differences (at least 2; scipy's one-sample t-test against 0); 1.0
    when they are all equal to 0, 0.0 when they are all one non-zero value."""
    from scipy.stats import ttest_1samp

    d = _finite_diffs(diffs, 2)
    if np.all(d == d[0]):
        return 1.0 if d[0] == 0 else 0.0
    return float(ttest_1samp(d, 0.0).pvalue)


def sign_flip_mde(sd: float, n: int, alpha: float, power: float = 0.8, reps: int = 2000, seed: int = 0) -> float:
    """The smallest mean paired difference (0-1, on a 0.01 grid) that the exact sign-flip test over ``n`` seeds
    detects at two-sided ``alpha`` with probability >= ``power``, when per-seed differences are Normal(effect,
    ``sd``): the same draws for every effect."""
    z = np.random.default_rng(seed).normal(0.0, sd, (reps, n))
    return _smallest_effect(lambda cents: np.mean([sign_flip_p(row) < alpha for row in z + cents / 100]) >= power)


def _smallest_effect(enough) -> float:
    """The smallest effect on the 0.01 grid of [0, 1] where ``enough(cents)`` holds, bisected (the rejection rate
    rises with the effect); 1.0 when even 1.0 is not enough."""
    if not enough(100):
        return 1.0
    lo, hi = -1, 100  # enough(hi) holds, enough(lo) is taken as failing
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if enough(mid) else (mid, hi)
    return round(hi / 100, 2)


def look_decision(diffs, seeds: int, alpha: float, futility: bool, last: bool) -> dict:
    """One look of a group-sequential sign-flip design over the first ``seeds`` per-seed differences: "efficacy"
    (reject) when the exact sign-flip p < ``alpha``; else "futility" when ``futility`` and their mean is <= 0;
    else "final" at the ``last`` look and "continue" before it. Returns {"p", "mean", "stop", "reject"}."""
    d = np.asarray(diffs, dtype=np.float64)
    if d.size < seeds:
        raise ValueError(f"the look needs {seeds} paired seeds, got {d.size}")
    d = d[:seeds]
    p = sign_flip_p(d)
    stop = ("efficacy" if p < alpha else "futility" if futility and d.mean() <= 0 and not last
            else "final" if last else "continue")
    return {"p": p, "mean": float(d.mean()), "stop": stop, "reject": stop == "efficacy"}


def sequential_outcome(diffs, looks) -> dict:
    """Where the design ``looks`` ((seeds, alpha, futility) per look, cumulative seed counts) stops on ``diffs``
    (seed order): :func:`look_decision` at each look until one stops; adds the 1-based ``look``."""
    for k, (seeds, alpha, futility) in enumerate(looks, start=1):
        out = look_decision(diffs, seeds, alpha, futility, last=k == len(looks))
        if out["stop"] != "continue":
            return {**out, "look": k}
    raise ValueError("looks: at least one look is needed")


def sequential_mde(sd: float, looks, power: float = 0.8, reps: int = 2000, seed: int = 0) -> float:
    """The smallest mean paired difference (0-1, 0.01 grid) the design ``looks`` rejects with probability >=
    ``power`` under Normal(effect, ``sd``) per-seed differences (the same draws for every effect)."""
    return _smallest_effect(lambda cents: sequential_power(cents / 100, sd, looks, reps, seed)["power"] >= power)


def sequential_power(effect: float, sd: float, looks, reps: int = 2000, seed: int = 0) -> dict:
    """Simulated operating characteristics of the design ``looks`` (see :func:`sequential_outcome`) when per-seed
    differences are Normal(effect, sd): the probability of rejecting overall and of stopping at each look."""
    n = looks[-1][0]
    z = np.random.default_rng(seed).normal(0.0, sd, (reps, n)) + effect
    outcomes = [sequential_outcome(row, looks) for row in z]
    out = {"effect": effect, "sd": sd, "reps": reps, "power": float(np.mean([o["reject"] for o in outcomes]))}
    for k in range(1, len(looks) + 1):
        out[f"look_{k}_efficacy"] = float(np.mean([o["look"] == k and o["reject"] for o in outcomes]))
        out[f"look_{k}_futility"] = float(np.mean([o["look"] == k and o["stop"] == "futility" for o in outcomes]))
    return out


def holm(pvalues: list[float]) -> list[float]:
    """Holm-adjusted p-values, in the order given."""
    p = np.asarray(pvalues, dtype=np.float64)
    order = np.argsort(p)
    adjusted = np.empty_like(p)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (p.size - rank) * p[i]))
        adjusted[i] = running
    return adjusted.tolist()


def seed_outcomes(units: list[dict], seeds):
    """``outcomes(variant, setting)``: the per-seed 0/1 test lists of ``units`` in ``seeds``' order, None until every
    seed of that variant is there."""
    by = {(u["variant"], u["seed"]): u for u in units}

    def outcomes(v, setting):
        rows = [by.get((v, s)) for s in seeds]
        return None if any(r is None for r in rows) else [r["test"][setting] for r in rows]

    return outcomes


# --- the report: summaries over seeds and the pictures ------------------------------------------------------------
def seed_level_verdict(diff: float, p_holm: float, alpha: float = 0.05) -> str:
    """v2's rule: "helps" / "hurts" (the sign of the mean paired difference) when Holm's sign-flip p < alpha."""
    if p_holm < alpha and diff != 0:
        return "helps" if diff > 0 else "hurts"
    return "no detectable effect"


def summarise_seed_level(tests: list[dict], variants, seeds, settings, primary, demos: int, reps: int = 4000,
                         holm_adjust: bool = True) -> tuple[list[dict], list[dict]]:
    """The seed-level report from test units (``variant``, ``seed``, ``test`` {setting: 0/1 list}). Table: per
    variant and setting the mean over seeds, its two-level interval, the SD of per-seed success and the fraction
    of seeds below real's worst. Comparisons with real: paired mean difference and interval, exact sign-flip p,
    paired t p, CMH p (secondary). ``primary``: the (variant, setting) comparisons that get a verdict; ``holm_adjust``:
    Holm over them once all are complete (else the caller decides them). reps: bootstrap draws per interval."""
    outcomes = seed_outcomes(tests, seeds)
    primary = {tuple(x) for x in primary}

    table, comparisons = [], []
    for setting in settings:
        real = outcomes("real", setting)
        real_worst = None if real is None else min(float(np.mean(x)) for x in real)
        for v in variants:
            o = outcomes(v, setting)
            if o is None:
                continue
            table.append(_success_row(v, setting, o, real_worst, reps))
            if v == "real" or real is None:
                continue
            diff, ci, per_seed = paired_diff(o, real, reps)
            comparisons.append({"variant": v, "vs": "real", "demos": demos, "setting": setting,
                                "primary": (v, setting) in primary, "diff": round(diff, 4),
                                "ci95": [round(c, 4) for c in ci], "per_seed_diff": [round(d, 4) for d in per_seed],
                                "p_sign_flip": sign_flip_p(per_seed), "p_t": paired_t_p(per_seed),
                                "p_cmh_secondary": cmh_p(o, real), "p_holm": None, "verdict": None})
    prim = [c for c in comparisons if c["primary"]]
    if holm_adjust and len(prim) == len(primary):
        for c, p in zip(prim, holm([c["p_sign_flip"] for c in prim])):
            c["p_holm"] = p
            c["verdict"] = seed_level_verdict(c["diff"], p)
    for c in comparisons:
        c["sentence"] = comparison_sentence(c)
    return table, comparisons


def comparison_sentence(c: dict) -> str:
    """One comparison in words: its verdict (``secondary``, or ``pending`` for a primary one without a verdict yet),
    the mean paired difference with its interval and its p-values."""
    what = c["verdict"] or ("secondary" if not c["primary"] else "pending")
    return (f"{c['variant']} vs real, {c['setting']}: {what} ({c['diff'] * 100:+.1f} points over "
            f"{len(c['per_seed_diff'])} paired seeds, 95 % CI {c['ci95'][0] * 100:+.1f} to "
            f"{c['ci95'][1] * 100:+.1f}, sign-flip p {c['p_sign_flip']:.3g}"
            + (f", Holm {c['p_holm']:.3g})" if c["p_holm"] is not None else ")"))


def _success_row(variant: str, setting: str, outcomes, real_worst: float | None, reps: int) -> dict:
    """One table row: mean success over seeds, its interval, per-seed rates, their SD, the share below real's worst."""
    mean, ci = seed_episode_ci(outcomes, reps)
    rates = [float(np.mean(x)) for x in outcomes]
    return {"variant": variant, "setting": setting, "mean": round(mean, 4), "ci95": [round(c, 4) for c in ci],
            "per_seed": [round(r, 4) for r in rates], "sd_over_seeds": round(float(np.std(rates, ddof=1)), 4),
            "below_real_worst": None if variant == "real" or real_worst is None
            else round(float(np.mean([r < real_worst for r in rates])), 4)}


def plot(table: list[dict], path: Path, variants, settings) -> None:
    """Success per variant (x) and setting (panel): one dot per training seed, the mean and its interval over them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, axes = plt.subplots(1, len(settings), figsize=(4.4 * len(settings), 3.6), sharey=True, squeeze=False)
    by = {(r["variant"], r["setting"]): r for r in table}
    for ax, setting in zip(axes[0], settings):
        for x, v in enumerate(variants):
            r = by.get((v, setting))
            if r is None:
                continue
            jitter = np.linspace(-0.15, 0.15, len(r["per_seed"]))
            ax.scatter(x + jitter, r["per_seed"], s=14, color="tab:gray", alpha=0.8, zorder=2)
            ax.errorbar([x], [r["mean"]], yerr=[[r["mean"] - r["ci95"][0]], [r["ci95"][1] - r["mean"]]], fmt="o",
                        color="tab:red" if v.startswith("fa") else "tab:blue", capsize=4, zorder=3)
        ax.set_xticks(range(len(variants)), variants, rotation=30, fontsize=8)
        ax.set_title(setting)
        ax.set_ylim(-0.03, 1.03)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("test success (dots: seeds; bar: 95 % CI)")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def plot_paired(looks: list[dict], comparisons: list[dict], path: Path) -> None:
    """The primary comparison as the test sees it: each seed's paired difference (a dot, coloured by the look that
    added it), their mean with its 95 % interval, and each analysed look's p against its alpha."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = next((x for x in comparisons if x["primary"]), None)
    done = [lk for lk in looks if lk["complete"]]
    if c is None or not done:
        return
    fig, ax = plt.subplots(figsize=(6.4, 4.0), layout="constrained")
    start = 0
    for lk in done:
        d = c["per_seed_diff"][start:len(lk["seeds"])]
        x = np.asarray(lk["seeds"][start:])  # the training seeds the look added
        ax.scatter(x, np.asarray(d) * 100, s=22, zorder=3, label=f"seeds of look {lk['look']} "
                   f"(p {lk['p']:.3g} vs alpha {lk['alpha']:g}: {lk['stop']})")
        start += len(d)
    ax.axhline(0, color="black", lw=0.8)
    ax.axhspan(c["ci95"][0] * 100, c["ci95"][1] * 100, color="tab:red", alpha=0.15, label="mean, 95 % CI")
    ax.axhline(c["diff"] * 100, color="tab:red", lw=1.5)
    ax.set_xlabel("training seed (both variants trained with it)")
    ax.set_ylabel(f"{c['variant']} - real, points ({c['setting']})")
    fig.legend(fontsize=7, loc="outside lower center", ncols=2)  # below the axes: no dot hidden behind it
    ax.grid(alpha=0.3)
    save_figure(fig, path, dpi=110)
