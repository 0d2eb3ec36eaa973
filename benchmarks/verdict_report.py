"""Statistics and the picture of a multi-seed policy comparison: per-episode outcomes grouped by training seed.

``outcomes`` below is always a list with one 0/1 array per training seed (the episodes that seed's policy
ran); two such lists compared are paired by position (the same training seed, the same episode seeds).

- :func:`seed_episode_ci`: the mean success over seeds with a two-level bootstrap interval (resample the
  seeds, then the episodes within each drawn seed), so it carries both sources of variance.
- :func:`paired_diff`: the mean of the seed-paired differences with the same two-level interval.
- :func:`cmh_p`: the Cochran-Mantel-Haenszel test with one 2x2 table (variant / real x success / failure)
  per training seed. scipy has no CMH test; the statistic is six lines (Agresti, Categorical Data Analysis,
  section 6.3), so no statsmodels dependency for it.
- :func:`sign_flip_p`: ``scipy.stats.permutation_test`` on the per-seed differences (seeds as the units; with
  n seeds its smallest two-sided p is 2 / 2**n, 0.0625 at five).
- :func:`holm`: Holm's step-down adjustment (five lines; scipy has only Benjamini-Hochberg).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _as_seeds(outcomes) -> list[np.ndarray]:
    out = [np.asarray(o, dtype=np.float64).reshape(-1) for o in outcomes]
    if not out or any(o.size == 0 for o in out):
        raise ValueError("outcomes: need at least one seed, each with at least one episode")
    return out


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
    """Two-sided exact p-value of the per-seed differences' mean under random sign flips (seeds as units)."""
    from scipy.stats import permutation_test

    d = np.asarray(diffs, dtype=np.float64)
    if np.all(d == 0):
        return 1.0
    res = permutation_test((d,), np.mean, permutation_type="samples", alternative="two-sided", n_resamples=10_000)
    return float(res.pvalue)


def paired_t_p(diffs) -> float:
    """Two-sided paired t-test p of the per-seed differences (scipy's one-sample t-test against 0); 1.0 when they
    are all equal to 0, 0.0 when they are all one non-zero value."""
    from scipy.stats import ttest_1samp

    d = np.asarray(diffs, dtype=np.float64)
    if np.all(d == d[0]):
        return 1.0 if d[0] == 0 else 0.0
    return float(ttest_1samp(d, 0.0).pvalue)


def _exact_sign_flip_p(d: np.ndarray) -> np.ndarray:
    """Exact two-sided sign-flip p of each row of ``d`` (reps, n): every one of the 2**n sign patterns."""
    n = d.shape[1]
    signs = 1 - 2 * ((np.arange(2 ** n)[:, None] >> np.arange(n)) & 1)
    null = np.abs(signs @ d.T) / n  # (2**n, reps)
    observed = np.abs(d.mean(axis=1))
    return (null >= observed[None, :] - 1e-12).mean(axis=0)


def sign_flip_mde(sd: float, n: int, alpha: float, power: float = 0.8, reps: int = 2000, seed: int = 0) -> float:
    """The smallest mean paired difference (0-1) that the exact sign-flip test over ``n`` seeds detects at
    two-sided ``alpha`` with probability >= ``power``, when per-seed differences are Normal(effect, ``sd``):
    simulated on a 0.01 grid, the same draws for every effect."""
    z = np.random.default_rng(seed).normal(0.0, sd, (reps, n))
    for effect in np.arange(0.0, 1.0001, 0.01):
        if (_exact_sign_flip_p(z + effect) < alpha).mean() >= power:
            return round(float(effect), 2)
    return 1.0


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


def verdict(diff: float, ci95: tuple[float, float], p_holm: float, alpha: float = 0.05) -> str:
    """"helps" / "hurts" when the Holm-adjusted CMH p < alpha and the seed-and-episode interval excludes 0 on
    the same side; otherwise "no detectable effect"."""
    if p_holm < alpha and ci95[0] > 0 and diff > 0:
        return "helps"
    if p_holm < alpha and ci95[1] < 0 and diff < 0:
        return "hurts"
    return "no detectable effect"


def seed_outcomes(units: list[dict], seeds):
    """``outcomes(variant, setting)``: the per-seed 0/1 test lists of ``units`` in ``seeds``' order, None until every
    seed of that variant is there."""
    by = {(u["variant"], u["seed"]): u for u in units}

    def outcomes(v, setting):
        rows = [by.get((v, s)) for s in seeds]
        return None if any(r is None for r in rows) else [r["test"][setting] for r in rows]

    return outcomes


# --- the report: summaries over seeds and the picture ------------------------------------------------------------------------------------------------------
def summarise(policies: list[dict], variants, seeds, settings, demos: int) -> tuple[list[dict], list[dict]]:
    """(per variant and setting: mean over seeds with its interval; per comparison with real: the paired
    difference, its interval, CMH and sign-flip p, Holm, verdict). Only complete (variant, setting) cells."""
    outcomes = seed_outcomes(policies, seeds)

    table, comparisons = [], []
    for setting in settings:
        for v in variants:
            o = outcomes(v, setting)
            if o is not None:
                mean, ci = seed_episode_ci(o)
                table.append({"variant": v, "setting": setting, "mean": round(mean, 4), "ci95": [round(ci[0], 4), round(ci[1], 4)],
                              "per_seed": [round(sum(x) / len(x), 4) for x in o]})
        real = outcomes("real", setting)
        for v in [x for x in variants if x != "real"]:
            o = outcomes(v, setting)
            if o is None or real is None:
                continue
            diff, ci, per_seed = paired_diff(o, real)
            comparisons.append({"variant": v, "vs": "real", "demos": demos, "setting": setting, "diff": round(diff, 4),
                                "ci95": [round(ci[0], 4), round(ci[1], 4)], "per_seed_diff": [round(d, 4) for d in per_seed],
                                "p": cmh_p(o, real), "p_sign_flip": sign_flip_p(per_seed)})
    for c, p in zip(comparisons, holm([c["p"] for c in comparisons])):
        c["p_holm"] = p
        c["verdict"] = verdict(c["diff"], c["ci95"], p)
        c["sentence"] = (f"{c['variant']} vs real, {c['setting']}: {c['verdict']} "
                         f"({c['diff'] * 100:+.1f} points, 95 % CI {c['ci95'][0] * 100:+.1f} to {c['ci95'][1] * 100:+.1f}, "
                         f"p_holm {p:.3g})")
    return table, comparisons


def seed_level_verdict(diff: float, p_holm: float, alpha: float = 0.05) -> str:
    """v2's rule: "helps" / "hurts" (the sign of the mean paired difference) when Holm's sign-flip p < alpha."""
    if p_holm < alpha and diff != 0:
        return "helps" if diff > 0 else "hurts"
    return "no detectable effect"


def summarise_seed_level(tests: list[dict], variants, seeds, settings, primary, demos: int, reps: int = 4000
                         ) -> tuple[list[dict], list[dict]]:
    """v2's report from its test units (``variant``, ``seed``, ``test`` {setting: 0/1 list}). Table: per variant and
    setting the mean over seeds, its two-level interval, the SD of per-seed success and the fraction of seeds
    below real's worst. Comparisons with real: paired mean difference and interval, exact sign-flip p (primary),
    paired t p, CMH p (secondary); Holm over the ``primary`` variants' comparisons once all are complete.
    reps: bootstrap draws per interval."""
    outcomes = seed_outcomes(tests, seeds)

    table, comparisons = [], []
    for setting in settings:
        real = outcomes("real", setting)
        real_worst = None if real is None else min(float(np.mean(x)) for x in real)
        for v in variants:
            o = outcomes(v, setting)
            if o is None:
                continue
            mean, ci = seed_episode_ci(o, reps)
            rates = [float(np.mean(x)) for x in o]
            table.append({"variant": v, "setting": setting, "mean": round(mean, 4), "ci95": [round(c, 4) for c in ci],
                          "per_seed": [round(r, 4) for r in rates], "sd_over_seeds": round(float(np.std(rates, ddof=1)), 4),
                          "below_real_worst": None if v == "real" or real_worst is None
                          else round(float(np.mean([r < real_worst for r in rates])), 4)})
            if v == "real" or real is None:
                continue
            diff, ci, per_seed = paired_diff(o, real, reps)
            comparisons.append({"variant": v, "vs": "real", "demos": demos, "setting": setting, "primary": v in primary,
                                "diff": round(diff, 4), "ci95": [round(c, 4) for c in ci],
                                "per_seed_diff": [round(d, 4) for d in per_seed], "p_sign_flip": sign_flip_p(per_seed),
                                "p_t": paired_t_p(per_seed), "p_cmh_secondary": cmh_p(o, real), "p_holm": None})
    prim = [c for c in comparisons if c["primary"]]
    if len(prim) == len(primary) * len(settings):
        for c, p in zip(prim, holm([c["p_sign_flip"] for c in prim])):
            c["p_holm"] = p
    for c in comparisons:
        c["verdict"] = seed_level_verdict(c["diff"], c["p_holm"]) if c["p_holm"] is not None else None
        what = c["verdict"] or ("secondary" if not c["primary"] else "pending")
        c["sentence"] = (f"{c['variant']} vs real, {c['setting']}: {what} ({c['diff'] * 100:+.1f} points over "
                         f"{len(c['per_seed_diff'])} paired seeds, 95 % CI {c['ci95'][0] * 100:+.1f} to "
                         f"{c['ci95'][1] * 100:+.1f}, sign-flip p {c['p_sign_flip']:.3g}"
                         + (f", Holm {c['p_holm']:.3g})" if c["p_holm"] is not None else ")"))
    return table, comparisons


def plot(table: list[dict], path: Path, variants, settings) -> None:
    """Success per variant (x) and setting (panel): one dot per training seed, the mean and its interval over them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from controltac_il.io import atomic_path

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
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
