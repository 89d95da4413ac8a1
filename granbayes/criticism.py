"""Model criticism: what the simulation gets wrong, which physics is missing, and the gain.

:func:`diagnose` runs the loop of the "model-criticism" issue on measured jumps:

1. fit the baseline law (default: the thesis's depth-only law with the bed's default
   unloading), one parameter set per volume fraction shared by all commands;
2. show what it gets wrong: posterior predictive residuals per command x phi x frequency
   cell, each with a z-score and a two-sided predictive p-value of the cell mean
   (:func:`residual_table`); cells beyond the significance threshold are *misfit*;
3. name the cause: every other term of the library is added to the current law and fitted;
   candidates are compared by PSIS-LOO (ELPD difference and its standard error; where
   Pareto k > 0.7 the comparison falls back to K-fold cross-validation);
4. extend and measure the gain, forward: a term is added only when the evidence is clear
   (the selection rule below); if misfit cells remain, a second round looks for a second
   effect.

Selection rule (documented in the report and in ``diagnosis.json``): the best candidate of
a round is added when its ELPD gain over the current law exceeds both ``min_gain`` (4 nats)
and ``se_factor`` (2) times the standard error of the difference, **and** the current law
shows misfit (at least one significant cell) or the gain exceeds ``strong_gain``
(10 nats). Otherwise the current law is adequate. False discoveries are as bad as misses:
with no hidden effect, LOO penalises the extra parameter and the rule keeps the baseline.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from . import datatree as gdt
from .experiment import Experiment
from .fit import FitConfig, FitResult, fit
from .forces import TERMS, terms_of
from .likelihood import Observations
from .priors import Prior
from .sampler import SamplerSettings

__all__ = ["DiagnoseConfig", "Diagnosis", "diagnose", "residual_table", "describe_cell"]


def _screening_sampler() -> SamplerSettings:
    return SamplerSettings(n_walkers=16, check_every=100, tau_factor=30, n_draws=100)


@dataclass(frozen=True)
class DiagnoseConfig:
    """Settings of the criticism loop.

    Parameters
    ----------
    baseline : tuple of str
        Terms of the baseline law.
    candidates : tuple of str, optional
        Terms to try (default: every library term not in the baseline).
    sampler : SamplerSettings
        MCMC settings of every fit (screening settings: chains of >= 30 tau).
    max_added : int
        Most terms added by forward selection.
    min_gain, se_factor, strong_gain : float
        The selection rule (module docstring) [nats, -, nats].
    z_threshold : float
        A cell is misfit when its lack-of-fit |z| exceeds this (default 3.5: with 50
        cells, a false alarm somewhere has probability of about 2-3% under a correct law).
    kfold : int
        Folds of the K-fold fallback.
    max_refits : int
        Jumps with Pareto k > 0.7 recomputed by exact leave-one-out refits; beyond this
        number, K-fold cross-validation is used instead.
    """

    baseline: tuple[str, ...] = ("depth",)
    candidates: tuple[str, ...] | None = None
    sampler: SamplerSettings = field(default_factory=_screening_sampler)
    max_added: int = 2
    min_gain: float = 4.0
    se_factor: float = 2.0
    strong_gain: float = 10.0
    z_threshold: float = 3.5
    kfold: int = 5
    max_refits: int = 10
    n_threads: int | None = None

    def candidate_terms(self, current: Sequence[str]) -> list[str]:
        """Terms that may still be added to ``current``."""
        pool = self.candidates if self.candidates is not None else tuple(TERMS)
        return [t for t in terms_of(pool) if t not in current and not TERMS[t].required]


@dataclass
class Diagnosis:
    """Result of :func:`diagnose` (``to_json`` gives ``diagnosis.json``)."""

    baseline: FitResult
    selected: FitResult
    residuals_before: pd.DataFrame
    residuals_after: pd.DataFrame
    candidates: list[dict]
    added: list[str]
    record: dict
    fits: dict[tuple[str, ...], FitResult]

    @property
    def verdict(self) -> str:
        """``"extended"`` or ``"baseline_adequate"``."""
        return self.record["verdict"]

    def to_json(self) -> dict:
        """The ``diagnosis.json`` document (shared/data-format.md)."""
        return self.record


# ----------------------------------------------------------------------------------------
def residual_table(result: FitResult) -> pd.DataFrame:
    """Residuals of the fitted law per (command, phi, freq_hz) cell, with significance.

    For each cell of ``n`` repeated jumps: the observed mean, the posterior mean of the
    simulated height and ``mean_residual_mm`` = observed - simulated. Two standardised
    statistics separate real misfit from noise:

    ``z`` (lack of fit, used for decisions)
        the residual over ``sqrt(s^2 / n + var_post(simulated))``, where ``s^2`` is the
        trial-to-trial variance *measured* from the repeated jumps (pooled over the cells
        at the same volume fraction) rather than the model's fitted scatter, which a wrong
        law inflates to absorb its own misfit; ``p_value`` is its two-sided Student-t tail
        probability (pooled degrees of freedom). Without repeated jumps the predictive
        statistics below are used instead.
    ``z_predictive``, ``p_predictive``
        the observed cell mean against the posterior predictive distribution of the mean
        of ``n`` replicated jumps (model scatter included).

    Returns
    -------
    pandas.DataFrame
        One row per cell, worst (largest |z|) first.
    """
    dt = result.datatree
    obs = dt.observed_data.to_dataset()
    pp = dt.posterior_predictive.to_dataset()
    y = obs["height_mm"].values
    rep = pp["height_mm"].values.reshape(-1, len(y))
    sim = pp["height_sim_mm"].values.reshape(-1, len(y))
    cells = pd.DataFrame(
        {
            "command": obs["command"].values,
            "phi": obs["phi"].values.astype(float),
            "freq_hz": obs["freq_hz"].values.astype(float) if "freq_hz" in obs.coords else 0.0,
            "y": y,
        }
    )
    keys = ["command", "phi", "freq_hz"]
    cells["dev2"] = (cells["y"] - cells.groupby(keys)["y"].transform("mean")) ** 2
    cells["dof"] = cells.groupby(keys)["y"].transform("size") - 1
    pooled = {}
    for phi, g in cells.groupby("phi"):
        dof = float(g.groupby(keys)["dof"].first().sum())
        pooled[phi] = (float(g["dev2"].sum()) / dof, dof) if dof > 0 else (np.nan, 0.0)
    rows = []
    for (command, phi, freq), idx in cells.groupby(keys).indices.items():
        idx = np.asarray(idx)
        n = len(idx)
        y_mean = float(np.mean(y[idx]))
        rep_mean = rep[:, idx].mean(axis=1)
        sim_cell = sim[:, idx].mean(axis=1)
        sim_mean = float(np.mean(sim_cell))
        sd_pred = float(np.std(rep_mean))
        z_pred = (y_mean - float(np.mean(rep_mean))) / sd_pred if sd_pred > 0 else np.inf
        tail = min(np.mean(rep_mean >= y_mean), np.mean(rep_mean <= y_mean))
        # the Monte Carlo p-value resolves 1/draws; beyond it, the normal tail of z
        p_pred = min(1.0, 2.0 * tail if tail > 0 else 2.0 * stats.norm.sf(abs(z_pred)))
        s2, dof = pooled[phi]
        if dof > 0:
            se = math.sqrt(s2 / n + float(np.var(sim_cell)))
            z = (y_mean - sim_mean) / se if se > 0 else np.inf
            p = float(2.0 * stats.t.sf(abs(z), dof))
        else:
            z, p = z_pred, p_pred
        rows.append(
            {
                "command": command,
                "phi": phi,
                "freq_hz": freq,
                "n": n,
                "observed_mm": y_mean,
                "simulated_mm": sim_mean,
                "mean_residual_mm": y_mean - sim_mean,
                "z": z,
                "p_value": p,
                "z_predictive": z_pred,
                "p_predictive": p_pred,
            }
        )
    table = pd.DataFrame(rows)
    order = table["z"].abs().sort_values(ascending=False).index
    return table.reindex(order).reset_index(drop=True)


def describe_cell(row: Mapping) -> str:
    """A misfit cell in words, e.g. "delayed stutter preload at phi = 0.592 (12 Hz) is
    under-predicted by 18.1 mm (z = 5.3)"."""
    verb = "under-predicted" if row["mean_residual_mm"] > 0 else "over-predicted"
    freq = f" ({row['freq_hz']:g} Hz)" if row.get("freq_hz") else ""
    return (
        f"{str(row['command']).replace('_', ' ')} at phi = {row['phi']:g}{freq} is {verb} "
        f"by {abs(row['mean_residual_mm']):.1f} mm (z = {row['z']:+.1f})"
    )


def rmse_mm(result: FitResult) -> float:
    """Root-mean-square of observed minus posterior-mean simulated height [mm]."""
    dt = result.datatree
    y = dt.observed_data["height_mm"].values
    sim = dt.posterior_predictive["height_sim_mm"].values.reshape(-1, len(y)).mean(axis=0)
    return float(np.sqrt(np.mean((y - sim) ** 2)))


# ----------------------------------------------------------------------------------------
def _elpd(result: FitResult) -> dict:
    return gdt.loo(result.datatree)


def _log_predictive(part, rows: pd.DataFrame) -> np.ndarray:
    """log p(y_i | data of the fit) for held-out jumps ``rows`` under a fitted run."""
    obs = Observations.from_table(rows)
    model = part.model
    flat = part.run.samples.reshape(-1, part.run.samples.shape[-1])
    heights, ok = model.predict(flat, obs)
    mean = heights[:, obs.config_of_obs]
    phi_index = np.searchsorted(model.phis, obs.table["phi"].to_numpy(float))
    sigma = model.parameter_values(flat)["sigma_mm"][:, phi_index]
    r = (obs.height_mm[None, :] - mean) / sigma
    if model.noise == "normal":
        ll = -0.5 * r * r - np.log(sigma) - 0.5 * math.log(2 * math.pi)
    else:
        ll = stats.t.logpdf(r, model.nu) - np.log(sigma)
    ll[~ok] = -np.inf
    return np.logaddexp.reduce(ll, axis=0) - math.log(len(ll))


def _heldout_fit(experiment, train, config, priors, seed):
    return fit(experiment, train, config, seed=seed, priors=priors)


def _exact_loo(
    experiment: Experiment,
    table: pd.DataFrame,
    config: FitConfig,
    priors: Mapping[str, Prior] | None,
    seed: int,
    points: Sequence[int],
) -> dict[int, float]:
    """Exact leave-one-out ELPD of the given jumps: one refit per jump without it.

    Only the jump's own volume fraction is refitted (``per_phi`` fits are independent).
    """
    out = {}
    for j in points:
        phi = table.loc[j, "phi"]
        train = table[(table["phi"] == phi) & (table.index != j)]
        res = _heldout_fit(experiment, train, config, priors, seed + 7919 * (j + 1))
        out[j] = float(_log_predictive(res.parts[0], table.loc[[j]])[0])
    return out


def _kfold_elpd_i(
    experiment: Experiment,
    table: pd.DataFrame,
    config: FitConfig,
    priors: Mapping[str, Prior] | None,
    seed: int,
    k: int,
) -> np.ndarray:
    """Pointwise K-fold ELPD: each jump predicted by a fit without its fold (stratified)."""
    rng = np.random.default_rng(seed)
    folds = np.empty(len(table), dtype=int)
    for _, idx in table.groupby(["phi", "command"]).indices.items():
        folds[idx] = rng.permutation(len(idx)) % k
    elpd_i = np.empty(len(table))
    for f in range(k):
        res = _heldout_fit(experiment, table[folds != f], config, priors, seed + 101 * (f + 1))
        for part in res.parts:
            sel = (folds == f) & (table["phi"] == float(part.model.phis[0])).to_numpy()
            if np.any(sel):
                elpd_i[sel] = _log_predictive(part, table[sel])
    return elpd_i


def diagnose(
    experiment: Experiment,
    table: pd.DataFrame,
    config: DiagnoseConfig | None = None,
    *,
    seed: int = 0,
    priors: Mapping[str, Prior] | None = None,
    data_source: str = "",
    log=print,
) -> Diagnosis:
    """Run the criticism loop (module docstring) on measured jumps.

    Parameters
    ----------
    experiment : Experiment
        Robot, command defaults and ``phi_c``.
    table : pandas.DataFrame
        Validated jumps (:func:`granbayes.load_jumps`).
    config : DiagnoseConfig, optional
        Baseline, candidates, MCMC settings and the selection rule.
    seed : int
        Master seed (recorded).
    priors : mapping, optional
        Prior overrides.
    data_source : str
        Where the data came from.
    log : callable
        Progress messages (``print`` by default; pass ``lambda *a: None`` to silence).

    Returns
    -------
    Diagnosis
    """
    cfg = config or DiagnoseConfig()
    table = table.reset_index(drop=True)
    fits: dict[tuple[str, ...], FitResult] = {}
    loos: dict[tuple[str, ...], dict] = {}
    sources: dict[tuple[str, ...], str] = {}

    def run(terms: Sequence[str]) -> FitResult:
        key = terms_of(terms)
        if key not in fits:
            log(f"  fitting {' + '.join(key)} ...")
            fc = FitConfig(terms=key, sampler=cfg.sampler, n_threads=cfg.n_threads)
            fits[key] = fit(
                experiment, table, fc, seed=seed, priors=priors, data_source=data_source
            )
            loos[key] = _elpd(fits[key])
            sources[key] = "psis-loo"
        return fits[key]

    exact: dict[tuple[str, ...], dict[int, float]] = {}

    def pointwise(keys: Sequence[tuple[str, ...]]) -> tuple[list[np.ndarray], str]:
        """Pointwise ELPD of models compared together, with the PSIS-LOO fallbacks.

        Jumps with Pareto k > 0.7 in any of the models are recomputed for all of them:
        by exact refits when there are at most ``max_refits`` such jumps, otherwise by
        K-fold cross-validation of the whole data set.
        """
        bad = sorted(
            set().union(*(np.flatnonzero(loos[k]["pareto_k"] > 0.7).tolist() for k in keys))
        )
        if not bad:
            return [loos[k]["elpd_i"] for k in keys], "psis-loo"
        if len(bad) > cfg.max_refits:
            for k in keys:
                if sources[k] != "kfold":
                    log(f"  {len(bad)} jumps with Pareto k > 0.7: {cfg.kfold}-fold CV ...")
                    fc = FitConfig(terms=k, sampler=cfg.sampler, n_threads=cfg.n_threads)
                    kf = _kfold_elpd_i(experiment, table, fc, priors, seed, cfg.kfold)
                    loos[k] = {**loos[k], "elpd_i_kfold": kf}
                    sources[k] = "kfold"
            return [loos[k]["elpd_i_kfold"] for k in keys], "kfold"
        out = []
        for k in keys:
            done = exact.setdefault(k, {})
            todo = [j for j in bad if j not in done]
            if todo:
                log(f"  exact leave-one-out refits of {len(todo)} jump(s) for {' + '.join(k)}")
                fc = FitConfig(terms=k, sampler=cfg.sampler, n_threads=cfg.n_threads)
                done.update(_exact_loo(experiment, table, fc, priors, seed, todo))
            e = loos[k]["elpd_i"].copy()
            e[bad] = [done[j] for j in bad]
            out.append(e)
        return out, f"psis-loo + {len(bad)} exact refit(s)"

    log(f"Baseline: {' + '.join(terms_of(cfg.baseline))}")
    base_key = terms_of(cfg.baseline)
    baseline = run(base_key)
    residuals_before = residual_table(baseline)
    current_key = base_key
    current = baseline
    added: list[str] = []
    candidates: list[dict] = []
    for round_no in range(1, cfg.max_added + 1):
        misfit = residuals_before if round_no == 1 else residual_table(current)
        n_misfit = int((misfit["z"].abs() > cfg.z_threshold).sum())
        pool = cfg.candidate_terms(current_key)
        if not pool:
            break
        if round_no > 1 and n_misfit == 0:
            log("  no misfit cell remains: no second round")
            break
        log(f"Round {round_no}: trying {', '.join(pool)}")
        entries = []
        for term in pool:  # PSIS-LOO screening of every candidate
            key = terms_of((*current_key, term))
            res = run(key)
            diff, se = gdt.elpd_difference(loos[key]["elpd_i"], loos[current_key]["elpd_i"])
            base_diff, base_se = gdt.elpd_difference(loos[key]["elpd_i"], loos[base_key]["elpd_i"])
            flagged = bool(loos[key]["n_bad_k"] or loos[current_key]["n_bad_k"])
            entry = {
                "added": [*added, term],
                "round": round_no,
                "elpd": loos[key]["elpd"],
                "elpd_diff": base_diff,
                "elpd_diff_se": base_se,
                "elpd_diff_vs_current": diff,
                "elpd_diff_vs_current_se": se,
                "rmse_mm": rmse_mm(res),
                "max_pareto_k": loos[key]["max_pareto_k"],
                "method": "psis-loo (Pareto k > 0.7, not decisive)" if flagged else "psis-loo",
                "_key": key,
            }
            entries.append(entry)
        # the decision rests on the best candidate (and a runner-up within 2 SE of it):
        # where Pareto k is bad, recompute those comparisons with exact refits or K-fold
        entries.sort(key=lambda e: -e["elpd_diff_vs_current"])
        decisive = entries[:1] + [
            e
            for e in entries[1:2]
            if entries[0]["elpd_diff_vs_current"] - e["elpd_diff_vs_current"]
            < 2.0 * max(entries[0]["elpd_diff_vs_current_se"], e["elpd_diff_vs_current_se"])
        ]
        for e in decisive:
            if e["method"] == "psis-loo":
                continue
            (e_key, e_cur, e_base), method = pointwise((e["_key"], current_key, base_key))
            e["elpd"] = float(np.sum(e_key))
            e["elpd_diff_vs_current"], e["elpd_diff_vs_current_se"] = gdt.elpd_difference(
                e_key, e_cur
            )
            e["elpd_diff"], e["elpd_diff_se"] = gdt.elpd_difference(e_key, e_base)
            e["method"] = method
        for e in entries:
            log(
                f"    + {e['added'][-1]:<11} elpd gain {e['elpd_diff_vs_current']:+7.1f} ± "
                f"{e['elpd_diff_vs_current_se']:4.1f}   rmse {e['rmse_mm']:.2f} mm "
                f"({e['method']})"
            )
            del e["_key"]
        candidates.extend(entries)
        best = max(decisive, key=lambda e: e["elpd_diff_vs_current"])
        gain, se = best["elpd_diff_vs_current"], best["elpd_diff_vs_current_se"]
        clear = gain > cfg.min_gain and gain > cfg.se_factor * se
        if not (clear and (n_misfit > 0 or gain > cfg.strong_gain)):
            log(f"  no clear gain (best: +{best['added'][-1]}, {gain:+.1f} ± {se:.1f})")
            break
        added.append(best["added"][-1])
        current_key = terms_of((*current_key, best["added"][-1]))
        current = fits[current_key]
        log(f"  added {best['added'][-1]}")
    residuals_after = residual_table(current)
    if current_key == base_key:
        gain = (0.0, 0.0, "none added")
    else:
        (e_cur, e_base), method = pointwise((current_key, base_key))
        gain = (*gdt.elpd_difference(e_cur, e_base), method)
    record = _record(
        cfg,
        baseline,
        current,
        base_key,
        current_key,
        loos,
        sources,
        residuals_before,
        residuals_after,
        candidates,
        added,
        seed,
        data_source,
        gain,
    )
    return Diagnosis(
        baseline, current, residuals_before, residuals_after, candidates, added, record, fits
    )


def _interval(values: np.ndarray, ci_prob: float) -> list[float]:
    q = [(1 - ci_prob) / 2, 0.5, 1 - (1 - ci_prob) / 2]
    return [float(v) for v in np.nanquantile(values, q)]


def _record(
    cfg,
    baseline,
    current,
    base_key,
    current_key,
    loos,
    sources,
    before,
    after,
    candidates,
    added,
    seed,
    data_source,
    gain,
) -> dict:
    gain, gain_se, gain_method = gain
    misfit = before[before["z"].abs() > cfg.z_threshold]
    keys = ["command", "phi", "freq_hz"]
    merged = before.merge(after, on=keys, suffixes=("_before", "_after"))
    per_cell = [
        {
            "command": r.command,
            "phi": float(r.phi),
            "freq_hz": float(r.freq_hz),
            "residual_before_mm": float(r.mean_residual_mm_before),
            "residual_after_mm": float(r.mean_residual_mm_after),
            "z_before": float(r.z_before),
            "z_after": float(r.z_after),
        }
        for r in merged.itertuples()
    ]
    post = current.datatree.posterior.to_dataset()
    new_params = {}
    for term in added:
        for p in TERMS[term].parameters:
            new_params[p.name] = {
                f"{float(phi):g}": _interval(post[p.name].sel(phi=phi).values.ravel(), gdt.CI_PROB)
                for phi in post["phi"].values
            }
    return {
        "baseline": {
            "terms": list(base_key),
            "elpd": float(loos[base_key]["elpd"]),
            "elpd_se": float(loos[base_key]["se"]),
            "rmse_mm": rmse_mm(baseline),
            "method": sources[base_key],
        },
        "misfit": [
            {
                "command": r.command,
                "phi": float(r.phi),
                "freq_hz": float(r.freq_hz),
                "n": int(r.n),
                "mean_residual_mm": float(r.mean_residual_mm),
                "z": float(r.z),
                "p_value": float(r.p_value),
                "significant": bool(abs(r.z) > cfg.z_threshold),
                "description": describe_cell(r._asdict()),
            }
            for r in before.itertuples()
        ],
        "n_misfit_cells": len(misfit),
        "candidates": candidates,
        "verdict": "extended" if added else "baseline_adequate",
        "selected": {
            "terms": list(current_key),
            "added": list(added),
            "elpd_gain": gain,
            "elpd_gain_se": gain_se,
            "elpd_method": gain_method,
            "rmse_before_mm": rmse_mm(baseline),
            "rmse_after_mm": rmse_mm(current),
            "parameters": new_params,
            "interval": f"{gdt.CI_PROB:.0%} equal-tailed (5%, 50%, 95% quantiles)",
            "per_cell": per_cell,
        },
        "rule": {
            "min_gain": cfg.min_gain,
            "se_factor": cfg.se_factor,
            "strong_gain": cfg.strong_gain,
            "z_threshold": cfg.z_threshold,
            "text": (
                f"add the best candidate when its ELPD gain > {cfg.min_gain:g} and > "
                f"{cfg.se_factor:g} SE, and the current law has a cell with |z| > "
                f"{cfg.z_threshold:g} or the gain exceeds {cfg.strong_gain:g}; at most "
                f"{cfg.max_added} terms"
            ),
        },
        "seed": int(seed),
        "data_source": data_source,
    }
