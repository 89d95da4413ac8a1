"""Posterior summaries of a fit: tables, diagnostics, identifiability, analyses' summaries."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence

import arviz_stats as azs
import numpy as np
import pandas as pd
import xarray as xr
from numpy.typing import ArrayLike
from scipy.stats import rankdata

from ._intervals import CI_PROB, interval


def run_diagnostics(dt: xr.DataTree) -> pd.DataFrame:
    """Per sampler run of a fit: ensembles, steps, largest tau, R-hat, ESS, convergence.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit's DataTree (reads only its ``runs`` attribute).

    Returns
    -------
    pandas.DataFrame
        One row per run; ``tau_max`` [steps] over ensembles and coordinates,
        ``steps_over_tau`` the shortest post-burn-in chain in autocorrelation times,
        ``rhat_max`` across ensembles, ``ess_min`` the smallest bulk or tail ESS.
    """
    rows = []
    for run in json.loads(dt.attrs["runs"]):
        tau = np.asarray(run["tau"], dtype=float)
        burn = np.asarray(run["burn"], dtype=float)
        tau_max = float(np.nanmax(tau)) if np.any(np.isfinite(tau)) else np.nan
        per_ens = (
            np.array([_finite_max(row) for row in tau]) if tau.ndim == 2 else np.array([tau_max])
        )
        steps = (run["n_steps"] - burn) / per_ens
        rows.append(
            {
                "run": run["label"],
                "n_ensembles": run["n_ensembles"],
                "n_chains": run["n_chains"],
                "n_steps": run["n_steps"],
                "tau_max": tau_max,
                # NaN where no ensemble has a tau estimate yet (a short, capped run)
                "steps_over_tau": -_finite_max(-steps),
                "rhat_max": _finite_max(run["rhat"]) if run["rhat"] else np.nan,
                "ess_min": -_finite_max(-np.asarray([*run["ess_bulk"], *run["ess_tail"]], float)),
                "acceptance": run["acceptance"],
                "converged": run["converged"],
                "warnings": "; ".join(run["warnings"]),
            }
        )
    return pd.DataFrame(rows)


def _finite_max(values: np.ndarray) -> float:
    """The largest finite value (NaN if there is none), without a warning."""
    values = np.asarray(values, dtype=float)
    finite = values[np.isfinite(values)]
    return float(finite.max()) if finite.size else float("nan")


def summary_table(
    dt: xr.DataTree, var_names: Sequence[str] | None = None, ci_prob: float = CI_PROB
) -> pd.DataFrame:
    """Posterior summary with equal-tailed intervals, R-hat and ESS.

    ``r_hat`` is the rank-normalised split R-hat **across the independent ensembles** of
    the parameter's run, the statistic of the stopping rule, read from the fit's ``runs``
    record. ArviZ's own R-hat would take every walker as an independent chain; the walkers
    of one ensemble move together (each proposal uses the others), which inflates it
    without saying anything about convergence (1.55 for every parameter of a converged
    run of 4 ensembles of 52 walkers, 150 steps). Where a row has no recorded value (the
    values of a run over several volume fractions: ``quadratic`` laws, a pooled robot)
    it is ArviZ's R-hat of the draws regrouped by ensemble (:func:`by_ensemble`), the
    same statistic (within 1e-4 of the record where both exist); for a DataTree made
    elsewhere, without ensembles, ArviZ's value is kept. ESS and MCSE are ArviZ's, over
    the walkers as chains (as the stopping rule's ESS).

    Parameters
    ----------
    dt : xarray.DataTree
        Result with a ``posterior`` group.
    var_names : sequence of str, optional
        Variables to summarise (default: all).
    ci_prob : float
        Probability of the equal-tailed interval (named in the column headers).

    Returns
    -------
    pandas.DataFrame
    """
    table = azs.summary(dt, var_names=var_names, ci_prob=ci_prob, ci_kind="eti")
    recorded = _ensemble_rhat(dt)
    missing = [row for row in table.index if row not in recorded]
    if missing and _n_ensembles(dt) is not None:
        names = list(dict.fromkeys(row.split("[")[0] for row in missing))
        regrouped = azs.summary(
            by_ensemble(dt), var_names=names, kind="diagnostics", round_to="none"
        )["r_hat"]
        recorded |= {row: float(regrouped[row]) for row in missing if row in regrouped.index}
    for row, value in recorded.items():
        if row in table.index:
            table.loc[row, "r_hat"] = value
    return table


def _ensemble_rhat(dt: xr.DataTree) -> dict[str, float]:
    """R-hat across ensembles per summary row (``"k[0.592]"``) from the ``runs`` record."""
    out: dict[str, float] = {}
    for run in json.loads(dt.attrs.get("runs", "[]")):
        label, rhat = run["label"], run.get("rhat") or []
        if not label.startswith("phi=") or len(rhat) != len(run["coordinates"]):
            continue
        phi = label.removeprefix("phi=")
        for name, value in zip(run["coordinates"], rhat, strict=True):
            base = name.split("[")[0]
            out[f"{base}[{phi}]"] = float(value)
    return out


def by_ensemble(dt: xr.DataTree, group: str = "posterior") -> xr.Dataset:
    """A fit's draws with one chain per independent *ensemble* instead of per walker.

    The walkers of an ensemble move together (each proposal uses the others), so they are
    not independent chains; the ensembles, started apart, are. Chain ``e`` holds ensemble
    ``e``'s kept draws in step order, its walkers inside each step (the chains of the
    stopping rule's R-hat, :mod:`granbayes._sampler`). Where the runs of a fit kept
    different numbers of ensembles (a stuck ensemble dropped), the walkers stay the chains.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit's DataTree (its ``runs`` attribute gives the ensembles).
    group : str
        The group to re-chunk.

    Returns
    -------
    xarray.Dataset
        Dimensions ``chain`` (ensembles), ``draw`` (walkers x draws), then the variables' own.
    """
    ds = dt[group].to_dataset()
    n_ens = _n_ensembles(dt)
    if n_ens is None:
        return ds
    walkers, n_draw = ds.sizes["chain"] // n_ens, ds.sizes["draw"]

    def regroup(da: xr.DataArray) -> xr.DataArray:
        v = da.transpose("chain", "draw", ...).values
        v = v.reshape(n_ens, walkers, n_draw, *v.shape[2:]).swapaxes(1, 2)
        other = [d for d in da.dims if d not in ("chain", "draw")]
        return xr.DataArray(
            v.reshape(n_ens, n_draw * walkers, *v.shape[3:]),
            dims=("chain", "draw", *other),
            coords={d: da.coords[d] for d in other if d in da.coords},
            attrs=da.attrs,
        )

    out = xr.Dataset({name: regroup(da) for name, da in ds.data_vars.items()})
    return out.assign_coords(chain=np.arange(n_ens), draw=np.arange(n_draw * walkers))


def rank_test_draws(dt: xr.DataTree, var_names: Sequence[str], step: int) -> xr.Dataset:
    """Draws of a fit for a rank test across ensembles: one walker in turn every ``step``.

    Per independent ensemble, kept draw ``k * step`` of walker ``k mod walkers``: the
    multi-chain rank test assumes independent draws, and an ensemble's walkers are not
    independent of each other even at one step (each proposal is built from the others'
    positions), nor along a walker within its autocorrelation time. Measured on a Gaussian
    target sampled like a fit (``benchmarks/rank_test_calibration.py``, 90 null
    p-values, ``step`` the draws over the smallest ESS as the rank plot takes it): every
    walker's draws thinned by ``step`` reject at alpha = 0.01 in 4 of 90, at 0.05 in 17;
    one walker in turn in 0 and 1 of 90 (at 0.2 in 11: conservative, for 12 draws per
    ensemble). Where the ensembles cannot be told apart
    (:func:`granbayes.stats.by_ensemble`), every walker is a chain, thinned by ``step``.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit (chains: walkers, ensemble by ensemble).
    var_names : sequence of str
        Parameters to keep.
    step : int
        Kept draws between two draws taken (>= 1): the autocorrelation time in kept draws.

    Returns
    -------
    xarray.Dataset
        Dimensions ``chain`` (ensembles), ``draw``, then the variables' own.
    """
    post = dt.posterior.to_dataset()[list(var_names)]
    step = max(1, int(step))
    n_ens = _n_ensembles(dt)
    if n_ens is None:
        return post.isel(draw=slice(None, None, step))
    walkers = post.sizes["chain"] // n_ens
    draws = np.arange(0, post.sizes["draw"], step)
    chains = np.arange(n_ens)[:, None] * walkers + np.arange(len(draws))[None, :] % walkers
    picked = {
        name: da.transpose("chain", "draw", ...).values[chains, draws[None, :]]
        for name, da in post.data_vars.items()
    }
    return xr.Dataset(
        {
            name: (("chain", "draw", *post[name].dims[2:]), values)
            for name, values in picked.items()
        },
        coords={d: post.coords[d] for d in post.coords if d not in ("chain", "draw")},
    ).assign_coords(chain=np.arange(n_ens), draw=np.arange(len(draws)))


#: Verdicts on the posterior-to-prior contraction ``1 - var_post / var_prior``: the first
#: level whose upper bound the contraction stays below.
IDENTIFIABILITY_LEVELS: tuple[tuple[float, str], ...] = (
    (0.1, "not identified: posterior ~ prior"),
    (0.5, "weakly identified: the prior still shapes the posterior"),
    (0.9, "identified"),
    (math.inf, "well identified: the data dominate the prior"),
)


def _n_ensembles(dt: xr.DataTree) -> int | None:
    """How many independent ensembles a fit's chains (walkers, ensemble by ensemble) form.

    None where the runs of the fit kept different numbers of ensembles (a stuck ensemble
    dropped) or do not say: then the walkers cannot be grouped.
    """
    runs = json.loads(dt.attrs.get("runs", "[]"))
    shapes = {(r["n_ensembles"], r["n_chains"]) for r in runs}
    if len(shapes) != 1:
        return None
    ((n_ens, n_chains),) = shapes
    n_chain = dt.posterior.sizes["chain"]
    if n_chains != n_chain or n_chain % n_ens:
        return None
    return int(n_ens)


def identifiability_table(
    dt: xr.DataTree,
    var_names: Sequence[str] | None = None,
    *,
    prior_sd: Mapping[str, float] | None = None,
) -> pd.DataFrame:
    """What the data determine: posterior-to-prior contraction per parameter and phi.

    The contraction ``1 - var_post / var_prior`` (Schad, Betancourt & Vasishth 2021) is 0
    when the posterior is as wide as the prior (the data say nothing about the parameter)
    and 1 when the data pin it down. Variances are taken in the coordinate in which the
    prior is uniform or normal: ``log(value)`` for log-scale priors (``k``, ``r_unload``,
    ``sigma_mm``), the value itself otherwise, so a contraction does not depend on
    whether a stiffness is written in N/m or kN/m.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit with a ``posterior`` group and its ``priors`` attribute, and a ``prior``
        group (``FitSettings.n_prior_draws > 0``) unless ``prior_sd`` gives every
        parameter's prior SD.
    var_names : sequence of str, optional
        Parameters (default: the fit's force parameters and ``sigma_mm``).
    prior_sd : mapping of str to float, optional
        The prior SD of parameters, in the scale above, taken instead of the SD of the
        ``prior`` group's draws (for fits stored without prior draws).

    Returns
    -------
    pandas.DataFrame
        One row per parameter and volume fraction: ``parameter``, ``phi``, ``scale``
        (``log`` or ``linear``), ``prior_sd`` and ``posterior_sd`` (in that scale),
        ``contraction`` and ``verdict`` (:data:`IDENTIFIABILITY_LEVELS`). Empty if the fit
        stored no prior draws and ``prior_sd`` gives none.
    """
    columns = ["parameter", "phi", "scale", "prior_sd", "posterior_sd", "contraction", "verdict"]
    prior_sd = dict(prior_sd or {})
    if "prior" not in dt.children and not prior_sd:
        return pd.DataFrame(columns=columns)
    priors = json.loads(dt.attrs["priors"])
    if var_names is None:
        var_names = [*json.loads(dt.attrs["parameters"]), "sigma_mm"]
    post = dt["posterior"].to_dataset()
    prior = dt["prior"].to_dataset() if "prior" in dt.children else xr.Dataset()
    rows = []
    for name in var_names:
        if name not in post or (name not in prior_sd and name not in prior):
            continue
        log = name in priors and priors[name]["dist"] in ("loguniform", "lognormal")
        for phi in post["phi"].values:
            b = post[name].sel(phi=phi).values.ravel()
            b = b[np.isfinite(b)]
            if log:
                b = np.log(b[b > 0])
            if name in prior_sd:
                var_prior = float(prior_sd[name]) ** 2
            else:
                a = prior[name].sel(phi=phi).values.ravel()
                a = a[np.isfinite(a)]
                a = np.log(a[a > 0]) if log else a
                var_prior = float(np.var(a, ddof=1)) if a.size >= 2 else math.nan
            if b.size < 2 or not var_prior == var_prior:
                continue
            var_post = float(np.var(b, ddof=1))
            c = 1.0 - var_post / var_prior if var_prior > 0 else float("nan")
            verdict = next((t for bound, t in IDENTIFIABILITY_LEVELS if c < bound), "undetermined")
            rows.append(
                {
                    "parameter": name,
                    "phi": float(phi),
                    "scale": "log" if log else "linear",
                    "prior_sd": math.sqrt(var_prior),
                    "posterior_sd": math.sqrt(var_post),
                    "contraction": c,
                    "verdict": verdict,
                }
            )
    return pd.DataFrame(rows, columns=columns)


def posterior_draws(
    dt: xr.DataTree,
    phi: float,
    names: Sequence[str],
    n: int,
    rng: np.random.Generator,
) -> dict[str, np.ndarray]:
    """``n`` joint posterior draws (with replacement) of ``names`` at volume fraction ``phi``.

    The same (chain, draw) pairs are used for every name, so correlations are kept.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit's DataTree; its ``posterior`` has the variables ``names`` over ``phi``.
    phi : float
        Volume fraction [-]; the nearest one of the posterior is used.
    names : sequence of str
        Posterior variables (force parameters [SI], ``sigma_mm`` [mm]).
    n : int
        Number of draws.
    rng : numpy.random.Generator
        Picks the (chain, draw) pairs.

    Returns
    -------
    dict of str to ndarray, shape (n,)
    """
    post = dt.posterior.to_dataset().sel(phi=phi, method="nearest")
    n_chain, n_draw = post.sizes["chain"], post.sizes["draw"]
    idx = rng.integers(0, n_chain * n_draw, size=n)
    return {name: post[name].values.reshape(n_chain * n_draw)[idx].astype(float) for name in names}


def posterior_intervals(
    dt: xr.DataTree, names: Sequence[str], phis: Sequence[float], ci_prob: float = CI_PROB
) -> pd.DataFrame:
    """Median and equal-tailed interval of posterior variables at each volume fraction.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit's DataTree (variables over ``chain``, ``draw`` and ``phi``).
    names : sequence of str
        Variables (force parameters [SI], ``sigma_mm`` [mm]).
    phis : sequence of float
        Volume fractions [-] (exact coordinates of the posterior).
    ci_prob : float
        Probability of the interval.

    Returns
    -------
    pandas.DataFrame
        One row per (name, phi), names outer: ``phi``, ``parameter``, ``median``, ``lo``,
        ``hi`` (in the variable's unit).
    """
    post = dt.posterior.to_dataset()
    rows = []
    for name in names:
        for phi in phis:
            med, lo, hi = interval(post[name].sel(phi=phi).values.ravel(), ci_prob)
            rows.append({"phi": phi, "parameter": name, "median": med, "lo": lo, "hi": hi})
    return pd.DataFrame(rows, columns=["phi", "parameter", "median", "lo", "hi"])


def p_greater(a: ArrayLike, b: ArrayLike) -> float:
    """Paired probability ``a > b`` over the draws where both are finite (NaN if none).

    Parameters
    ----------
    a, b : array_like
        Paired draws.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.mean(a[ok] > b[ok])) if ok.any() else math.nan


def pearson_rows(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Pearson r across columns for every row (NaN pairs dropped; NaN if < 3 pairs).

    Parameters
    ----------
    x, y : ndarray, shape (n_rows, n_columns)

    Returns
    -------
    ndarray, shape (n_rows,)
    """
    out = np.full(x.shape[0], np.nan)
    for s in range(x.shape[0]):
        ok = np.isfinite(x[s]) & np.isfinite(y[s])
        if ok.sum() >= 3 and np.std(x[s, ok]) > 0 and np.std(y[s, ok]) > 0:
            out[s] = np.corrcoef(x[s, ok], y[s, ok])[0, 1]
    return out


def spearman_rows(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Spearman rank correlation across columns for every row (NaN pairs dropped).

    Parameters
    ----------
    x, y : ndarray, shape (n_rows, n_columns)

    Returns
    -------
    ndarray, shape (n_rows,)
    """
    out = np.full(x.shape[0], np.nan)
    for s in range(x.shape[0]):
        ok = np.isfinite(x[s]) & np.isfinite(y[s])
        if ok.sum() >= 3:
            out[s] = pearson_rows(rankdata(x[s, ok])[None], rankdata(y[s, ok])[None])[0]
    return out


def correlation(
    x_med: np.ndarray,
    y_med: np.ndarray,
    x_draws: np.ndarray,
    y_draws: np.ndarray,
    ci_prob: float = CI_PROB,
) -> dict:
    """Correlation of two quantities across cells: point (medians) and propagated.

    Parameters
    ----------
    x_med, y_med : ndarray, shape (n_cell,)
        Posterior medians per cell.
    x_draws, y_draws : ndarray, shape (n_draw, n_cell)
        Draw ``s`` of every cell.
    ci_prob : float
        Probability of the interval of the propagated r.

    Returns
    -------
    dict
        Pearson (``point``: r of the medians; ``median``, ``interval``: of r computed
        across cells for every draw index; ``p_positive``: share of draws with r > 0;
        ``n_draws``), with a ``spearman`` entry of the same form.
    """
    out: dict = {}
    for name, rows in (("pearson", pearson_rows), ("spearman", spearman_rows)):
        point = float(rows(x_med[None], y_med[None])[0])
        per_draw = rows(x_draws, y_draws)
        med, lo, hi = interval(per_draw, ci_prob)
        finite = per_draw[np.isfinite(per_draw)]
        out[name] = {
            "point": point,
            "median": med,
            "interval": [lo, hi],
            "p_positive": float(np.mean(finite > 0)) if finite.size else math.nan,
            "n_draws": int(finite.size),
        }
    return {**out["pearson"], "spearman": out["spearman"]}
