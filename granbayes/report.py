"""Reports of fits: tables, figures and a Markdown summary written into a folder.

Figures are built with matplotlib's object API (no pyplot state), corner plots with
``corner`` (>= 2.3) from plain arrays, and rank plots through the ArviZ adapter
(:mod:`granbayes._datatree`).

Also public here, for scripts that write results of their own (``analyses/``):
:func:`staged_folder` (an output folder built as ``OUT.partial`` and swapped in whole)
and :func:`environment` (the package versions and the machine, for provenance).
"""

from __future__ import annotations

import fnmatch
import json
import math
import tomllib
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine

from . import _datatree as gdt
from . import figures, stats
from ._files import staged_folder
from ._provenance import environment
from .kinds import KINDS

__all__ = [
    "environment",
    "load_truth",
    "markdown_table",
    "staged_folder",
    "write_diagnosis_report",
    "write_fit_report",
]


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
        Output of :func:`granbayes.compare_commands`.
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
    # the observation models' parameters of the kinds the fit holds
    # the robot parameters sampled with their calibration as prior, after the force law's
    calibrated = list(json.loads(dt.attrs.get("calibrated", "{}")))
    names = [*force_names, *calibrated, *(n for n in _NOISE_NAMES if n in dt.posterior)]
    fit_warnings = json.loads(dt.attrs.get("warnings", "[]"))
    summary = stats.summary_table(dt, var_names=names).reset_index(names="parameter")
    if truth:
        summary["truth"] = [_truth_of(truth, label) for label in summary["parameter"]]
    summary.to_csv(out / "summary.csv", index=False)
    diag = stats.run_diagnostics(dt)
    diag.to_csv(out / "diagnostics.csv", index=False)
    loo = stats.loo(dt, log_weights=True)
    kinds = [k for k in KINDS.values() if k.unit_dim in dt["log_likelihood"].dims]
    heights = "height_mm" in dt["observed_data"]
    pit = np.array([np.nan])
    if heights:  # with the heights' smoothed weights of the LOO above, where it has them
        weights = loo["log_weights"]
        pareto_k = None if weights is None else loo["pareto_k"]
        pit = stats.loo_pit(dt, log_weights=weights, pareto_k=pareto_k)
    pit_p = stats.pit_uniformity(pit) if np.all(np.isfinite(pit)) else float("nan")
    units = ", ".join(f"a {k.unit_dim} ({k.name})" for k in kinds)
    phi_c = json.loads(dt.attrs["experiment"])["phi_c"]
    lines = [
        "# granbayes fit",
        "",
        *([f"**{figures.data_label(dt)}**", ""] if figures.data_label(dt) else []),
        f"- data: {dt.attrs.get('data_source', '')} (sha256 {dt.attrs['data_sha256'][:12]}…)",
        f"- terms: {', '.join(config['terms'])}; parametrisation across φ: "
        f"{config['phi_mode']}; noise: {config['noise']}",
        f"- seed: {dt.attrs['seed']}; intervals: {stats.CI_PROB:.0%} equal-tailed (ETI)",
        f"- PSIS-LOO: elpd = {loo['elpd']:.1f} ± {loo['se']:.1f}, p_loo = {loo['p']:.1f}, "
        f"max Pareto k = {loo['max_pareto_k']:.2f} ({loo['n_bad_k']} units with k > "
        f"{loo['good_k']:.2f}; units of leave-one-out: {units})",
        *(
            [
                f"- LOO-PIT calibration of the jump heights: uniformity p = {pit_p:.2f} "
                "(ArviZ `pot_c`; small p: the predictive distribution is mis-calibrated, "
                "see `loo_pit.png`)"
            ]
            if heights
            else []
        ),
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
    lines += _kind_cell_lines(dt, kinds, out, written)
    label = figures.data_label(dt)
    figs: dict[str, Figure] = {}
    for kind in kinds:
        for stem, draw in kind.figures.items():
            figs[f"{stem}.png"] = draw(dt)
    figs["parameters_vs_phi.png"] = figures.plot_parameters_vs_phi(dt, names, phi_c, truth)
    for phi in dt.posterior["phi"].values:
        t = truth.get(float(phi)) if truth else None
        figs[f"corner_phi{phi:g}.png"] = figures.plot_corner(dt, float(phi), names, t)
    if "prior" in dt.children:
        figs["prior_posterior.png"] = figures.plot_prior_posterior(
            dt,
            names,
            labels=_prior_posterior_labels(dt, names),
            log10=[n for n in names if _log_scale(dt, n)],
            title=label,
        )
    if np.all(np.isfinite(pit)):
        figs["loo_pit.png"] = figures.plot_loo_pit(dt, pit=pit, title=label)
    if diagnostics_plots:
        figs["trace.png"] = figures.plot_trace(dt, force_names)
        figs["rank.png"] = figures.plot_rank(dt, force_names)
    written += _save_figures(figs, out)
    lines += ["## Figures", ""] + [f"![{p.stem}]({p.name})" for p in written if p.suffix == ".png"]
    summary_md = out / "summary.md"
    summary_md.write_text("\n".join(lines) + "\n")
    written += [out / "summary.csv", out / "diagnostics.csv", summary_md]
    return written


#: Observation-model parameters reported with the force law's, when a fit has them.
_NOISE_NAMES = ("sigma_mm", "frame_sd_foot_mm", "frame_sd_rod_mm", "frame_tau_ms", "force_sd_N")


def _kind_cell_lines(dt: xr.DataTree, kinds: list, out: Path, written: list[Path]) -> list[str]:
    """Residual cells of the kinds beyond heights: a CSV each and the worst in the summary."""
    lines: list[str] = []
    for kind in kinds:
        if kind.name == "heights" or kind.cells is None:
            continue
        cells = kind.cells(dt)
        path = out / f"cells_{kind.name}.csv"
        cells.to_csv(path, index=False)
        written.append(path)
        worst = cells.head(8).assign(kind=kind.name)
        lines += [
            f"## Where the law misses: {kind.name}",
            "",
            "Observed mean of each cell against the posterior predictive distribution of that "
            "mean (replicates carry the fitted noise, its correlation and, for tracked jumps, "
            f"the clock offset); the worst cells by |z| (all in `{path.name}`):",
            "",
            *[f"- {stats.describe_cell(r)}" for r in worst.to_dict("records")],
            "",
        ]
    return lines


#: How each figure is saved: ``savefig`` keywords by file name pattern (default: 120 dpi,
#: and a tight bounding box unless the figure lays itself out, see :func:`_save_figures`).
#: The corner plots lay themselves out too (corner.py's margins, and room for the title
#: made by :func:`granbayes.figures.plot_corner`): cropping drew each twice.
_SAVE = {
    "prior_posterior.png": {"dpi": 110},
    "loo_pit.png": {"dpi": 110},
    "trace.png": {"dpi": 110},
    "rank.png": {"dpi": 110},
    "corner_phi*.png": {"dpi": 120},
}


def _save_options(name: str) -> dict:
    """``savefig`` keywords of the figure file ``name`` (:data:`_SAVE`)."""
    for pattern, options in _SAVE.items():
        if fnmatch.fnmatchcase(name, pattern):
            return dict(options)
    return {"dpi": 120, "bbox_inches": "tight"}


def _save_figures(figs: Mapping[str, Figure], out: Path) -> list[Path]:
    """Save figures as PNG files into ``out`` and release them (pyplot's too)."""
    from matplotlib import pyplot as plt

    written = []
    for name, fig in figs.items():
        kwargs = _save_options(name)
        if isinstance(fig.get_layout_engine(), ConstrainedLayoutEngine):
            # constrained layout already fits every label inside the figure; a tight box
            # would draw the whole figure a second time to measure it (a third of a fit
            # report's time went to such draws)
            kwargs.pop("bbox_inches", None)
        fig.savefig(out / name, format="png", **kwargs)
        plt.close(fig)
        written.append(out / name)
    return written


def _log_scale(dt: xr.DataTree, name: str) -> bool:
    """Whether the fit's prior on ``name`` is log-scale (log-uniform or log-normal)."""
    prior = json.loads(dt.attrs["priors"]).get(name)
    return prior is not None and prior["dist"] in ("loguniform", "lognormal")


def _prior_posterior_labels(dt: xr.DataTree, names: list[str]) -> dict[str, str]:
    """Panel labels with units; log-scale parameters as ``log₁₀ k (k in N/m)``."""
    out = {}
    for n in names:
        symbol = figures.param_label(n).split(" [")[0]
        unit = figures.param_unit(n) or "-"
        out[n] = (
            f"log₁₀ {symbol} ({symbol} in {unit})" if _log_scale(dt, n) else figures.param_label(n)
        )
    return out


def _truth_of(truth: Mapping[float, Mapping[str, float]], label: str) -> float:
    name, _, rest = label.partition("[")
    try:
        phi = float(rest.rstrip("]"))
    except ValueError:
        return float("nan")
    return float(truth.get(phi, {}).get(name, np.nan))


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
    label = figures.data_label(selected)
    written = [out / "diagnosis.json"]
    (out / "diagnosis.json").write_text(json.dumps(rec, indent=2, default=float) + "\n")
    cells = pd.DataFrame(rec["misfit"])
    kind = cells["kind"].fillna("heights") if "kind" in cells else pd.Series("heights", cells.index)
    before = cells[kind == "heights"].dropna(axis=1, how="all")
    if (kind != "heights").any():  # the kinds beyond heights: their cells in one table
        cells[kind != "heights"].dropna(axis=1, how="all").to_csv(
            out / "residuals_baseline_kinds.csv", index=False
        )
        written.append(out / "residuals_baseline_kinds.csv")
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
        "residuals_baseline.png": figures.plot_residual_heatmap(
            before, f"{prefix}baseline {base_terms}", z
        ),
        "residuals_selected.png": figures.plot_residual_heatmap(
            after, f"{prefix}selected {sel_terms}", z
        ),
    }
    for k in KINDS.values():
        if k.unit_dim in selected["log_likelihood"].dims:
            for stem, draw in k.figures.items():
                figs[f"{stem}_selected.png"] = draw(selected)
    written += _save_figures(figs, out)
    gdt.write_datatree(selected, out / "posterior_selected.nc")
    written.append(out / "posterior_selected.nc")
    lines = [f"# What the simulation gets wrong: {Path(rec.get('data_source', '')).name}", ""]
    if label:
        lines += [f"**{label}**", ""]
    lines += _verdict_lines(rec, base_terms)
    worst = [m for m in rec["misfit"] if m["significant"]][:5]
    lines += ["", f"Baseline misfit ({rec['n_misfit_cells']} cells with |z| > {z:.2f}):", ""]
    lines += [f"- {m['description']}" for m in worst] or ["- none"]
    lines += _lack_of_fit_lines(rec)
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
    where = [f"- {m['description']}" for m in rec["residual_misfit"][:8]] or [
        "- in no cell alone: in the cells together (the omnibus lack-of-fit test, below)"
    ]
    return [
        "**Verdict: misfit remains.** The data show physics that the library does not hold. "
        + helped
        + "No term is named as the cause. Where the law still fails:",
        "",
        *where,
        *ties,
    ]


def _lack_of_fit_lines(rec: Mapping) -> list[str]:
    """The omnibus lack-of-fit test of the baseline and the selected law, in words."""
    tests = rec.get("lack_of_fit") or {}
    if not tests:
        return []

    def text(test: Mapping) -> str:
        if test.get("p_value") is None:
            return "not available (no repeated jumps)"
        return (
            f"T = {test['statistic']:.1f} on {test['dof_lack']:g} and {test['dof_pure']:g} "
            f"degrees of freedom, p = {test['p_value']:.3g}"
        )

    alpha = rec["rule"].get("lack_of_fit_alpha")
    lines = [
        "",
        "Omnibus lack of fit (every height cell together, against the pure error of the "
        f"repeated jumps): baseline {text(tests['baseline'])}; selected law "
        f"{text(tests['selected'])}"
        + (f" (used by the rule at {alpha:g})." if alpha is not None else " (reported only)."),
    ]
    p_sel = tests["selected"].get("p_value")
    if alpha is None and rec["verdict"] == "extended" and p_sel is not None and p_sel < 0.05:
        lines += [
            "",
            f"**Caution:** the selected law's cells are off together (p = {p_sel:.3g}), "
            "though none is off alone: the added term may stand in for physics the library "
            "does not hold (in `benchmarks/results/lack_of_fit`, a drag whose coefficient "
            "changes with depth, or a strength that changes with the intrusion rate, named "
            "as drag or viscous damping). Test the claim on new jumps (`granbayes design`, "
            "a fresh replicate).",
        ]
    return lines


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
        )
        + " `granbayes design DIR --diagnosis OUT --out NEXT` proposes the jumps expected to "
        "separate them, and how many (the fits of both laws are in `laws/`).",
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
