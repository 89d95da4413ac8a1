"""Posterior summaries shared by the analyses: intervals, joint draws, paired comparisons.

Small, general tools that the analysis scripts (``analyses/``) and the analysis modules
(:mod:`granbayes.maps`, :mod:`granbayes.optimal`, :mod:`granbayes.mechanics`) build on:

* :func:`interval`, :func:`fmt_triple`, :func:`fmt_interval`: the median and the
  equal-tailed interval of a sample, and their text;
* :func:`posterior_draws`: joint posterior draws of named parameters at one volume
  fraction of a fit's DataTree (correlations kept); :func:`posterior_intervals`: their
  medians and intervals per volume fraction, as a table;
* :func:`cell_experiment`: the experiment with one data row's command settings applied;
* :func:`p_greater`: a paired probability over common posterior draws;
* :func:`correlation`: Pearson and Spearman correlation across cells, from the cells'
  medians and propagated draw by draw;
* :func:`cell_statistics`: mean, standard deviation and standard error of measured
  heights per cell; :func:`mean_discrepancy`: a measured cell mean against the posterior
  predictive of the mean of its jumps.

Heights are in mm; everything else is in the units of its input.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
import xarray as xr
from numpy.typing import ArrayLike
from scipy.stats import rankdata

from .experiment import COMMAND_NAMES, Experiment
from .likelihood import SETTING_COLUMNS

__all__ = [
    "CI_PROB",
    "cell_experiment",
    "cell_statistics",
    "correlation",
    "fmt_interval",
    "fmt_triple",
    "interval",
    "mean_discrepancy",
    "p_greater",
    "posterior_draws",
    "posterior_intervals",
]

#: Interval reported everywhere in the analyses (equal-tailed).
CI_PROB = 0.90


def interval(values: ArrayLike, ci_prob: float = CI_PROB) -> tuple[float, float, float]:
    """Median and the equal-tailed ``ci_prob`` interval of ``values`` (NaNs ignored).

    Parameters
    ----------
    values : array_like
        A sample (any shape; flattened).
    ci_prob : float
        Probability of the interval, in (0, 1).

    Returns
    -------
    tuple of float
        ``(median, lo, hi)``; all NaN if no value is finite.
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return (math.nan, math.nan, math.nan)
    lo, med, hi = np.quantile(v, [(1 - ci_prob) / 2, 0.5, 1 - (1 - ci_prob) / 2])
    return float(med), float(lo), float(hi)


def fmt_triple(med: float, lo: float, hi: float, fmt: str = ".3g") -> str:
    """``"median [lo, hi]"`` of a precomputed triple, each value formatted with ``fmt``.

    Parameters
    ----------
    med, lo, hi : float
        Median and interval bounds.
    fmt : str
        Format specification.
    """
    return f"{med:{fmt}} [{lo:{fmt}}, {hi:{fmt}}]"


def fmt_interval(values: ArrayLike, digits: int = 3, ci_prob: float = CI_PROB) -> str:
    """``"median [lo, hi]"`` of ``values`` with ``digits`` significant digits.

    Parameters
    ----------
    values : array_like
        Draws.
    digits : int
        Significant digits.
    ci_prob : float
        Probability of the equal-tailed interval.
    """
    return fmt_triple(*interval(values, ci_prob), fmt=f".{digits}g")


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


def cell_experiment(experiment: Experiment, row: Mapping[str, object]) -> Experiment:
    """The experiment with the command settings of one data row (or cell) applied.

    Parameters
    ----------
    experiment : Experiment
    row : mapping
        May hold ``freq_hz`` [Hz], ``amplitude_mm`` [mm], ``delay_ms`` [ms],
        ``settle_periods`` [periods]; missing or NaN ones keep the experiment's value.

    Returns
    -------
    Experiment
    """
    return experiment.replace(
        **{k: float(row[k]) for k in SETTING_COLUMNS if k in row and pd.notna(row[k])}
    )


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
    """Spearman rank correlation across columns for every row (NaN pairs dropped)."""
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


def cell_statistics(
    table: pd.DataFrame, keys: Sequence[str] = ("freq_hz", "phi", "command")
) -> pd.DataFrame:
    """Count, mean, standard deviation and standard error of heights per cell.

    Parameters
    ----------
    table : pandas.DataFrame
        Jumps (``height_mm`` [mm] and the ``keys`` columns).
    keys : sequence of str
        Columns that define a cell.

    Returns
    -------
    pandas.DataFrame
        ``keys``, ``n``, ``mean_mm``, ``sd_mm``, ``se_mm`` [mm], sorted by ``keys``
        (commands in the order of ``COMMAND_NAMES``).
    """
    keys = list(keys)
    g = table.groupby(keys, sort=True)["height_mm"]
    stats = g.agg(n="count", mean_mm="mean", sd_mm="std").reset_index()
    stats["se_mm"] = stats["sd_mm"] / np.sqrt(stats["n"])
    order = {c: i for i, c in enumerate(COMMAND_NAMES)}
    return stats.sort_values(
        keys, key=lambda s: s.map(order) if s.name == "command" else s
    ).reset_index(drop=True)


def mean_discrepancy(
    mean_mm: float,
    n: int,
    sim_mm: np.ndarray,
    sigma_mm: np.ndarray,
    rng: np.random.Generator,
    ci_prob: float = CI_PROB,
) -> tuple[float, float, float, float]:
    """A measured cell mean against the posterior predictive of the mean of ``n`` jumps.

    The predictive mean of draw ``s`` is ``sim_mm[s] + e_s sigma_mm[s] / sqrt(n)`` with
    ``e_s ~ Normal(0, 1)`` (one ``rng.normal`` call of size ``len(sim_mm)``).

    Parameters
    ----------
    mean_mm : float
        Measured cell mean [mm].
    n : int
        Jumps in the cell.
    sim_mm, sigma_mm : ndarray, shape (n_draws,)
        Simulated height [mm] and trial scatter [mm] per posterior draw (NaN: failed).
    rng : numpy.random.Generator
    ci_prob : float
        Probability of the interval.

    Returns
    -------
    tuple of float
        Median, lo and hi of ``measured - predicted`` [mm], and ``z``: the median over the
        predictive standard deviation ``sqrt(var(sim) + mean(sigma^2) / n)`` (NaN if that
        is not positive).
    """
    predicted = sim_mm + rng.normal(size=len(sim_mm)) * sigma_mm / np.sqrt(n)
    med, lo, hi = interval(mean_mm - predicted, ci_prob)
    sd_mean = np.sqrt(np.nanvar(sim_mm) + np.nanmean(sigma_mm**2) / n)
    z = med / sd_mean if np.isfinite(sd_mean) and sd_mean > 0 else np.nan
    return med, lo, hi, z


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
