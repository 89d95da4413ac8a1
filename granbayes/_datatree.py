"""The converters: a fit's draws into one ArviZ DataTree, and DataTrees to and from netCDF.

Results live in one data model, an ``xarray.DataTree`` in ArviZ 1.x conventions, with
groups ``posterior``, ``log_likelihood``, ``posterior_predictive``, ``observed_data`` and
``sample_stats`` (and ``prior``, ``prior_predictive``, ``log_prior``); observations are
indexed by the dimension ``jump`` and volume fractions by ``phi``. ArviZ is used in three
layers, as ArviZ 1.x is itself built: converters here, statistics in
:mod:`granbayes.stats` (``arviz-stats``), figures in :mod:`granbayes.figures`
(``arviz-plots``).
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import arviz_base as azb
import numpy as np
import pandas as pd
import xarray as xr

__all__ = [
    "build_datatree",
    "read_datatree",
    "write_datatree",
]


def _heights_observed(observed: pd.DataFrame) -> xr.Dataset:
    """A jumps table as observed data: ``height_mm`` over ``jump``, columns as coordinates."""
    coords: dict[str, object] = {"jump": np.arange(len(observed))}
    coords |= {
        c: ("jump", observed[c].to_numpy())
        for c in observed.columns
        if c != "height_mm" and observed[c].notna().all()
    }
    values = observed["height_mm"].to_numpy(float)
    return xr.Dataset({"height_mm": ("jump", values)}, coords=coords)


def _with_dims(
    variables: Mapping[str, object], default: Sequence[str]
) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
    """Arrays and their dimensions from ``name -> array`` or ``name -> (dims, array)``."""
    arrays, dims = {}, {}
    for name, value in variables.items():
        if isinstance(value, tuple):
            dims[name], arrays[name] = list(value[0]), np.asarray(value[1])
        else:
            dims[name], arrays[name] = list(default), np.asarray(value)
    return arrays, dims


def build_datatree(
    posterior: Mapping[str, np.ndarray],
    *,
    dims: Mapping[str, Sequence[str]],
    coords: Mapping[str, object],
    log_likelihood: np.ndarray | Mapping[str, tuple[Sequence[str], np.ndarray]],
    posterior_predictive: Mapping[str, object],
    observed: pd.DataFrame | xr.Dataset,
    sample_stats: Mapping[str, np.ndarray],
    attrs: Mapping[str, object],
    stats_dims: Mapping[str, Sequence[str]] | None = None,
    prior: Mapping[str, np.ndarray] | None = None,
    prior_predictive: Mapping[str, object] | None = None,
    log_prior: Mapping[str, np.ndarray] | None = None,
    var_attrs: Mapping[str, Mapping[str, str]] | None = None,
    thinned: Mapping[str, xr.Dataset] | None = None,
) -> xr.DataTree:
    """Assemble a DataTree from arrays with leading (chain, draw) axes.

    Parameters
    ----------
    posterior : mapping of str to ndarray
        Posterior variables, shape ``(chain, draw, *dims[name])``.
    dims : mapping of str to sequence of str
        Extra dimensions per posterior variable.
    coords : mapping of str to array_like
        Coordinate values per dimension.
    log_likelihood : ndarray or mapping
        Pointwise log-likelihood of every unit of leave-one-out: an array of shape
        ``(chain, draw, jump)`` (variable ``height_mm``), or, per kind of measurement,
        variable name to ``(dims, array)`` over its unit dimension.
    posterior_predictive : mapping of str to ndarray or (dims, ndarray)
        Variables of shape ``(chain, draw, jump)`` (e.g. replicated heights [mm]), or with
        their own dimensions.
    observed : pandas.DataFrame or xarray.Dataset
        One row per jump with ``height_mm`` and descriptive columns (``phi``,
        ``command``, ``freq_hz``, ...), stored as coordinates of ``jump``; or the observed
        data of every kind, each on its own dimensions with its coordinates.
    sample_stats : mapping of str to ndarray
        Per-draw sampler statistics, shape ``(chain, draw, ...)``.
    attrs : mapping
        Provenance (seed, versions, configuration, data hash); non-scalar values are
        stored as JSON strings.
    stats_dims : mapping of str to sequence of str, optional
        Extra dimensions of the ``sample_stats`` variables.
    prior : mapping of str to ndarray, optional
        Prior draws of the posterior's variables, shape ``(chain, draw, *dims[name])``.
    prior_predictive : mapping of str to ndarray or (dims, ndarray), optional
        Measurements simulated from the prior draws (``(chain, draw, jump)`` arrays, or
        with their own dimensions).
    log_prior : mapping of str to ndarray, optional
        Log prior density of every posterior draw, shape ``(chain, draw)``.
    var_attrs : mapping of str to mapping, optional
        Attributes (``units``, ``long_name``) of the variables of that name, in every group.
    thinned : mapping of str to xarray.Dataset, optional
        Group name (``"posterior_predictive"``, ``"prior_predictive"``) to variables on
        thinned draws with their own dimensions and coordinates (e.g.
        ``("predictive_draw", "frame")``): replicates of measurements with many elements
        per unit, kept for a few hundred draws rather than every one.

    Returns
    -------
    xarray.DataTree
    """
    if isinstance(observed, pd.DataFrame):
        observed = _heights_observed(observed)
    if not isinstance(log_likelihood, Mapping):
        log_likelihood = {"height_mm": (["jump"], log_likelihood)}
    ll, ll_dims = _with_dims(log_likelihood, ["jump"])
    pp, pp_dims = _with_dims(posterior_predictive or {}, ["jump"])
    prior_pp, prior_pp_dims = _with_dims(prior_predictive or {}, ["jump"])
    groups: dict[str, dict] = {"posterior": dict(posterior), "log_likelihood": ll}
    all_dims: dict[str, list[str]] = {k: list(v) for k, v in dims.items()}
    all_dims.update(ll_dims)
    if pp:
        groups["posterior_predictive"] = pp
        all_dims.update(pp_dims)
    if sample_stats:
        groups["sample_stats"] = dict(sample_stats)
        all_dims.update({k: list(v) for k, v in (stats_dims or {}).items()})
    if prior:
        groups["prior"] = dict(prior)
    if prior_pp:
        groups["prior_predictive"] = prior_pp
        all_dims.update(prior_pp_dims)
    if log_prior:
        groups["log_prior"] = dict(log_prior)
    used = {d for v in all_dims.values() for d in v}
    all_coords = {k: np.asarray(v) for k, v in coords.items() if k in used}
    all_coords |= {d: observed[d].values for d in observed.dims if d in used}
    with warnings.catch_warnings():
        # every walker of the ensembles is a chain, so a run keeps more chains than draws
        # by design; ArviZ's check of the dimension names would flag it as a naming error
        warnings.filterwarnings(
            "ignore",
            message="Found chain dimension to be longer than draw dimension",
            category=UserWarning,
        )
        dt = azb.from_dict(groups, coords=all_coords, dims=all_dims)
    for group, extra_vars in (thinned or {}).items():
        if extra_vars.data_vars:
            ds = dt[group].to_dataset() if group in dt.children else xr.Dataset()
            dt[group] = xr.merge([ds, extra_vars])
    dt["observed_data"] = observed
    # the coordinates of the observations (volume fraction, command, settings, ...) go
    # with every group over the same dimensions
    extra = {c: observed[c] for c in observed.coords if c not in observed.dims}
    for group in ("log_likelihood", "posterior_predictive", "prior_predictive"):
        if group in dt.children:
            ds = dt[group].to_dataset()
            mine = {c: v for c, v in extra.items() if set(v.dims) <= set(ds.dims)}
            dt[group] = ds.assign_coords(mine)
    for group in dt.children:
        ds = dt[group].to_dataset()
        for name, var_attr in (var_attrs or {}).items():
            if name in ds:
                ds[name].attrs.update(var_attr)
        dt[group] = ds
    dt.attrs.update({k: _attr(v) for k, v in attrs.items()})
    return dt


def _attr(value: object) -> object:
    """A netCDF-storable attribute.

    Strings and numbers as they are, the rest (booleans, lists, mappings) as JSON text.
    """
    if isinstance(value, str | int | float) and not isinstance(value, bool):
        return value
    return json.dumps(value)


def write_datatree(dt: xr.DataTree, path: Path) -> None:
    """Write a DataTree to netCDF (h5netcdf engine).

    Parameters
    ----------
    dt : xarray.DataTree
        The tree.
    path : Path
        The netCDF file.
    """
    dt.to_netcdf(path, engine="h5netcdf")


def read_datatree(path: Path) -> xr.DataTree:
    """Read a DataTree written by :func:`write_datatree`.

    Parameters
    ----------
    path : Path
        The netCDF file.

    Returns
    -------
    xarray.DataTree
    """
    return xr.open_datatree(path, engine="h5netcdf").load()
