"""Reports of fits: tables, figures and a Markdown summary written into a folder.

Figures are built with matplotlib's object API (no pyplot state), corner plots with
``corner`` (>= 2.3) from plain arrays, and trace/rank plots through the ArviZ adapter
(:mod:`granbayes.datatree`).
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr
from matplotlib.figure import Figure

from . import datatree as gdt
from . import stats
from .experiment import COMMAND_NAMES
from .forces import parameter

__all__ = [
    "data_label",
    "markdown_table",
    "source_label",
    "load_truth",
    "plot_corner",
    "plot_predictive",
    "plot_parameters_vs_phi",
    "write_fit_report",
    "plot_residual_heatmap",
    "write_diagnosis_report",
]

#: Label and unit of the noise parameter; those of the force-term parameters are in the
#: registry (:data:`granbayes.forces.TERMS`).
_NOISE_LABELS: dict[str, tuple[str, str]] = {"sigma_mm": ("σ [mm]", "mm")}
_COLORS = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00")


def load_truth(path: str | Path) -> dict[float, dict[str, float]]:
    """Read a ``truth.toml`` (as written by ``data/generate_reference.py``).

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    dict of float to dict
        Per volume fraction, the true parameter values (and ``sigma_mm``).
    """
    doc = tomllib.loads(Path(path).read_text())
    return {float(phi): dict(v) for phi, v in doc.get("phi", {}).items()}


def data_label(dt: xr.DataTree) -> str:
    """``"SYNTHETIC data (<generator>)"`` if the jumps say so in a ``source`` column, else ``""``.

    Synthetic data sets mark every row (``source = "synthetic: <generator> seed=<n>"``);
    every figure and summary of such data carries this label.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit.

    Returns
    -------
    str
    """
    obs = dt.observed_data.to_dataset()
    if "source" not in obs.coords:
        return ""
    return source_label(obs["source"].values)


def source_label(sources: Iterable[object]) -> str:
    """``"SYNTHETIC data (<generator>)"`` if any of the ``source`` values is synthetic, else ``""``.

    Parameters
    ----------
    sources : iterable
        The ``source`` column of a jumps table (one value per jump).
    """
    synthetic = sorted({str(v) for v in sources if str(v).startswith("synthetic")})
    if not synthetic:
        return ""
    return (
        "SYNTHETIC data ("
        + "; ".join(s.removeprefix("synthetic:").strip() for s in synthetic)
        + ")"
    )


def _unit(name: str) -> str | None:
    """Unit of a parameter (from the force-term registry), or None if it is unknown."""
    if name in _NOISE_LABELS:
        return _NOISE_LABELS[name][1]
    try:
        return parameter(name).unit
    except KeyError:
        return None


def _label(name: str) -> str:
    """Axis and table label of a parameter, e.g. ``"k2 [N/m²]"`` (from the registry)."""
    if name in _NOISE_LABELS:
        return _NOISE_LABELS[name][0]
    try:
        return parameter(name).label
    except KeyError:
        return f"{name} []"


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
        labels=[_label(n) for n in names],
        quantiles=[0.05, 0.5, 0.95],
        show_titles=True,
        title_fmt=".3g",
        truths=truths,
        truth_color="#D55E00",
        bins=30,
        smooth=0.8,
        # density and contours, not the ~3,000 draws as points (half the drawing time)
        plot_datapoints=False,
    )
    title = f"Posterior at φ = {phi:g} (lines: 5%, 50%, 95%)"
    if truth is not None:
        title += "; orange: synthetic truth"
    if data_label(dt):
        title = f"{data_label(dt)}\n{title}"
    fig.suptitle(title, y=1.0)
    return fig


def plot_predictive(dt: xr.DataTree, ci_prob: float = stats.CI_PROB) -> Figure:
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
    q = stats.eti_probs(ci_prob)
    fig = Figure(figsize=(3.3 * len(commands), 3.6), layout="constrained")
    axes = fig.subplots(1, len(commands), sharey=True, squeeze=False)[0]
    rep = pp["height_mm"].values.reshape(-1, len(phi))
    sim = pp["height_sim_mm"].values.reshape(-1, len(phi))
    phis = np.unique(phi)
    dphi = 0.0015 * (len(freqs) > 1)
    for ax, cmd in zip(axes, commands, strict=True):
        for j, f in enumerate(freqs):
            color = _COLORS[j % len(_COLORS)]
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
    fig.suptitle(
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
    ci_prob: float = stats.CI_PROB,
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
    q = stats.eti_probs(ci_prob)
    for ax, n in zip(axes, names, strict=True):
        v = post[n].values.reshape(-1, len(phis))
        lo, med, hi = np.nanquantile(v, q, axis=0)
        ax.errorbar(
            x,
            med,
            yerr=[med - lo, hi - med],
            fmt="o",
            color=_COLORS[0],
            capsize=3,
            label=f"posterior ({ci_prob:.0%} ETI)",
        )
        if truth:
            t = [truth.get(float(p), {}).get(n, np.nan) for p in phis]
            ax.plot(x, t, "x", color=_COLORS[1], ms=8, mew=2, label="synthetic truth")
        ax.axvline(0.0, color="0.5", lw=0.8, ls=":")
        ax.set_xlabel("φ − φ_c [-]")
        ax.set_ylabel(_label(n))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    if data_label(dt):
        fig.suptitle(data_label(dt), fontsize=10)
    return fig


def markdown_table(df: pd.DataFrame, floatfmt: str = ".4g", missing: str | None = None) -> str:
    """A GitHub Markdown table of ``df`` (no tabulate dependency).

    Parameters
    ----------
    df : pandas.DataFrame
    floatfmt : str
        Format of floating-point cells.
    missing : str, optional
        Text of non-finite floats (default: formatted like any float, ``nan``).
    """
    cols = list(df.columns)
    lines = ["| " + " | ".join(str(c) for c in cols) + " |", "|" + "---|" * len(cols)]
    for row in df.itertuples(index=False):
        cells = []
        for v in row:
            if isinstance(v, float | np.floating):
                finite = math.isfinite(v)
                cells.append(
                    missing if missing is not None and not finite else format(float(v), floatfmt)
                )
            else:
                cells.append(str(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_fit_report(
    dt: xr.DataTree,
    out: Path,
    *,
    truth: Mapping[float, Mapping[str, float]] | None = None,
    uniqueness: pd.DataFrame | None = None,
    diagnostics_plots: bool = True,
) -> list[Path]:
    """Write the posterior, tables and figures of a fit into ``out``.

    Parameters
    ----------
    dt : xarray.DataTree
        A fit's DataTree (``FitResult.datatree``, or ``posterior.nc`` read back): the
        report reads nothing else, so any saved fit can be re-rendered.
    out : Path
        Existing folder.
    truth : mapping, optional
        Synthetic truth per volume fraction (overlaid on figures, compared in the summary).
    uniqueness : pandas.DataFrame, optional
        Output of :func:`granbayes.fitting.compare_commands`.
    diagnostics_plots : bool
        Whether to draw trace and rank plots.

    Returns
    -------
    list of Path
        Files written.
    """
    out = Path(out)
    written: list[Path] = []
    if truth:  # kept with the posterior, so that a re-rendered report shows it too
        dt = dt.copy()
        dt.attrs["truth"] = json.dumps({repr(float(k)): dict(v) for k, v in truth.items()})
    elif "truth" in dt.attrs:
        truth = {float(k): v for k, v in json.loads(dt.attrs["truth"]).items()}
    gdt.write_datatree(dt, out / "posterior.nc")
    written.append(out / "posterior.nc")
    config = json.loads(dt.attrs["config"])
    force_names = list(json.loads(dt.attrs["parameters"]))
    names = [*force_names, "sigma_mm"]
    fit_warnings = json.loads(dt.attrs.get("warnings", "[]"))
    summary = stats.summary_table(dt, var_names=names).reset_index(names="parameter")
    if truth:
        summary["truth"] = [_truth_of(truth, label) for label in summary["parameter"]]
    summary.to_csv(out / "summary.csv", index=False)
    diag = stats.run_diagnostics(dt)
    diag.to_csv(out / "diagnostics.csv", index=False)
    loo = stats.loo(dt)
    pit = stats.loo_pit(dt)
    pit_p = stats.pit_uniformity(pit) if np.all(np.isfinite(pit)) else float("nan")
    phi_c = json.loads(dt.attrs["experiment"])["phi_c"]
    lines = [
        "# granbayes fit",
        "",
        *([f"**{data_label(dt)}**", ""] if data_label(dt) else []),
        f"- data: {dt.attrs.get('data_source', '')} (sha256 {dt.attrs['data_sha256'][:12]}…)",
        f"- terms: {', '.join(config['terms'])}; parametrisation across φ: "
        f"{config['phi_mode']}; noise: {config['noise']}",
        f"- seed: {dt.attrs['seed']}; intervals: {stats.CI_PROB:.0%} equal-tailed (ETI)",
        f"- PSIS-LOO: elpd = {loo['elpd']:.1f} ± {loo['se']:.1f}, p_loo = {loo['p']:.1f}, "
        f"max Pareto k = {loo['max_pareto_k']:.2f} ({loo['n_bad_k']} jumps with k > "
        f"{loo['good_k']:.2f})",
        f"- LOO-PIT calibration of the jump heights: uniformity p = {pit_p:.2f} "
        "(ArviZ `pot_c`; small p: the predictive distribution is mis-calibrated, see "
        "`loo_pit.png`)",
        "",
    ]
    if fit_warnings:
        lines += ["**Warnings**", ""] + [f"- {w}" for w in fit_warnings] + [""]
    lines += ["## Posterior summary", "", markdown_table(summary), "", "## Sampler", ""]
    lines += [
        markdown_table(
            diag[
                [
                    "run",
                    "n_ensembles",
                    "n_chains",
                    "n_steps",
                    "tau_max",
                    "steps_over_tau",
                    "rhat_max",
                    "ess_min",
                    "acceptance",
                    "converged",
                ]
            ]
        ),
        "",
    ]
    ident = stats.identifiability_table(dt, names)
    if len(ident):
        ident.to_csv(out / "identifiability.csv", index=False)
        written.append(out / "identifiability.csv")
        lines += [
            "## Identifiability",
            "",
            "What the data determine, per parameter and volume fraction: the contraction "
            "1 − var(posterior) / var(prior), in the coordinate the prior is defined in "
            "(the logarithm for log-uniform and log-normal priors). Near 0 the posterior is "
            "the prior: the data say nothing about the parameter, and its interval is the "
            "prior's range; near 1 the data pin it down. Verdicts: < 0.1 not identified, "
            "< 0.5 weakly identified, < 0.9 identified, else well identified.",
            "",
            markdown_table(
                ident.assign(
                    contraction=ident["contraction"].map("{:.3f}".format),
                    prior_sd=ident["prior_sd"].map("{:.3g}".format),
                    posterior_sd=ident["posterior_sd"].map("{:.3g}".format),
                )
            ),
            "",
        ]
    if uniqueness is not None:
        uniqueness.to_csv(out / "uniqueness.csv", index=False)
        lines += [
            "## One force law for every jump?",
            "",
            "Per volume fraction: one parameter set shared by the five commands against "
            "separate parameters per command, by PSIS-LOO (`elpd_diff` = shared − "
            "per-command; the shared law is preferred unless per-command is better by more "
            "than 2 SE). `*_intervals_overlap`: whether the per-command "
            f"{stats.CI_PROB:.0%} intervals of a parameter share a common value.",
            "",
            markdown_table(uniqueness),
            "",
        ]
    figs: dict[str, Figure] = {"predictive.png": plot_predictive(dt)}
    figs["parameters_vs_phi.png"] = plot_parameters_vs_phi(dt, names, phi_c, truth)
    for phi in dt.posterior["phi"].values:
        t = truth.get(float(phi)) if truth else None
        figs[f"corner_phi{phi:g}.png"] = plot_corner(dt, float(phi), names, t)
    for name, fig in figs.items():
        fig.savefig(out / name, dpi=120, bbox_inches="tight")
        written.append(out / name)
    label = data_label(dt)
    if "prior" in dt.children:
        written.append(
            gdt.plot_prior_posterior(
                dt,
                names,
                out / "prior_posterior.png",
                labels=_prior_posterior_labels(dt, names),
                log10=[n for n in names if _log_scale(dt, n)],
                title=label,
            )
        )
    if np.all(np.isfinite(pit)):
        written.append(gdt.plot_loo_pit(dt, out / "loo_pit.png", title=label))
    if diagnostics_plots:
        written += gdt.plot_diagnostics(dt, force_names, out)
    lines += ["## Figures", ""] + [f"![{p.stem}]({p.name})" for p in written if p.suffix == ".png"]
    summary_md = out / "summary.md"
    summary_md.write_text("\n".join(lines) + "\n")
    written += [out / "summary.csv", out / "diagnostics.csv", summary_md]
    return written


def _log_scale(dt: xr.DataTree, name: str) -> bool:
    """Whether the fit's prior on ``name`` is log-scale (log-uniform or log-normal)."""
    prior = json.loads(dt.attrs["priors"]).get(name)
    return prior is not None and prior["dist"] in ("loguniform", "lognormal")


def _prior_posterior_labels(dt: xr.DataTree, names: list[str]) -> dict[str, str]:
    """Panel labels with units; log-scale parameters as ``log₁₀ k (k in N/m)``."""
    out = {}
    for n in names:
        symbol = _label(n).split(" [")[0]
        out[n] = (
            f"log₁₀ {symbol} ({symbol} in {_unit(n) or '-'})" if _log_scale(dt, n) else _label(n)
        )
    return out


def _truth_of(truth: Mapping[float, Mapping[str, float]], label: str) -> float:
    name, _, rest = label.partition("[")
    try:
        phi = float(rest.rstrip("]"))
    except ValueError:
        return float("nan")
    return float(truth.get(phi, {}).get(name, np.nan))


_SETTING_UNITS = {"amplitude_mm": "mm", "delay_ms": "ms", "settle_periods": "T"}


def _row_labels(residuals: pd.DataFrame) -> tuple[pd.Series, list[int]]:
    """Heat-map row of every cell: its command, plus the settings that vary for it."""
    varying = [
        k
        for k in _SETTING_UNITS
        if k in residuals and residuals.groupby("command")[k].nunique().max() > 1
    ]
    labels = []
    for r in residuals.to_dict("records"):
        extra = [f"{r[k]:g} {_SETTING_UNITS[k]}" for k in varying]
        labels.append(r["command"] + (f" ({', '.join(extra)})" if extra else ""))
    order = [COMMAND_NAMES.index(c) for c in residuals["command"]]
    return pd.Series(labels, index=residuals.index), order


def plot_residual_heatmap(residuals: pd.DataFrame, title: str, z_threshold: float = 3.0) -> Figure:
    """Mean residual (observed - simulated) per command x phi, one panel per frequency.

    Cells are coloured by the mean residual [mm] (red: the model under-predicts) and
    annotated with it and the z-score; cells with |z| above ``z_threshold`` are framed.

    Parameters
    ----------
    residuals : pandas.DataFrame
        Cells (:func:`granbayes.criticism.residual_table`).
    title : str
        Figure title.
    z_threshold : float
        Misfit threshold of |z|.

    Returns
    -------
    matplotlib.figure.Figure
    """
    rows, order = _row_labels(residuals)
    residuals = residuals.assign(row=rows, order=order)
    freqs = sorted(residuals["freq_hz"].unique())
    phis = sorted(residuals["phi"].unique())
    commands = list(dict.fromkeys(residuals.sort_values("order")["row"]))
    vmax = max(5.0, float(np.nanmax(np.abs(residuals["mean_residual_mm"]))))
    fig = Figure(
        figsize=(1.25 * len(phis) * len(freqs) + 3.0, 0.55 * len(commands) + 1.8),
        layout="constrained",
    )
    axes = fig.subplots(1, len(freqs), squeeze=False, sharey=True)[0]
    image = None
    for ax, f in zip(axes, freqs, strict=True):
        grid = np.full((len(commands), len(phis)), np.nan)
        zs = np.full_like(grid, np.nan)
        sub = residuals[residuals["freq_hz"] == f]
        for r in sub.itertuples():
            i, j = commands.index(r.row), phis.index(r.phi)
            grid[i, j], zs[i, j] = r.mean_residual_mm, r.z
        image = ax.imshow(grid, cmap="RdBu_r", vmin=-vmax, vmax=vmax, aspect="auto")
        for i in range(len(commands)):
            for j in range(len(phis)):
                if np.isnan(grid[i, j]):
                    continue
                strong = abs(zs[i, j]) > z_threshold
                dark = abs(grid[i, j]) > 0.55 * vmax
                ax.text(
                    j,
                    i,
                    f"{grid[i, j]:+.1f}\nz={zs[i, j]:+.1f}",
                    ha="center",
                    va="center",
                    fontsize=7,
                    color="white" if dark else "black",
                    fontweight="bold" if strong else "normal",
                )
                if strong:
                    ax.add_patch(_frame(j, i))
        ax.set_xticks(range(len(phis)), [f"{p:g}" for p in phis])
        ax.set_yticks(range(len(commands)), [c.replace("_", " ") for c in commands])
        ax.set_xlabel("volume fraction φ [-]")
        ax.set_title(f"{f:g} Hz" if f else "")
    fig.colorbar(image, ax=list(axes), label="mean residual: observed − simulated [mm]")
    fig.suptitle(
        title + f"\nmean residual [mm] and lack-of-fit z per cell (framed: |z| > {z_threshold:g})",
        fontsize=10,
    )
    return fig


def _frame(j: int, i: int):
    from matplotlib.patches import Rectangle

    return Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, lw=2, ec="k")


def write_diagnosis_report(record: Mapping, selected: xr.DataTree, out: Path) -> list[Path]:
    """Write ``diagnosis.json``, residual tables, heat maps and ``report.md`` into ``out``.

    Reads only saved results: the ``diagnosis.json`` document and the selected law's
    DataTree, so a diagnosis can be re-rendered from its files.

    Parameters
    ----------
    record : mapping
        The ``diagnosis.json`` document (``Diagnosis.to_json()``).
    selected : xarray.DataTree
        The selected law's fit (written as ``posterior_selected.nc``).
    out : Path
        Existing folder.

    Returns
    -------
    list of Path
    """
    out = Path(out)
    rec = dict(record)
    label = data_label(selected)
    written = [out / "diagnosis.json"]
    (out / "diagnosis.json").write_text(json.dumps(rec, indent=2, default=float) + "\n")
    before = pd.DataFrame(rec["misfit"])
    after = pd.DataFrame(rec["selected"]["per_cell"]).rename(
        columns={"residual_after_mm": "mean_residual_mm", "z_after": "z"}
    )
    before.to_csv(out / "residuals_baseline.csv", index=False)
    after.to_csv(out / "residuals_selected.csv", index=False)
    pd.DataFrame([{**c, "added": "+".join(c["added"])} for c in rec["candidates"]]).to_csv(
        out / "candidates.csv", index=False
    )
    z = rec["rule"]["z_threshold"]
    base_terms = " + ".join(rec["baseline"]["terms"])
    sel_terms = " + ".join(rec["selected"]["terms"])
    prefix = f"{label}: " if label else ""
    figs = {
        "residuals_baseline.png": plot_residual_heatmap(
            before, f"{prefix}baseline {base_terms}", z
        ),
        "residuals_selected.png": plot_residual_heatmap(after, f"{prefix}selected {sel_terms}", z),
        "predictive_selected.png": plot_predictive(selected),
    }
    for name, fig in figs.items():
        fig.savefig(out / name, dpi=120, bbox_inches="tight")
        written.append(out / name)
    gdt.write_datatree(selected, out / "posterior_selected.nc")
    written.append(out / "posterior_selected.nc")
    lines = [f"# What the simulation gets wrong: {Path(rec.get('data_source', '')).name}", ""]
    if label:
        lines += [f"**{label}**", ""]
    lines += _verdict_lines(rec, base_terms)
    worst = [m for m in rec["misfit"] if m["significant"]][:5]
    lines += ["", f"Baseline misfit ({rec['n_misfit_cells']} cells with |z| > {z:.2f}):", ""]
    lines += [f"- {m['description']}" for m in worst] or ["- none"]
    lines += [
        "",
        "## Candidates (PSIS-LOO; exact refits or K-fold where Pareto k exceeds ArviZ's good_k)",
        "",
    ]
    cand = pd.DataFrame([_candidate_row(c, base_terms) for c in rec["candidates"]])
    lines += [markdown_table(cand) if len(cand) else "(none)", "", f"Rule: {rec['rule']['text']}."]
    lines += ["", "## Fits the decision rests on", ""]
    lines += [
        f"- {' + '.join(f['terms'])}: {'converged' if f['converged'] else 'NOT converged'}"
        + (f" ({f['reruns']} rerun(s))" if f["reruns"] else "")
        + "".join(f"; {w}" for w in f["warnings"])
        for f in rec["fits"]
    ]
    lines += ["", *_added_physics_lines(rec["selected"]), "## Figures", ""]
    lines += [f"![{n}]({n})" for n in figs]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    written.append(out / "report.md")
    return written


def _fmt(value: float | None, spec: str) -> str:
    """A number of ``diagnosis.json`` (``null`` for not computed) as table text."""
    return "-" if value is None else format(value, spec)


def _candidate_row(c: Mapping, base_terms: str) -> dict[str, str]:
    """One row of the candidates table (screened-out candidates have no ELPD)."""
    screened = c["elpd_diff"] is None
    return {
        "round": str(c["round"]),
        "law": base_terms + "".join(f" + {t}" for t in c["added"]),
        "log-lik gain (screen)": _fmt(c.get("screen_gain"), "+.1f"),
        "elpd gain vs current": "-"
        if screened
        else f"{c['elpd_diff_vs_current']:+.1f} ± {c['elpd_diff_vs_current_se']:.1f}",
        "elpd gain vs baseline": "-"
        if screened
        else f"{c['elpd_diff']:+.1f} ± {c['elpd_diff_se']:.1f}",
        "rmse [mm]": _fmt(c["rmse_mm"], ".2f"),
        "elpd behind the chosen": "-"
        if c.get("elpd_diff_vs_selected") is None
        else f"{c['elpd_diff_vs_selected']:+.1f} ± {c['elpd_diff_vs_selected_se']:.1f}",
        "max Pareto k": _fmt(c["max_pareto_k"], ".2f"),
        "method": c["method"],
        "converged": "-" if screened else ("yes" if c["converged"] else "NO"),
    }


def _verdict_lines(rec: Mapping, base_terms: str) -> list[str]:
    """The verdict in words (data-format.md's three verdicts)."""
    sel = rec["selected"]
    gain = (
        f"{sel['elpd_gain']:.1f} ± {sel['elpd_gain_se']:.1f} nats of ELPD "
        f"({sel['elpd_gain_cells']:.1f} ± {sel['elpd_gain_cells_se']:.1f} predicting "
        f"unseen settings, leave-one-cell-out)"
    )
    rmse = f"RMSE {sel['rmse_before_mm']:.2f} mm -> {sel['rmse_after_mm']:.2f} mm"
    ties = _tie_lines(sel)
    if rec["verdict"] == "extended":
        return [
            f"**Verdict: extended.** The baseline law ({base_terms}) misses physics; adding "
            f"**{', '.join(sel['added'])}** gains {gain}, {rmse}, and leaves no misfit cell.",
            *ties,
        ]
    if rec["verdict"] == "baseline_adequate":
        return [
            f"**Verdict: baseline adequate.** No misfit cell and no candidate term improves "
            f"the baseline ({base_terms}) by a clear margin; RMSE {sel['rmse_before_mm']:.2f} mm."
        ]
    unconverged = [
        f"{c['term']} ({c['elpd_diff_vs_current']:+.1f} ± {c['elpd_diff_vs_current_se']:.1f})"
        for c in rec["candidates"]
        if not c["converged"] and c["elpd_diff"] is not None
    ]
    if sel["added"]:
        helped = (
            f"Adding {', '.join(sel['added'])} helped ({gain}, {rmse}) but does not explain it. "
        )
    elif unconverged:
        helped = (
            "No converged library term removes it; these candidates did not converge, so "
            f"nothing was decided on them: {', '.join(unconverged)}. "
        )
    else:
        helped = "No library term removes it. "
    where = [f"- {m['description']}" for m in rec["residual_misfit"][:8]]
    return [
        "**Verdict: misfit remains.** The data show physics that the library does not hold. "
        + helped
        + "No term is named as the cause. Where the law still fails:",
        "",
        *where,
        *ties,
    ]


def _tie_lines(sel: Mapping) -> list[str]:
    """The added terms the data do not tell from another candidate, in words."""
    ties = sel.get("indistinguishable", [])
    if not ties:
        return []
    by_term: dict[str, list[str]] = {}
    for t in ties:
        by_term.setdefault(t["selected"], []).append(
            f"{t['term']} ({t['elpd_diff']:+.1f} ± {t['elpd_diff_se']:.1f} nats behind"
            + ("" if t["converged"] else ", not converged")
            + ")"
        )
    said = "; ".join(f"**{k}** from {', '.join(v)}" for k, v in by_term.items())
    rate_pair = any({t["selected"], t["term"]} == {"drag", "viscous"} for t in ties)
    return [
        "",
        f"**Not distinguished on these data:** {said}. The data predict about as well with "
        "either term (a difference below the rule's margin), so the named term is the "
        "better-scoring of equals, not an established cause; an experiment designed to "
        "separate them would decide"
        + (
            " (drag grows with the square of the intrusion speed, viscous damping linearly: "
            "jumps over a wider range of intrusion speeds, from more actuation frequencies "
            "and commands, and more repeats per cell separate them)."
            if rate_pair
            else "."
        ),
    ]


def _added_physics_lines(sel: Mapping) -> list[str]:
    if not sel["parameters"]:
        return []
    lines = ["## The added physics", "", f"Posterior ({sel['interval']}):", ""]
    for name, per_phi in sel["parameters"].items():
        cells = ", ".join(
            f"φ={phi}: {v[1]:.3g} [{v[0]:.3g}, {v[2]:.3g}]" for phi, v in per_phi.items()
        )
        lines.append(f"- `{name}`: {cells}")
    improved = sorted(sel["per_cell"], key=lambda c: -abs(c["z_before"]))[:5]
    lines += ["", "Largest misfits, before -> after:", ""]
    lines += [
        f"- {c['command'].replace('_', ' ')} at φ = {c['phi']:g} ({c['freq_hz']:g} Hz): "
        f"{c['residual_before_mm']:+.1f} mm (z {c['z_before']:+.1f}) -> "
        f"{c['residual_after_mm']:+.1f} mm (z {c['z_after']:+.1f})"
        for c in improved
    ]
    return [*lines, ""]
