"""Is the added-mass coefficient kappa identified by jump heights, tracked jumps, intrusions?

Jump heights alone confound the added-mass cone with drag: both resist the foot's advance
in proportion to its speed squared (the cone's momentum flux kappa rho phi V'(d) z'^2
against c_d z'^2), so a fit can trade one for the other along a valley. Tracked jumps show
the motion the heights only summarise, and intrusion curves at several speeds separate the
two by depth: the flux falls to zero once the cone is full (about 30 mm for the default
foot, physics-model.md section 5b), drag does not.

The law ``depth + drag + added_mass`` (the true terms of the SYNTHETIC data set
``granbayes/data/added_mass``, made by ``data/generate_lab_reference.py``) is fitted per
volume fraction four times with the same seed and the converged default chain settings
of ``granbayes fit``: (i) jump heights only, (ii) heights + tracked jumps, (iii) heights +
intrusion curves, (iv) heights + tracked jumps + intrusion curves. Per case and volume
fraction it reports the posterior median and 90% equal-tailed interval of kappa and c_d
against the truth (``truth.toml`` of the folder, when there is one), the width of kappa's
interval relative to its prior range, the posterior contraction
(``granbayes.stats.identifiability_table``), the joint posterior correlation of kappa and
c_d, each run's convergence and each fit's wall time.

Default DIR: ``granbayes/data/added_mass``. Results: ``docs/analyses/kappa_identification/``
(``make``-style: ``python analyses/kappa_identification.py --out
docs/analyses/kappa_identification``).
"""

from __future__ import annotations

import hashlib
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from scipy.stats import binom

import _common as common
from granbayes import FitSettings, default_priors, fit
from granbayes.kinds import load_measurements
from granbayes.report import load_truth
from granbayes.stats import CI_PROB, IDENTIFIABILITY_LEVELS, identifiability_table, interval

NAME = "kappa_identification"

#: The SYNTHETIC data set with added mass (data/generate_lab_reference.py).
ADDED_MASS_DATA = Path(common.REFERENCE_DATA).parent / "added_mass"

#: The force law fitted: the true terms of the added-mass data set.
TERMS = ("depth", "drag", "added_mass")

#: The four cases: label -> kinds of measurement.
CASES: dict[str, tuple[str, ...]] = {
    "heights": ("heights",),
    "heights + trajectories": ("heights", "trajectories"),
    "heights + intrusions": ("heights", "intrusions"),
    "heights + trajectories + intrusions": ("heights", "trajectories", "intrusions"),
}

_KAPPA_PRIOR = default_priors()["kappa"]
#: Range of kappa's (uniform) prior: the yardstick of how well kappa is known.
KAPPA_PRIOR_RANGE = _KAPPA_PRIOR.upper - _KAPPA_PRIOR.lower
#: Width of the prior's own 90% equal-tailed interval, relative to its range.
PRIOR_RELATIVE_WIDTH = CI_PROB


def _add_arguments(p) -> None:
    """DIR defaults to the added-mass data set."""
    p.set_defaults(data=ADDED_MASS_DATA)
    for action in p._actions:
        if action.dest == "data":
            action.help = "experiment folder (default: the SYNTHETIC added-mass data set)"


def _draws(dt, name: str, phi: float) -> np.ndarray:
    post = dt["posterior"].to_dataset()
    return post[name].sel(phi=phi).values.ravel()


def run_case(ctx: common.Context, label: str, kinds: tuple[str, ...], truth: dict) -> dict:
    """One fit and its per-phi rows."""
    data = load_measurements(ctx.data, ctx.experiment, use=list(kinds))
    config = FitSettings(terms=TERMS, sampler=common.sampler_settings(ctx.fast))
    print(f"[{NAME}] fitting {label} ...", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    result = fit(ctx.experiment, data, config, seed=ctx.seed, data_source=str(ctx.data))
    seconds = time.perf_counter() - t0
    print(f"[{NAME}] {label}: {seconds:.0f} s", file=sys.stderr, flush=True)
    dt = result.datatree
    diag = result.diagnostics().set_index("run")
    ident = identifiability_table(dt, ["k", "c_d", "kappa"])
    rows, joint = [], {}
    for part in result.parts:
        phi = float(np.unique(np.asarray(part.model.phis, float))[0])
        kappa, c_d = _draws(dt, "kappa", phi), _draws(dt, "c_d", phi)
        k_med, k_lo, k_hi = interval(kappa)
        c_med, c_lo, c_hi = interval(c_d)
        true = truth.get(round(phi, 6), {})
        contraction = {
            r.parameter: r.contraction
            for r in ident[np.isclose(ident["phi"].astype(float), phi)].itertuples()
        }
        d = diag.loc[part.label]
        rows.append(
            {
                "case": label,
                "phi": phi,
                "kappa_true": true.get("kappa", np.nan),
                "kappa_median": k_med,
                "kappa_lo": k_lo,
                "kappa_hi": k_hi,
                "kappa_sd": float(np.std(kappa)),
                "kappa_width_over_prior_range": (k_hi - k_lo) / KAPPA_PRIOR_RANGE,
                "kappa_contraction": contraction.get("kappa", np.nan),
                "c_d_true": true.get("c_d", np.nan),
                "c_d_median": c_med,
                "c_d_lo": c_lo,
                "c_d_hi": c_hi,
                "c_d_sd": float(np.std(c_d)),
                "c_d_contraction": contraction.get("c_d", np.nan),
                "k_true": true.get("k", np.nan),
                "k_median": float(np.median(_draws(dt, "k", phi))),
                "k_contraction": contraction.get("k", np.nan),
                "corr_kappa_c_d": float(np.corrcoef(kappa, c_d)[0, 1]),
                "spearman_kappa_c_d": float(
                    pd.Series(kappa).corr(pd.Series(c_d), method="spearman")
                ),
                "kappa_in_interval": bool(k_lo <= true.get("kappa", np.nan) <= k_hi),
                "c_d_in_interval": bool(c_lo <= true.get("c_d", np.nan) <= c_hi),
                "converged": bool(part.run.converged),
                "n_steps": int(d["n_steps"]),
                "tau_max": float(d["tau_max"]),
                "rhat_max": float(d["rhat_max"]),
                "ess_min": float(d["ess_min"]),
            }
        )
        joint[phi] = (kappa, c_d)
    return {
        "label": label,
        "kinds": kinds,
        "rows": rows,
        "joint": joint,
        "seconds": seconds,
        "converged": bool(result.converged),
        "warnings": list(result.warnings),
    }


def _figure(ctx: common.Context, cases: list[dict], truth: dict) -> Figure:
    """Joint posterior of (c_d, kappa): a column per volume fraction, a colour per case;
    the top row over kappa's prior range, the bottom row zoomed on the truth."""
    phis = sorted(cases[0]["joint"])
    fig = Figure(figsize=(4.0 * len(phis), 7.0), layout="constrained")
    axes = fig.subplots(2, len(phis), squeeze=False)
    colours = ("tab:grey", "tab:blue", "tab:green", "tab:red")
    rng = ctx.rng(1)
    for j, phi in enumerate(phis):
        true = truth.get(round(phi, 6), {})
        for case, colour in zip(cases, colours, strict=False):
            kappa, c_d = case["joint"][phi]
            pick = rng.choice(kappa.size, size=min(kappa.size, 1500), replace=False)
            for ax in axes[:, j]:
                ax.scatter(c_d[pick], kappa[pick], s=3, alpha=0.3, color=colour, lw=0)
        for row, ax in enumerate(axes[:, j]):
            if "kappa" in true and "c_d" in true:
                ax.plot(true["c_d"], true["kappa"], ls="", marker="*", ms=12, mfc="none", mec="k")
            ax.set_xlabel("c_d [kg/m]")
            ax.set_ylabel("kappa [-]")
            if row == 0:
                ax.set_ylim(_KAPPA_PRIOR.lower, _KAPPA_PRIOR.upper)
                ax.set_title(f"phi = {phi:g}")
            elif "kappa" in true and "c_d" in true:
                ax.set_xlim(true["c_d"] - 1.5, true["c_d"] + 1.5)
                ax.set_ylim(true["kappa"] - 0.3, true["kappa"] + 0.3)
                ax.set_title(f"phi = {phi:g}, near the truth")
    handles = [
        Line2D([], [], ls="", marker="o", color=colour, label=case["label"])
        for case, colour in zip(cases, colours, strict=False)
    ]
    handles.append(Line2D([], [], ls="", marker="*", mfc="none", mec="k", ms=12, label="truth"))
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles))
    fig.suptitle(ctx.title("Joint posterior of kappa and c_d, per kind of data"))
    return fig


def _fmt(med: float, lo: float, hi: float, digits: str = ".3g") -> str:
    return f"{med:{digits}} [{lo:{digits}}, {hi:{digits}}]"


def _summary_table(table: pd.DataFrame) -> pd.DataFrame:
    out = pd.DataFrame(
        {
            "data": table["case"],
            "φ": table["phi"].map(lambda p: f"{p:g}"),
            "κ (true)": [
                f"{_fmt(r.kappa_median, r.kappa_lo, r.kappa_hi, '.3f')} ({r.kappa_true:g})"
                for r in table.itertuples()
            ],
            "κ width / prior range": table["kappa_width_over_prior_range"].map(
                lambda v: f"{v:.2f}"
            ),
            "κ contraction": table["kappa_contraction"].map(lambda v: f"{v:.2f}"),
            "c_d [kg/m] (true)": [
                f"{_fmt(r.c_d_median, r.c_d_lo, r.c_d_hi)} ({r.c_d_true:g})"
                for r in table.itertuples()
            ],
            "c_d contraction": table["c_d_contraction"].map(lambda v: f"{v:.2f}"),
            "corr(κ, c_d)": table["corr_kappa_c_d"].map(lambda v: f"{v:+.2f}"),
            "converged": table["converged"].map(lambda v: "yes" if v else "**no**"),
            "steps": table["n_steps"],
        }
    )
    return out


def _level(contraction: float) -> str:
    """The identifiability verdict of a contraction (granbayes.stats levels), in short."""
    return next(t for bound, t in IDENTIFIABILITY_LEVELS if contraction < bound).split(":")[0]


def _range(values: np.ndarray, fmt: str) -> str:
    lo, hi = float(np.nanmin(values)), float(np.nanmax(values))
    return f"{lo:{fmt}}" if f"{lo:{fmt}}" == f"{hi:{fmt}}" else f"{lo:{fmt}} to {hi:{fmt}}"


def _verdict(table: pd.DataFrame, cases: list[dict]) -> str:
    """The conclusion: is kappa identified by each kind of data? (worst volume fraction)."""
    sentences = []
    for case in cases:
        sub = table[table["case"] == case["label"]]
        width = sub["kappa_width_over_prior_range"].to_numpy(float)
        contr = sub["kappa_contraction"].to_numpy(float)
        corr = sub["corr_kappa_c_d"].to_numpy(float)
        c_width = (sub["c_d_hi"] - sub["c_d_lo"]).to_numpy(float)
        worst = int(np.nanargmax(width))
        text = (
            f"With **{case['label']}** kappa is **{_level(contr[worst])}** at the worst "
            f"volume fraction (phi = {sub['phi'].iloc[worst]:g}): its 90% interval spans "
            f"{_range(width, '.0%')} of the prior range"
            + (f" (the prior's own: {PRIOR_RELATIVE_WIDTH:.0%})" if not sentences else "")
            + f", contraction {_range(contr, '.2f')}; c_d's interval "
            f"is {_range(c_width, '.2g')} kg/m wide; corr(kappa, c_d) {_range(corr, '+.2f')}"
        )
        if np.nanmin(contr) < 0.9 and np.nanmax(np.abs(corr)) >= 0.5:
            text += " (the two rate terms trade off along a valley of the posterior)"
        text += f"; {case['seconds'] / 60:.1f} min"
        text += "" if case["converged"] else ", **not every run converged: provisional**"
        sentences.append(text + ".")
    known = table[table["kappa_true"].notna()]
    missed = known[~known["kappa_in_interval"]]
    if len(known):
        n, m = len(known), len(missed)
        p_tail = float(binom.sf(m - 1, n, 1.0 - CI_PROB)) if m else 1.0
        sentences.append(
            f"The truth lies in {n - m} of the {n} 90% intervals of kappa"
            + (
                ""
                if not m
                else f" (about {n * (1 - CI_PROB):.1f} misses expected; {m} or more has "
                f"probability {p_tail:.2f} if every interval had its nominal coverage). "
                "Outside: "
                + "; ".join(
                    f"{r.case} at phi = {r.phi:g}, {r.kappa_median:.3f} [{r.kappa_lo:.3f}, "
                    f"{r.kappa_hi:.3f}]"
                    for r in missed.itertuples()
                )
            )
            + "."
        )
    return " ".join(sentences)


def analysis(ctx: common.Context) -> tuple[str, dict]:
    """Fit the four cases, tabulate, plot, and write the answer."""
    truth_path = ctx.data / "truth.toml"
    truth = (
        {round(p, 6): v for p, v in load_truth(truth_path).items()} if truth_path.is_file() else {}
    )
    every = load_measurements(
        ctx.data, ctx.experiment, use=list(CASES["heights + trajectories + intrusions"])
    )
    sizes = {
        "jumps": len(every.tables["heights"]),
        "tracked jumps": int(every.tables["trajectories"]["jump"].nunique()),
        "frames": len(every.tables["trajectories"]),
        "tracked commands": sorted(set(every.tables["trajectories"]["command"])),
        "intrusion tests": int(every.tables["intrusions"]["test"].nunique()),
        "intrusion speeds [mm/s]": sorted(set(every.tables["intrusions"]["speed_mm_s"])),
        "intrusion samples": len(every.tables["intrusions"]),
    }
    cases = [run_case(ctx, label, kinds, truth) for label, kinds in CASES.items()]
    table = pd.DataFrame([row for case in cases for row in case["rows"]])
    ctx.save_table(table, "intervals")
    timings = pd.DataFrame(
        [
            {
                "case": c["label"],
                "kinds": ",".join(c["kinds"]),
                "wall_time_s": round(c["seconds"], 1),
                "converged": c["converged"],
                "n_warnings": len(c["warnings"]),
            }
            for c in cases
        ]
    )
    ctx.save_table(timings, "timings")
    ctx.save_figure(_figure(ctx, cases, truth), "joint_kappa_c_d")

    threads = getattr(ctx.args, "threads", None)
    body = [
        f"The law `{' + '.join(TERMS)}` fitted per volume fraction to the same data four "
        f"times (seed {ctx.seed}, the converged default chain settings of `granbayes fit`"
        + (", **fast mode: short capped chains, rough numbers**" if ctx.fast else "")
        + f"; numba threads: {threads if threads else 'all cores'}). "
        f"κ's prior is uniform on [{_KAPPA_PRIOR.lower:g}, {_KAPPA_PRIOR.upper:g}] "
        f"(its own 90% interval spans {PRIOR_RELATIVE_WIDTH:.2f} of the range); c_d's is "
        f"{default_priors()['c_d'].describe()}. Contraction is 1 − var(posterior)/var(prior) "
        "(0: the data say nothing; 1: they pin it down); c_d's is measured against its wide "
        "prior, so even an interval several kg/m wide contracts it by about 1.",
        "",
        "Data: "
        + ", ".join(
            f"{v} {k}"
            if not isinstance(v, list)
            else f"{k} {', '.join(f'{x:g}' if isinstance(x, float) else x for x in v)}"
            for k, v in sizes.items()
        )
        + ".",
        "",
        "## Per case and volume fraction",
        "",
        common.markdown_table(_summary_table(table)),
        "",
        "## Wall time of each fit",
        "",
        common.markdown_table(
            timings.rename(columns={"wall_time_s": "wall time [s]", "n_warnings": "warnings"})
        ),
        "",
        "![joint posterior](joint_kappa_c_d.png)",
        "",
        "## Conclusion",
        "",
        _verdict(table, cases),
    ]
    warnings = [f"{c['label']}: {w}" for c in cases for w in c["warnings"]]
    if warnings:
        body += ["", "## Fit warnings", "", *(f"- {w}" for w in warnings)]
    numbers = {
        "terms": list(TERMS),
        "data_sizes": sizes,
        "data_files_sha256": {
            f.name: hashlib.sha256(f.read_bytes()).hexdigest()
            for f in sorted(ctx.data.iterdir())
            if f.suffix in (".csv", ".toml")
        },
        "cases": [
            {
                "case": c["label"],
                "kinds": list(c["kinds"]),
                "wall_time_s": c["seconds"],
                "converged": c["converged"],
                "warnings": c["warnings"],
                "per_phi": c["rows"],
            }
            for c in cases
        ],
    }
    return "\n".join(body), numbers


def main(argv: list[str] | None = None) -> int:
    return common.main(NAME, __doc__, analysis, argv, _add_arguments)


if __name__ == "__main__":
    sys.exit(main())
