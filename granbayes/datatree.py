"""The ArviZ adapter: every use of ArviZ in granbayes goes through this module.

Results live in one data model, an ``xarray.DataTree`` in ArviZ 1.x conventions, with
groups ``posterior``, ``log_likelihood``, ``posterior_predictive``, ``observed_data`` and
``sample_stats``; observations are indexed by the dimension ``jump`` and volume fractions
by ``phi``. Intervals are always named explicitly (``ci_prob``), never ArviZ's default.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import arviz as az
import numpy as np
import pandas as pd
import xarray as xr

from .stats import by_ensemble
from .stats._loo import _ignore_pareto_k_warning, _pit_tree
from .stats._sbc import _sbc_dataset

__all__ = [
    "build_datatree",
    "plot_diagnostics",
    "plot_loo_pit",
    "plot_prior_posterior",
    "plot_sbc_ecdf",
    "read_datatree",
    "write_datatree",
]


def build_datatree(
    posterior: Mapping[str, np.ndarray],
    *,
    dims: Mapping[str, Sequence[str]],
    coords: Mapping[str, object],
    log_likelihood: np.ndarray,
    posterior_predictive: Mapping[str, np.ndarray],
    observed: pd.DataFrame,
    sample_stats: Mapping[str, np.ndarray],
    attrs: Mapping[str, object],
    stats_dims: Mapping[str, Sequence[str]] | None = None,
    prior: Mapping[str, np.ndarray] | None = None,
    prior_predictive: Mapping[str, np.ndarray] | None = None,
    log_prior: Mapping[str, np.ndarray] | None = None,
    var_attrs: Mapping[str, Mapping[str, str]] | None = None,
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
    log_likelihood : ndarray, shape (chain, draw, jump)
        Pointwise log-likelihood of every measured jump (variable ``height_mm``).
    posterior_predictive : mapping of str to ndarray
        Variables of shape ``(chain, draw, jump)``, e.g. replicated heights [mm].
    observed : pandas.DataFrame
        One row per jump with ``height_mm`` and descriptive columns (``phi``,
        ``command``, ``freq_hz``, ...), stored as coordinates of ``jump``.
    sample_stats : mapping of str to ndarray
        Per-draw sampler statistics, shape ``(chain, draw, ...)``.
    attrs : mapping
        Provenance (seed, versions, configuration, data hash); non-scalar values are
        stored as JSON strings.
    stats_dims : mapping of str to sequence of str, optional
        Extra dimensions of the ``sample_stats`` variables.
    prior : mapping of str to ndarray, optional
        Prior draws of the posterior's variables, shape ``(chain, draw, *dims[name])``.
    prior_predictive : mapping of str to ndarray, optional
        Heights simulated from the prior draws, shape ``(chain, draw, jump)``.
    log_prior : mapping of str to ndarray, optional
        Log prior density of every posterior draw, shape ``(chain, draw)``.
    var_attrs : mapping of str to mapping, optional
        Attributes (``units``, ``long_name``) of the variables of that name, in every group.

    Returns
    -------
    xarray.DataTree
    """
    n_jump = len(observed)
    groups: dict[str, dict] = {
        "posterior": dict(posterior),
        "log_likelihood": {"height_mm": log_likelihood},
        "observed_data": {"height_mm": observed["height_mm"].to_numpy(float)},
    }
    all_dims: dict[str, list[str]] = {k: list(v) for k, v in dims.items()}
    all_dims["height_mm"] = ["jump"]
    if posterior_predictive:
        groups["posterior_predictive"] = dict(posterior_predictive)
        all_dims.update({k: ["jump"] for k in posterior_predictive})
    if sample_stats:
        groups["sample_stats"] = dict(sample_stats)
        all_dims.update({k: list(v) for k, v in (stats_dims or {}).items()})
    if prior:
        groups["prior"] = dict(prior)
    if prior_predictive:
        groups["prior_predictive"] = dict(prior_predictive)
    if log_prior:
        groups["log_prior"] = dict(log_prior)
    used = {d for v in all_dims.values() for d in v}
    all_coords = {k: np.asarray(v) for k, v in coords.items() if k in used}
    all_coords["jump"] = np.arange(n_jump)
    with warnings.catch_warnings():
        # every walker of the ensembles is a chain, so a run keeps more chains than draws
        # by design; ArviZ's check of the dimension names would flag it as a naming error
        warnings.filterwarnings(
            "ignore",
            message="Found chain dimension to be longer than draw dimension",
            category=UserWarning,
        )
        dt = az.from_dict(groups, coords=all_coords, dims=all_dims)
    extra = {
        c: ("jump", observed[c].to_numpy())
        for c in observed.columns
        if c != "height_mm" and observed[c].notna().all()
    }
    for group in ("log_likelihood", "posterior_predictive", "prior_predictive", "observed_data"):
        if group in dt.children:
            dt[group] = dt[group].to_dataset().assign_coords(extra)
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


def plot_diagnostics(
    dt: xr.DataTree, var_names: Sequence[str], out_dir: Path, stem: str = ""
) -> list[Path]:
    """Trace and rank plots (arviz-plots, matplotlib backend) written as PNG files.

    One line per independent ensemble (:func:`by_ensemble`): what the stopping rule's
    R-hat compares.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.
    var_names : sequence of str
        Parameters to plot.
    out_dir : Path
        Folder of the PNG files.
    stem : str
        Suffix of the file names.

    Returns
    -------
    list of Path
        The files written.
    """
    import arviz_plots as azp
    from matplotlib import pyplot as plt

    tree = xr.DataTree.from_dict({"posterior": by_ensemble(dt)[list(var_names)]})
    written = []
    for kind, fn in (("trace", azp.plot_trace), ("rank", azp.plot_rank)):
        path = Path(out_dir) / f"{kind}{stem}.png"
        pc = fn(tree, var_names=list(var_names), backend="matplotlib")
        pc.savefig(path, dpi=110)
        plt.close("all")
        written.append(path)
    return written


def _draw_uniform_band(fig, n: int, band_prob: float, seed: int) -> None:
    """Shade the simultaneous band of uniform ECDF differences on every axis (grey).

    The ``band_prob`` band of the ECDF of ``n`` uniform values minus the uniform CDF.
    """
    from arviz_stats.ecdf_utils import ecdf_pit

    x, _, lower, upper = ecdf_pit(
        np.linspace(0.0, 1.0, n), band_prob, 1000, rng=np.random.default_rng(seed)
    )
    for ax in fig.axes:
        ax.fill_between(x, lower - x, upper - x, step="post", color="0.75", alpha=0.5, lw=0)


def plot_loo_pit(
    dt: xr.DataTree, path: Path, *, band_prob: float = 0.95, seed: int = 0, title: str = ""
) -> Path:
    """LOO-PIT calibration plot of the jump heights (``arviz_plots.plot_loo_pit``).

    The difference between the ECDF of the LOO-PIT values and the uniform CDF, with
    ArviZ's simultaneous envelope and ``pot_c`` p-value; points that drive a departure are
    highlighted. Above zero in the middle (an S shape): the predictive distribution is too
    wide; below: too narrow; a shift at one end: biased predictions.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit's DataTree.
    path : Path
        PNG file to write.
    band_prob : float
        Probability of the grey simultaneous band of a uniform sample of the same size
        (``arviz_stats.ecdf_utils.ecdf_pit``).
    seed : int
        Seed of the band's simulation.
    title : str
        Figure title.

    Returns
    -------
    Path
    """
    import arviz_plots as azp
    from matplotlib import pyplot as plt

    with warnings.catch_warnings():
        _ignore_pareto_k_warning()  # the PSIS weights' k values are reported by ``loo``
        pc = azp.plot_loo_pit(
            _pit_tree(dt),
            var_names=["height_mm"],
            backend="matplotlib",
            figure_kwargs={"figsize": (6.4, 3.6)},
        )
    fig = pc.viz["figure"].item()
    n = dt["observed_data"].sizes["jump"]
    _draw_uniform_band(fig, n, band_prob, seed)
    for ax in fig.axes:
        ax.set_title("")
        ax.set_xlabel("LOO-PIT of the jump height H [-] (uniform if calibrated)")
        ax.set_ylabel("ECDF − uniform CDF [-]")
    fig.suptitle(
        (title + "\n" if title else "")
        + f"LOO-PIT calibration of {n} jumps; grey: {band_prob:.0%} simultaneous band "
        "of a calibrated model",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)
    return Path(path)


class _UnitLabeller:
    """ArviZ labeller: variable names with their units, ``phi = <value>`` for selections."""

    def __new__(cls, labels: Mapping[str, str]):
        from arviz_base.labels import BaseLabeller

        class Labeller(BaseLabeller):
            def var_name_to_str(self, var_name):
                return labels.get(var_name, var_name)

            def dim_coord_to_str(self, dim, coord_val, coord_idx):
                return f"φ = {coord_val:g}" if dim == "phi" else f"{dim} = {coord_val}"

        return Labeller()


def plot_prior_posterior(
    dt: xr.DataTree,
    var_names: Sequence[str],
    path: Path,
    *,
    labels: Mapping[str, str] | None = None,
    log10: Sequence[str] = (),
    title: str = "",
) -> Path:
    """Prior and posterior marginals per parameter and volume fraction, as a PNG file.

    Drawn with ``arviz_plots.plot_prior_posterior``.

    One row per parameter, one column per volume fraction. A posterior as wide as its
    prior means the data do not determine the parameter.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit's DataTree with ``prior`` and ``posterior`` groups.
    var_names : sequence of str
        Parameters to show.
    path : Path
        PNG file to write.
    labels : mapping of str to str, optional
        Panel label (with units) per parameter, e.g. ``"log₁₀ k (k in N/m)"``.
    log10 : sequence of str
        Parameters shown as ``log10`` of their value (log-uniform priors), so that the
        prior is flat and a narrow posterior stays visible.
    title : str
        Figure title.

    Returns
    -------
    Path
    """
    import arviz_plots as azp
    from matplotlib import pyplot as plt
    from matplotlib.lines import Line2D

    names = [n for n in var_names if n in dt["prior"].data_vars and n in dt["posterior"].data_vars]
    groups = {}
    for group in ("prior", "posterior"):
        ds = dt[group].to_dataset()[names]
        for n in names:
            if n in log10:
                ds[n] = np.log10(ds[n])
        groups[group] = ds
    tree = xr.DataTree.from_dict(groups)
    n_phi = tree["posterior"].sizes.get("phi", 1)
    shown = {n: (labels or {}).get(n, f"log₁₀ {n}" if n in log10 else n) for n in names}
    pc = azp.plot_prior_posterior(
        tree,
        var_names=names,
        backend="matplotlib",
        labeller=_UnitLabeller(shown),
        col_wrap=n_phi,
        figure_kwargs={
            "figsize": (3.0 * n_phi + 0.6, 2.3 * len(names) + 1.2),
            "layout": "constrained",
        },
    )
    fig = pc.viz["figure"].item()
    for legend in fig.legends:
        legend.remove()
    for ax in fig.axes:
        ax.title.set_fontsize(9)
        ax.tick_params(labelsize=8)
    handles = [
        Line2D([], [], color=line.get_color(), label=group)
        for line, group in zip(fig.axes[0].get_lines()[:2], ("prior", "posterior"), strict=False)
    ]
    fig.legend(handles=handles, loc="outside lower center", ncols=2, fontsize=8)
    fig.suptitle(
        (title + "\n" if title else "")
        + "Prior and posterior marginal density per volume fraction\n"
        + "(a posterior as wide as its prior: the data do not determine the parameter)",
        fontsize=9,
    )
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)
    return Path(path)


def plot_sbc_ecdf(
    pit: Mapping[str, np.ndarray],
    phis: Sequence[float],
    path: Path,
    *,
    band_prob: float = 0.95,
    seed: int = 0,
    title: str = "",
) -> Path:
    """ECDF-difference plots of SBC PIT values with simultaneous confidence bands.

    One panel per parameter (rows) and volume fraction (columns): the difference between
    the ECDF of the normalised ranks and the uniform CDF (``arviz_plots.plot_ecdf_pit``,
    with ArviZ's ``pot_c`` p-value and the points that drive a departure highlighted),
    over the grey ``band_prob`` simultaneous band of a uniform sample of the same size
    (``arviz_stats.ecdf_utils.ecdf_pit``, Säilynoja et al. 2022). A calibrated posterior
    stays inside the band.

    Parameters
    ----------
    pit : mapping of str to ndarray, shape (replicate, phi)
        PIT values in (0, 1) per parameter.
    phis : sequence of float
        Volume fractions of the second axis.
    path : Path
        PNG file to write.
    band_prob : float
        Probability of the simultaneous band.
    seed : int
        Seed of the band's simulation.
    title : str
        Figure title.

    Returns
    -------
    Path
    """
    import arviz_plots as azp
    from matplotlib import pyplot as plt

    ds = _sbc_dataset(pit, phis)
    n = ds.sizes["replicate"]
    n_phi, n_var = len(phis), len(pit)
    pc = azp.plot_ecdf_pit(
        xr.DataTree.from_dict({"prior_sbc": ds}),
        group="prior_sbc",
        sample_dims=["replicate"],
        envelope_prob=band_prob,
        backend="matplotlib",
        col_wrap=n_phi,
        figure_kwargs={"figsize": (2.8 * n_phi + 0.6, 2.3 * n_var + 0.6)},
    )
    fig = pc.viz["figure"].item()
    _draw_uniform_band(fig, n, band_prob, seed)
    fig.suptitle(
        (title + "\n" if title else "")
        + f"ECDF - uniform of the normalised ranks ({n} replicates); grey: "
        f"{band_prob:.0%} simultaneous band",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)
    return Path(path)


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
