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
from arviz_stats.base import array_stats

__all__ = [
    "build_datatree",
    "by_ensemble",
    "run_diagnostics",
    "summary_table",
    "loo",
    "elpd_difference",
    "compare",
    "loo_pit",
    "pit_uniformity",
    "plot_diagnostics",
    "plot_loo_pit",
    "plot_prior_posterior",
    "plot_sbc_ecdf",
    "sbc_uniformity",
    "write_datatree",
    "read_datatree",
    "CI_PROB",
]

#: Credible-interval probability reported everywhere (equal-tailed).
CI_PROB = 0.90

#: arviz-stats warns (UserWarning) whenever a Pareto k of PSIS-LOO exceeds its threshold.
#: granbayes reports the k values itself (:func:`loo`: ``pareto_k``, ``max_pareto_k``,
#: ``n_bad_k``; the fit report lists them, ``diagnose`` refits such jumps exactly), so this
#: one warning is silenced where LOO is computed; every other warning surfaces.
_PARETO_K_WARNING = "Estimated shape parameter of Pareto distribution is greater than"


def _ignore_pareto_k_warning() -> None:
    """Inside ``warnings.catch_warnings()``: silence only :data:`_PARETO_K_WARNING`."""
    warnings.filterwarnings("ignore", message=_PARETO_K_WARNING, category=UserWarning)


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
        per_ens = np.nanmax(tau, axis=1) if tau.ndim == 2 else np.array([tau_max])
        rows.append(
            {
                "run": run["label"],
                "n_ensembles": run["n_ensembles"],
                "n_chains": run["n_chains"],
                "n_steps": run["n_steps"],
                "tau_max": tau_max,
                "steps_over_tau": float(np.nanmin((run["n_steps"] - burn) / per_ens)),
                "rhat_max": float(np.nanmax(run["rhat"])) if run["rhat"] else np.nan,
                "ess_min": float(np.nanmin([*run["ess_bulk"], *run["ess_tail"]])),
                "acceptance": run["acceptance"],
                "converged": run["converged"],
                "warnings": "; ".join(run["warnings"]),
            }
        )
    return pd.DataFrame(rows)


def summary_table(
    dt: xr.DataTree, var_names: Sequence[str] | None = None, ci_prob: float = CI_PROB
) -> pd.DataFrame:
    """Posterior summary with equal-tailed intervals, R-hat and ESS.

    ``r_hat`` is the rank-normalised split R-hat **across the independent ensembles** of
    the parameter's run, the statistic of the stopping rule, read from the fit's ``runs``
    record. ArviZ's own R-hat would take every walker as an independent chain; the walkers
    of one ensemble move together (each proposal uses the others), which inflates it
    without saying anything about convergence. Where a row has no recorded value (the
    ``quadratic`` parametrisation, or a DataTree made elsewhere) ArviZ's value is kept.
    ESS and MCSE are ArviZ's, over the walkers as chains (as the stopping rule's ESS).

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
    table = az.summary(dt, var_names=var_names, ci_prob=ci_prob, ci_kind="eti")
    for row, value in _ensemble_rhat(dt).items():
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


def loo(dt: xr.DataTree | np.ndarray) -> dict[str, object]:
    """PSIS-LOO of the ``height_mm`` log-likelihood.

    Parameters
    ----------
    dt : xarray.DataTree or ndarray
        A fit's DataTree, or a pointwise log-likelihood array of shape
        ``(chain, draw, jump)`` (PSIS with relative efficiency 1: the kept draws are
        thinned to roughly independent ones).

    Returns
    -------
    dict
        ``elpd``, ``se``, ``p`` (effective number of parameters), ``elpd_i`` and
        ``pareto_k`` (ndarrays over jumps), ``max_pareto_k``, ``good_k`` (ArviZ's
        sample-size dependent threshold ``min(1 - 1/log10(S), 0.7)`` for S draws, above
        which PSIS is unreliable) and ``n_bad_k`` (jumps with k > ``good_k``).
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
        }
    with warnings.catch_warnings():
        _ignore_pareto_k_warning()  # the k values are returned
        res = az.loo(dt, pointwise=True, var_name="height_mm")
    k = np.asarray(res.pareto_k)
    good_k = float(res.good_k)
    return {
        "elpd": float(res.elpd),
        "se": float(res.se),
        "p": float(res.p),
        "elpd_i": np.asarray(res.elpd_i),
        "pareto_k": k,
        "max_pareto_k": float(np.nanmax(k)),
        "good_k": good_k,
        "n_bad_k": int(np.sum(k > good_k)),
    }


def _good_k(n_samples: int) -> float:
    """ArviZ's Pareto k threshold for ``n_samples`` draws (as ``ELPDData.good_k``)."""
    return float(min(1.0 - 1.0 / np.log10(n_samples), 0.7)) if n_samples > 1 else 0.7


def elpd_difference(elpd_i_a: np.ndarray, elpd_i_b: np.ndarray) -> tuple[float, float]:
    """ELPD difference ``a - b`` and its standard error from pointwise values.

    ``se = sqrt(n var(elpd_i_a - elpd_i_b))`` (Vehtari, Gelman & Gabry 2017, eq. 24).

    Parameters
    ----------
    elpd_i_a, elpd_i_b : ndarray
        Pointwise ELPD [nats] of two models on the same jumps.

    Returns
    -------
    tuple of float
        The difference and its standard error [nats].
    """
    d = np.asarray(elpd_i_a, dtype=float) - np.asarray(elpd_i_b, dtype=float)
    return float(np.sum(d)), float(np.sqrt(d.size * np.var(d)))


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
        return az.compare(dict(models), var_name="height_mm")


def by_ensemble(dt: xr.DataTree, group: str = "posterior") -> xr.Dataset:
    """A fit's draws with one chain per independent *ensemble* instead of per walker.

    The walkers of an ensemble move together (each proposal uses the others), so they are
    not independent chains; the ensembles, started apart, are. Chain ``e`` holds ensemble
    ``e``'s kept draws in step order, its walkers inside each step (the chains of the
    stopping rule's R-hat, :mod:`granbayes.sampler`). Where the runs of a fit kept
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
    runs = json.loads(dt.attrs.get("runs", "[]"))
    shapes = {(r["n_ensembles"], r["n_chains"]) for r in runs}
    n_chain = ds.sizes["chain"]
    if len(shapes) != 1:
        return ds
    ((n_ens, n_chains),) = shapes
    if n_chains != n_chain or n_chain % n_ens:
        return ds
    walkers, n_draw = n_chain // n_ens, ds.sizes["draw"]

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


def loo_pit(dt: xr.DataTree) -> np.ndarray:
    """LOO-PIT values of the measured heights (``arviz.loo_pit``, PSIS-LOO weights).

    ``p(new height <= measured height | all other jumps)`` per jump: uniform on (0, 1) for
    a calibrated predictive distribution. Needs the ``posterior_predictive``,
    ``log_likelihood`` and ``observed_data`` groups (variable ``height_mm``).

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.

    Returns
    -------
    ndarray, shape (jump,)
    """
    with warnings.catch_warnings():
        _ignore_pareto_k_warning()  # the PSIS weights' k values are reported by ``loo``
        pit = az.loo_pit(_pit_tree(dt), var_names=["height_mm"])
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


def _sbc_dataset(pit: Mapping[str, np.ndarray], phis: Sequence[float]) -> xr.Dataset:
    n = len(next(iter(pit.values())))
    return xr.Dataset(
        {name: (("replicate", "phi"), np.asarray(v, dtype=float)) for name, v in pit.items()},
        coords={"replicate": np.arange(n), "phi": np.asarray(phis, dtype=float)},
    )


def sbc_uniformity(pit: Mapping[str, np.ndarray], phis: Sequence[float]) -> dict[str, np.ndarray]:
    """ArviZ's uniformity test of SBC PIT values (``pot_c``, arviz-stats), per phi.

    Parameters
    ----------
    pit : mapping of str to ndarray, shape (replicate, phi)
        PIT values in (0, 1) (normalised ranks) per parameter.
    phis : sequence of float
        The volume fractions of the second axis.

    Returns
    -------
    dict of str to ndarray, shape (phi,)
        p-value per parameter and volume fraction.
    """
    import arviz_stats  # noqa: F401  (registers the ``azstats`` accessor)

    ds = _sbc_dataset(pit, phis)
    p_values, _, _ = ds.azstats.uniformity_test(dim=["replicate"], method="pot_c")
    return {name: np.atleast_1d(p_values[name].values) for name in pit}


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
