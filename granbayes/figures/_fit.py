"""Figures of a fit.

Posterior predictive, corner plots, coefficients across volume fractions, prior against
posterior, LOO-PIT, trace and rank plots, SBC ranks.

Each function takes a DataTree (or arrays drawn from it) and returns a Figure; none
writes a file. Figures drawn by ``arviz-plots`` come from ``pyplot``: close them (``plt.close``)
once saved.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import xarray as xr
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

from ..commands import COMMAND_NAMES
from ..stats import CI_PROB, eti_probs, run_diagnostics
from ..stats._loo import loo_pit
from ..stats._sbc import _sbc_dataset
from ..stats._summaries import _n_ensembles, rank_test_draws
from ._analyses import panel_grid
from ._style import COLORS, data_label, param_label, suptitle, value_with_errors


def plot_corner(
    dt: xr.DataTree, phi: float, var_names: list[str], truth: Mapping[str, float] | None = None
) -> Figure:
    """Corner plot of the posterior at one volume fraction, with the truth if known.

    Parameters
    ----------
    dt : xarray.DataTree
        Fit result.
    phi : float
        Volume fraction.
    var_names : list of str
        Parameters to show.
    truth : mapping, optional
        True values (synthetic data) drawn as lines.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import corner

    post = dt.posterior.to_dataset().sel(phi=phi)
    names = [n for n in var_names if n in post and np.all(np.isfinite(post[n].values))]
    samples = np.column_stack([post[n].values.ravel() for n in names])
    fig = Figure(figsize=(2.4 * len(names) + 1, 2.4 * len(names) + 1))
    truths = None if truth is None else [truth.get(n, None) for n in names]
    corner.corner(
        samples,
        fig=fig,
        labels=[param_label(n) for n in names],
        quantiles=[0.05, 0.5, 0.95],
        truths=truths,
        truth_color="#D55E00",
        bins=30,
        smooth=0.8,
        # density and contours, not the ~3,000 draws as points (half the drawing time)
        plot_datapoints=False,
    )
    # each marginal's median and 5-95% interval as its title, to the precision of the
    # interval (corner.py's one ``title_fmt`` for every parameter printed k as 1.86e+03)
    grid = np.asarray(fig.axes).reshape(len(names), len(names))
    for i, n in enumerate(names):
        lo, med, hi = np.quantile(samples[:, i], [0.05, 0.5, 0.95])
        grid[i, i].set_title(f"{param_label(n)} = {value_with_errors(med, med - lo, hi - med)}")
    title = f"Posterior at φ = {phi:g} (lines: 5%, 50%, 95%)"
    if truth is not None:
        title += "; orange: synthetic truth"
    if data_label(dt):
        title = f"{data_label(dt)}\n{title}"
    # corner.py leaves room for the top panel's title only: make room for the figure's
    # title above it, so that the figure is complete without cropping (savefig once)
    height = fig.get_size_inches()[1]
    lines = suptitle(fig, title, y=1.0 - 0.08 / height, va="top").get_text().count("\n") + 1
    fig.subplots_adjust(top=1.0 - (0.5 + 0.25 * lines) / height)
    return fig


def plot_predictive(dt: xr.DataTree, ci_prob: float = CI_PROB) -> Figure:
    """Jump height vs volume fraction per command: data and posterior predictive bands.

    One panel per command; one colour per actuation frequency. Points: measured jumps;
    dark band: the simulated height (force-law uncertainty); light band: a new jump
    (simulated height plus scatter); both ``ci_prob`` equal-tailed.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit with posterior predictive and observed data.
    ci_prob : float
        Probability of the bands.

    Returns
    -------
    matplotlib.figure.Figure
    """
    obs = dt.observed_data.to_dataset()
    pp = dt.posterior_predictive.to_dataset()
    phi = obs["phi"].values
    command = obs["command"].values
    freq = obs["freq_hz"].values if "freq_hz" in obs.coords else np.zeros(len(phi))
    commands = [c for c in COMMAND_NAMES if c in set(command)]
    freqs = np.unique(freq)
    q = eti_probs(ci_prob)
    fig = Figure(figsize=(3.3 * len(commands), 3.6), layout="constrained")
    axes = fig.subplots(1, len(commands), sharey=True, squeeze=False)[0]
    rep = pp["height_mm"].values.reshape(-1, len(phi))
    sim = pp["height_sim_mm"].values.reshape(-1, len(phi))
    phis = np.unique(phi)
    dphi = 0.0015 * (len(freqs) > 1)
    spacing = float(np.min(np.diff(phis))) if len(phis) > 1 else 0.01
    half = 0.4 * dphi if dphi else 0.15 * spacing  # half-width of a lone volume fraction's box
    for ax, cmd in zip(axes, commands, strict=True):
        for j, f in enumerate(freqs):
            color = COLORS[j % len(COLORS)]
            off = (j - (len(freqs) - 1) / 2) * dphi
            bands = []
            for p in phis:
                sel = (command == cmd) & (freq == f) & (phi == p)
                if not np.any(sel):
                    bands.append((np.nan,) * 5)
                    continue
                i = np.flatnonzero(sel)[0]
                lo_r, _, hi_r = np.quantile(rep[:, i], q)
                lo_s, med, hi_s = np.quantile(sim[:, i], q)
                bands.append((lo_r, lo_s, med, hi_s, hi_r))
            b = np.array(bands)
            ax.fill_between(phis + off, b[:, 0], b[:, 4], color=color, alpha=0.15, lw=0)
            ax.fill_between(phis + off, b[:, 1], b[:, 3], color=color, alpha=0.4, lw=0)
            ax.plot(phis + off, b[:, 2], color=color, lw=1.2, label=f"{f:g} Hz")
            # a volume fraction with no measured neighbour in its series has no band to
            # join (one packing, or a gap): its bands are drawn as boxes
            finite = np.isfinite(b[:, 2])
            alone = finite & ~np.r_[False, finite[:-1]] & ~np.r_[finite[1:], False]
            for i in np.flatnonzero(alone):
                xs = phis[i] + off + np.array([-half, half])
                ax.fill_between(xs, b[i, 0], b[i, 4], color=color, alpha=0.15, lw=0)
                ax.fill_between(xs, b[i, 1], b[i, 3], color=color, alpha=0.4, lw=0)
                ax.plot(xs, [b[i, 2]] * 2, color=color, lw=1.2)
            sel = (command == cmd) & (freq == f)
            ax.plot(
                phi[sel] + off,
                obs["height_mm"].values[sel],
                "o",
                ms=3,
                color=color,
                mec="k",
                mew=0.3,
            )
        ax.set_title(cmd.replace("_", " "))
        ax.set_xlabel("volume fraction φ [-]")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("jump height H [mm]")
    axes[0].legend(title="actuation", fontsize=8)
    label = data_label(dt)
    suptitle(
        fig,
        (f"{label}\n" if label else "")
        + "Posterior predictive check: points = measured jumps; dark band = simulated height, "
        f"light band = new jump ({ci_prob:.0%} equal-tailed)",
        fontsize=10,
    )
    return fig


def plot_parameters_vs_phi(
    dt: xr.DataTree,
    var_names: list[str],
    phi_c: float,
    truth: Mapping[float, Mapping[str, float]] | None = None,
    ci_prob: float = CI_PROB,
) -> Figure:
    """Posterior median and ``ci_prob`` interval of each parameter against ``phi - phi_c``.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.
    var_names : list of str
        Parameters to plot.
    phi_c : float
        Critical packing fraction [-].
    truth : mapping, optional
        True values per volume fraction (synthetic data), drawn as crosses.
    ci_prob : float
        Probability of the intervals.

    Returns
    -------
    matplotlib.figure.Figure
    """
    post = dt.posterior.to_dataset()
    names = [n for n in var_names if n in post]
    phis = post["phi"].values
    x = phis - phi_c
    fig = Figure(figsize=(3.4 * len(names), 3.2), layout="constrained")
    axes = fig.subplots(1, len(names), squeeze=False)[0]
    q = eti_probs(ci_prob)
    for ax, n in zip(axes, names, strict=True):
        v = post[n].values.reshape(-1, len(phis))
        lo, med, hi = np.nanquantile(v, q, axis=0)
        ax.errorbar(
            x,
            med,
            yerr=[med - lo, hi - med],
            fmt="o",
            color=COLORS[0],
            capsize=3,
            label=f"posterior ({ci_prob:.0%} ETI)",
        )
        if truth:
            t = [truth.get(float(p), {}).get(n, np.nan) for p in phis]
            ax.plot(x, t, "x", color=COLORS[1], ms=8, mew=2, label="synthetic truth")
        ax.axvline(0.0, color="0.5", lw=0.8, ls=":")
        ax.set_xlabel("φ − φ_c [-]")
        ax.set_ylabel(param_label(n))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    if data_label(dt):
        suptitle(fig, data_label(dt), fontsize=10)
    return fig


def plot_trace(dt: xr.DataTree, var_names: Sequence[str]) -> Figure:
    """Trace of every walker, coloured by ensemble, with each ensemble's median per draw.

    One panel per parameter and volume fraction: the kept draws of each walker as a thin
    line and, per independent ensemble (started apart; the chains of the stopping rule's
    R-hat), the median over its walkers at each kept draw as a thick one. Ensembles that
    have not mixed show as medians at different levels, a walker stuck away from the
    others as a flat thin line. Drawn here rather than by ``arviz_plots.plot_trace``, whose
    chains would be either every walker (dozens of colours, no ensembles) or an ensemble's
    walkers concatenated into one line (:func:`granbayes.stats.by_ensemble`): a band of
    jumps between walkers at every draw, which hides both failures.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.
    var_names : sequence of str
        Parameters to plot.

    Returns
    -------
    matplotlib.figure.Figure
    """
    post = dt.posterior.to_dataset()
    n_ens = _n_ensembles(dt) or 1
    panels = []
    for name in var_names:
        da = post[name].transpose("chain", "draw", ...)
        extra = [d for d in da.dims if d not in ("chain", "draw")]
        stacked = da.stack(_panel=extra) if extra else da.expand_dims(_panel=[0], axis=-1)
        for j in range(stacked.sizes["_panel"]):
            at = stacked.isel(_panel=j)
            where = ", ".join(f"{d} = {_coordinate_text(at[d].item())}" for d in extra)
            panels.append((name, where, at.values))
    fig, axes, legend_ax = panel_grid(len(panels), width=3.4, height=2.3)
    for ax, (name, where, values) in zip(axes, panels, strict=True):
        draws = np.arange(values.shape[1])
        # chains are the walkers, ensemble by ensemble (granbayes._sampler)
        for e, walkers in enumerate(values.reshape(n_ens, -1, values.shape[1])):
            colour = COLORS[e % len(COLORS)]
            # one collection of every walker's line: one artist instead of one per walker
            # (a fit with tracked jumps has ~1,000 of them, whose drawing was half the
            # figure's time)
            lines = np.stack(np.broadcast_arrays(draws[None, :], walkers), axis=-1)
            ax.add_collection(LineCollection(lines, colors=colour, linewidths=0.4, alpha=0.25))
            ax.plot(draws, np.median(walkers, axis=0), color=colour, lw=1.5, label=f"ensemble {e}")
        ax.set_title(where, fontsize=9)
        ax.set_ylabel(param_label(name), fontsize=9)
        ax.set_xlabel("kept draw", fontsize=9)
        ax.tick_params(labelsize=8)
    if legend_ax is not None:
        legend_ax.legend(*axes[0].get_legend_handles_labels(), fontsize=8, loc="center")
    else:
        axes[0].legend(fontsize=7)
    title = "Walkers' traces (thin) and each ensemble's median over its walkers (thick)"
    label = data_label(dt)
    suptitle(fig, f"{label}\n{title}" if label else title, fontsize=10)
    return fig


def _coordinate_text(value: object) -> str:
    """A coordinate value as a panel title shows it (numbers in the shortest form)."""
    return f"{value:g}" if isinstance(value, (int, float, np.number)) else str(value)


def plot_rank(dt: xr.DataTree, var_names: Sequence[str]) -> Figure:
    """Rank plot (``arviz_plots.plot_rank``), one line per independent ensemble.

    The multi-chain uniformity test behind the p-values and the highlighted points assumes
    independent draws (Säilynoja et al. 2022), so the test sees one walker in turn per
    autocorrelation time of each ensemble
    (:func:`granbayes.stats._summaries.rank_test_draws`): few draws, so a test of little
    power, but one whose p-values mean what they say. The autocorrelation time
    comes from the fit's own ESS (the smallest over runs, the fit's draws over it;
    :func:`granbayes.stats.run_diagnostics`). Thinning an ensemble's walkers concatenated
    into one chain by that factor, as before, rejected uniformity at alpha = 0.01 in 21 of
    90 null replicates of a Gaussian target sampled like a fit
    (``benchmarks/rank_test_calibration.py``), and the reference data's fit showed
    p <= 0.01 in three of ten panels with R-hat <= 1.009.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.
    var_names : sequence of str
        Parameters to plot.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import arviz_plots as azp

    ess = run_diagnostics(dt)["ess_min"].astype(float)
    n_draws = dt.posterior.sizes["chain"] * dt.posterior.sizes["draw"]
    factor = math.ceil(n_draws / ess.min()) if ess.notna().all() and ess.min() > 0 else 1
    tree = xr.DataTree.from_dict({"posterior": rank_test_draws(dt, var_names, factor)})
    from matplotlib.lines import Line2D

    pc = azp.plot_rank(
        tree,
        var_names=list(var_names),
        thin=False,
        backend="matplotlib",
        labeller=_UnitLabeller({n: param_label(n) for n in var_names}),
        figure_kwargs={"layout": "constrained"},  # titles clear of the row above's labels
        color=list(COLORS),  # an ensemble's colour in the trace plot too
    )
    fig = pc.viz["figure"].item()
    for ax in fig.axes:
        ax.title.set_fontsize(9)
    n_test = tree["posterior"].sizes["draw"]
    if _n_ensembles(dt) is not None:
        # one colour per independent ensemble (the chains of the stopping rule's R-hat)
        n_ens = tree["posterior"].sizes["chain"]
        handles = [
            Line2D([], [], color=line.get_color(), label=f"ensemble {e}")
            for e, line in enumerate(fig.axes[0].get_lines()[:n_ens])
        ]
        fig.legend(handles=handles, loc="outside lower center", ncols=n_ens, fontsize=8)
        chains = (
            f"{n_test} draws per ensemble (one walker in turn every {factor} kept draws, "
            "the autocorrelation time)"
        )
    else:  # runs kept different numbers of ensembles: every walker is a chain
        chains = f"every walker a chain, every {factor}th kept draw ({n_test} per walker)"
    title = (
        "Rank plots: ECDF of each chain's ranks among all draws minus the uniform CDF; "
        f"p: ArviZ's multi-chain uniformity test on {chains}"
    )
    label = data_label(dt)
    suptitle(fig, f"{label}\n{title}" if label else title, fontsize=9)
    return fig


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
    dt: xr.DataTree,
    *,
    pit: np.ndarray | None = None,
    band_prob: float = 0.95,
    seed: int = 0,
    title: str = "",
) -> Figure:
    """LOO-PIT calibration plot of the jump heights (``arviz_plots.plot_ecdf_pit``).

    The difference between the ECDF of the LOO-PIT values and the uniform CDF, with
    ArviZ's simultaneous envelope and ``pot_c`` p-value; points that drive a departure are
    highlighted. Above zero in the middle (an S shape): the predictive distribution is too
    wide; below: too narrow; a shift at one end: biased predictions. This is
    ``arviz_plots.plot_loo_pit`` drawn from given values: that function computes them
    again (a second Pareto smoothing of every jump's weights, a second in a report).

    Parameters
    ----------
    dt : xarray.DataTree
        A fit's DataTree.
    pit : ndarray, shape (jump,), optional
        The LOO-PIT values (:func:`granbayes.stats.loo_pit`); computed if not given.
    band_prob : float
        Probability of the grey simultaneous band of a uniform sample of the same size
        (``arviz_stats.ecdf_utils.ecdf_pit``).
    seed : int
        Seed of the band's simulation.
    title : str
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import arviz_plots as azp
    from arviz_base import convert_to_datatree

    if pit is None:
        pit = loo_pit(dt)
    jumps = dt["observed_data"]["jump"]
    values = xr.Dataset({"height_mm": (("jump",), np.asarray(pit, dtype=float))})
    values = values.assign_coords(jump=jumps.values)
    pc = azp.plot_ecdf_pit(
        convert_to_datatree(values, group="loo_pit"),
        var_names=["height_mm"],
        group="loo_pit",
        sample_dims=["jump"],
        method="pot_c",
        backend="matplotlib",
        visuals={"ylabel": {}, "remove_axis": False, "xlabel": {"text": "LOO-PIT"}},
        figure_kwargs={"figsize": (6.4, 3.6)},
    )
    fig = pc.viz["figure"].item()
    n = dt["observed_data"].sizes["jump"]
    _draw_uniform_band(fig, n, band_prob, seed)
    for ax in fig.axes:
        ax.set_title("")
        ax.set_xlabel("LOO-PIT of the jump height H [-] (uniform if calibrated)")
        ax.set_ylabel("ECDF − uniform CDF [-]")
    suptitle(
        fig,
        (title + "\n" if title else "")
        + f"LOO-PIT calibration of {n} jumps; grey: {band_prob:.0%} simultaneous band "
        "of a calibrated model",
        fontsize=9,
    )
    fig.tight_layout()
    return fig


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
    *,
    labels: Mapping[str, str] | None = None,
    log10: Sequence[str] = (),
    title: str = "",
) -> Figure:
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
    labels : mapping of str to str, optional
        Panel label (with units) per parameter, e.g. ``"log₁₀ k (k in N/m)"``.
    log10 : sequence of str
        Parameters shown as ``log10`` of their value (log-uniform priors), so that the
        prior is flat and a narrow posterior stays visible.
    title : str
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import arviz_plots as azp
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
    suptitle(
        fig,
        (title + "\n" if title else "")
        + "Prior and posterior marginal density per volume fraction\n"
        + "(a posterior as wide as its prior: the data do not determine the parameter)",
        fontsize=9,
    )
    return fig


def plot_sbc_ecdf(
    pit: Mapping[str, np.ndarray],
    phis: Sequence[float],
    *,
    band_prob: float = 0.95,
    seed: int = 0,
    title: str = "",
) -> Figure:
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
    band_prob : float
        Probability of the simultaneous band.
    seed : int
        Seed of the band's simulation.
    title : str
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import arviz_plots as azp

    ds = _sbc_dataset(pit, phis)
    n = ds.sizes["replicate"]
    n_phi, n_var = len(phis), len(pit)
    # a row per parameter and a column per volume fraction; one volume fraction: 4 across
    n_col = n_phi if n_phi > 1 else min(4, n_var)
    n_row = math.ceil(n_var * n_phi / n_col)
    pc = azp.plot_ecdf_pit(
        xr.DataTree.from_dict({"prior_sbc": ds}),
        group="prior_sbc",
        sample_dims=["replicate"],
        envelope_prob=band_prob,
        backend="matplotlib",
        labeller=_UnitLabeller({name: param_label(name) for name in pit}),
        col_wrap=n_col,
        figure_kwargs={"figsize": (2.8 * n_col + 0.6, 2.3 * n_row + 0.8)},
    )
    fig = pc.viz["figure"].item()
    _draw_uniform_band(fig, n, band_prob, seed)
    for ax in fig.axes:
        ax.title.set_fontsize(9)
        if ax.get_xlabel():
            ax.set_xlabel("normalised rank of the truth [-]", fontsize=8)
    text = (title + "\n" if title else "") + (
        f"ECDF - uniform of the normalised ranks ({n} replicates); grey: "
        f"{band_prob:.0%} simultaneous band"
    )
    suptitle(fig, text, fontsize=9)
    fig.tight_layout()
    return fig
