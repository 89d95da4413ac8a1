"""PSIS-LOO of jump heights, its comparison of laws, and LOO-PIT (arviz-stats).

Intervals and k thresholds are always named explicitly; ArviZ's warning about large Pareto
k is silenced where LOO is computed, because the k values are returned and reported
(``diagnose`` recomputes flagged jumps: moment matching, refits).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import arviz_stats as azs
import numpy as np
import pandas as pd
import xarray as xr
from arviz_stats.base import array_stats

from ._cells import cell_keys, observed_jumps
from ._sbc import sbc_uniformity

#: arviz-stats warns (UserWarning) whenever a Pareto k of PSIS-LOO exceeds its threshold.
#: granbayes reports the k values itself (:func:`loo`: ``pareto_k``, ``max_pareto_k``,
#: ``n_bad_k``; the fit report lists them, ``diagnose`` refits such jumps exactly), so this
#: one warning is silenced where LOO is computed; every other warning surfaces.
_PARETO_K_WARNING = "Estimated shape parameter of Pareto distribution is greater than"


def _ignore_pareto_k_warning() -> None:
    """Inside ``warnings.catch_warnings()``: silence only :data:`_PARETO_K_WARNING`."""
    warnings.filterwarnings("ignore", message=_PARETO_K_WARNING, category=UserWarning)


def unit_phi_name(dim: str) -> str:
    """The coordinate holding the volume fraction of each unit along ``dim``.

    ``phi`` for jumps (``jump``), ``<dim>_phi`` for the units of the other kinds (a
    DataTree group has one coordinate of each name).

    Parameters
    ----------
    dim : str
        A unit dimension of a fit's ``log_likelihood`` group.

    Returns
    -------
    str
    """
    return "phi" if dim == "jump" else f"{dim}_phi"


def unit_log_likelihood(dt: xr.DataTree) -> tuple[np.ndarray, np.ndarray]:
    """The pointwise log-likelihood of every unit of every kind, and their phi.

    Every variable of the ``log_likelihood`` group (one per kind of measurement, over its
    unit dimension), concatenated in the group's order: the units of the fit's joint
    leave-one-out.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.

    Returns
    -------
    log_lik : ndarray, shape (chain, draw, n_units)
    phi : ndarray, shape (n_units,)
        Volume fraction of every unit.
    """
    ll = dt["log_likelihood"].to_dataset()
    arrays, phis = [], []
    for name in ll.data_vars:
        var = ll[name]
        dim = var.dims[-1]
        arrays.append(var.transpose("chain", "draw", dim).values)
        phis.append(np.asarray(ll[unit_phi_name(dim)].values, dtype=float))
    return np.concatenate(arrays, axis=-1), np.concatenate(phis)


def loo(dt: xr.DataTree | np.ndarray, *, log_weights: bool = False) -> dict[str, object]:
    """PSIS-LOO of a fit: jump heights, or every unit of every kind of measurement.

    Parameters
    ----------
    dt : xarray.DataTree or ndarray
        A fit's DataTree (with one kind, ArviZ's ``loo`` of its variable; with several,
        the units of all, :func:`unit_log_likelihood`), or a pointwise log-likelihood
        array of shape ``(chain, draw, unit)`` (PSIS with relative efficiency 1: the kept
        draws are thinned to roughly independent ones).
    log_weights : bool
        Whether to return the smoothed log weights too (``log_weights``: ArviZ's
        DataArray over ``(jump, chain, draw)``; ``None`` unless the fit has jump heights
        alone), which :func:`loo_pit` can reuse instead of smoothing them again.

    Returns
    -------
    dict
        ``elpd``, ``se``, ``p`` (effective number of parameters), ``elpd_i`` and
        ``pareto_k`` (ndarrays over jumps), ``max_pareto_k``, ``good_k`` (ArviZ's
        sample-size dependent threshold ``min(1 - 1/log10(S), 0.7)`` for S draws, above
        which PSIS is unreliable) and ``n_bad_k`` (jumps with k > ``good_k``); with
        ``log_weights=True``, ``log_weights`` too.
    """
    if isinstance(dt, np.ndarray):
        elpd_i, k, p_i = array_stats.loo(np.moveaxis(dt, -1, 0), chain_axis=-2, draw_axis=-1)
        elpd_i, k = np.asarray(elpd_i, dtype=float), np.asarray(k, dtype=float)
        good_k = _good_k(dt.shape[0] * dt.shape[1])
        return {
            "elpd": float(np.sum(elpd_i)),
            "se": float(np.sqrt(elpd_i.size * np.var(elpd_i))),
            "p": float(np.sum(p_i)),
            "elpd_i": elpd_i,
            "pareto_k": k,
            "max_pareto_k": float(np.nanmax(k)),
            "good_k": good_k,
            "n_bad_k": int(np.sum(k > good_k)),
            **({"log_weights": None} if log_weights else {}),
        }
    if len(dt["log_likelihood"].data_vars) > 1:
        return loo(unit_log_likelihood(dt)[0], log_weights=log_weights)
    (var_name,) = dt["log_likelihood"].data_vars
    with warnings.catch_warnings():
        _ignore_pareto_k_warning()  # the k values are returned
        res = azs.loo(dt, pointwise=True, var_name=var_name)
    k = np.asarray(res.pareto_k)
    good_k = float(res.good_k)
    out = {
        "elpd": float(res.elpd),
        "se": float(res.se),
        "p": float(res.p),
        "elpd_i": np.asarray(res.elpd_i),
        "pareto_k": k,
        "max_pareto_k": float(np.nanmax(k)),
        "good_k": good_k,
        "n_bad_k": int(np.sum(k > good_k)),
    }
    if log_weights:
        out["log_weights"] = res.log_weights if var_name == "height_mm" else None
    return out


def _good_k(n_samples: int) -> float:
    """ArviZ's Pareto k threshold for ``n_samples`` draws (as ``ELPDData.good_k``)."""
    return float(min(1.0 - 1.0 / np.log10(n_samples), 0.7)) if n_samples > 1 else 0.7


def elpd_difference(
    elpd_i_a: np.ndarray, elpd_i_b: np.ndarray, strata: np.ndarray | None = None
) -> tuple[float, float]:
    """ELPD difference ``a - b`` and its standard error from pointwise values.

    ``se = sqrt(n var(elpd_i_a - elpd_i_b))`` (Vehtari, Gelman & Gabry 2017, eq. 24): the
    units as draws from one population. With ``strata`` (the kind of measurement of each
    unit, :func:`unit_kinds`) of more than one kind, ``se = sqrt(sum_k n_k var_k)``: the
    stratified form, for a design that fixes how many units of each kind it has (so many
    jumps, so many tracked jumps), with ``var_k`` each kind's sample variance (divided by
    ``n_k - 1``: a kind may hold a handful of units; one unit adds nothing). The pooled
    form would also count the spread *between* the kinds' mean differences as sampling
    error: a tracked jump carries hundreds of frames and gains hundreds of nats where a
    jump height gains a few, and pooled, that difference in kind inflates the SE until a
    gain of thousands of nats fails the rule's 2 SE (``tests/test_elpd_difference.py``
    measures both). With one kind (or none given) the SE is the pooled one, as before.

    Parameters
    ----------
    elpd_i_a, elpd_i_b : ndarray
        Pointwise ELPD [nats] of two models on the same units.
    strata : ndarray, optional
        A label per unit (its kind).

    Returns
    -------
    tuple of float
        The difference and its standard error [nats].
    """
    d = np.asarray(elpd_i_a, dtype=float) - np.asarray(elpd_i_b, dtype=float)
    labels = None if strata is None else np.asarray(strata)
    if labels is None or np.unique(labels).size < 2:
        return float(np.sum(d)), float(np.sqrt(d.size * np.var(d)))
    if labels.shape != d.shape:
        raise ValueError(f"strata has {labels.size} labels for {d.size} units")
    var = 0.0
    for level in np.unique(labels):
        part = d[labels == level]
        if part.size > 1:  # the sample variance: a stratum may hold a handful of units
            var += part.size * float(np.var(part, ddof=1))
    return float(np.sum(d)), float(np.sqrt(var))


def unit_kinds(dt: xr.DataTree) -> np.ndarray:
    """The kind of measurement of every unit, in :func:`unit_log_likelihood`'s order.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.

    Returns
    -------
    ndarray of str, shape (n_units,)
        The name of the unit's ``log_likelihood`` variable (``height_mm``, ...).
    """
    ll = dt["log_likelihood"].to_dataset()
    return np.concatenate(
        [np.full(ll[name].sizes[ll[name].dims[-1]], str(name)) for name in ll.data_vars]
    )


def compare(models: Mapping[str, xr.DataTree]) -> pd.DataFrame:
    """PSIS-LOO comparison (``arviz.compare``): ``elpd``, ``elpd_diff``, ``dse``, ``weight``.

    Parameters
    ----------
    models : mapping of str to xarray.DataTree
        Fits of the same jumps, by name.

    Returns
    -------
    pandas.DataFrame
    """
    with warnings.catch_warnings():
        _ignore_pareto_k_warning()  # flagged per model in the ``warning`` column
        return azs.compare(dict(models), var_name="height_mm")


def cell_loo(dt: xr.DataTree) -> dict:
    """Leave-one-*cell*-out PSIS-LOO: each cell's summed log-likelihood left out at once.

    How well a law predicts a command setting it has not seen (cells: :data:`CELL_KEYS`).

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.

    Returns
    -------
    dict
        As :func:`loo`, over cells (in the order of their keys).
    """
    ll = dt["log_likelihood"]["height_mm"].values
    frame = observed_jumps(dt).drop(columns="height_mm")
    groups = frame.groupby(cell_keys(frame), sort=True).indices
    summed = np.stack([ll[..., np.asarray(idx)].sum(axis=-1) for idx in groups.values()], -1)
    return loo(summed)


def loo_pit(
    dt: xr.DataTree,
    *,
    log_weights: xr.DataArray | None = None,
    pareto_k: np.ndarray | None = None,
) -> np.ndarray:
    """LOO-PIT values of the measured heights (``arviz_stats.loo_pit``, PSIS-LOO weights).

    ``p(new height <= measured height | all other jumps)`` per jump: uniform on (0, 1) for
    a calibrated predictive distribution. Needs the ``posterior_predictive``,
    ``log_likelihood`` and ``observed_data`` groups (variable ``height_mm``). The tails
    are Pareto-smoothed (``pareto_pit=True``), as ArviZ's ``plot_loo_pit`` computes them
    for its ``pot_c`` test: the values :func:`pit_uniformity` tests and
    :func:`granbayes.figures.plot_loo_pit` draws are the same.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.
    log_weights : xarray.DataArray, optional
        The jump heights' smoothed log weights (:func:`loo` with ``log_weights=True``),
        given with ``pareto_k``; by default they are computed (the larger part of the cost).
    pareto_k : ndarray, optional
        Their Pareto shape per jump (``loo``'s ``pareto_k``).

    Returns
    -------
    ndarray, shape (jump,)
    """
    given = {}
    if (log_weights is None) != (pareto_k is None):
        raise ValueError("loo_pit: give log_weights and pareto_k together, or neither")
    if log_weights is not None:
        k = xr.DataArray(np.asarray(pareto_k, dtype=float), dims=["jump"])
        given = {
            "log_weights": log_weights.to_dataset(name="height_mm"),
            "pareto_k": k.to_dataset(name="height_mm"),
        }
    with warnings.catch_warnings():
        _ignore_pareto_k_warning()  # the PSIS weights' k values are reported by ``loo``
        pit = azs.loo_pit(_pit_tree(dt), var_names=["height_mm"], pareto_pit=True, **given)
    return np.asarray(pit["height_mm"].values, dtype=float)


def _pit_tree(dt: xr.DataTree) -> xr.DataTree:
    """The groups LOO-PIT needs, with only ``height_mm`` in the predictive group."""
    return xr.DataTree.from_dict(
        {
            "posterior": dt["posterior"].to_dataset(),
            "log_likelihood": dt["log_likelihood"].to_dataset(),
            "observed_data": dt["observed_data"].to_dataset(),
            "posterior_predictive": dt["posterior_predictive"].to_dataset()[["height_mm"]],
        }
    )


def pit_uniformity(pit: np.ndarray) -> float:
    """p-value of ArviZ's uniformity test (``pot_c``, arviz-stats) of PIT values in (0, 1).

    Parameters
    ----------
    pit : ndarray
        PIT values.

    Returns
    -------
    float
    """
    return float(sbc_uniformity({"pit": np.asarray(pit, dtype=float)[:, None]}, [0.0])["pit"][0])
