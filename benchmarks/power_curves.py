"""Study: where ``diagnose`` stops seeing. Detection probability against effect size.

For each kind (a library term or an effect outside the library) and each effect size of
its ladder (``granbayes.calibration.POWER_SIZES``, weakest first), ``--per-size`` SYNTHETIC
cases (the oracle of ``granbayes.testing``; robot, noise and design drawn per case from
lab-like ranges, ``granbayes.calibration.POWER_DESIGN``: 2-5 volume fractions, 1-2
frequencies, 2-5 trials, scatter 1.5-5 mm) are diagnosed as a Dask campaign
(``granbayes.calibration.power_case``; resumable, each finished case written at once).

Writes into OUT (default ``benchmarks/results/power``): ``results.csv`` (one row per case:
its design, the effect's size in its own unit and in the heights, the verdict),
``summary.md`` / ``summary.json`` (detection probability per kind and size with exact 95%
intervals; the sizes at 50% and 90% detection from a logistic fit on the effect's
signal-to-noise ratio and on its own parameter) and ``power.png`` (the curves).

With ``--tracked`` every case also films some of its jumps (``POWER_TRACKING``: the single
jump and the stutter at each volume fraction, 1000 frames/s, the reference lab's frame
noise) and ``diagnose`` fits the heights and tracked jumps jointly: the same cases, the
same heights (paired with the heights-only study case by case); default OUT
``benchmarks/results/power_tracked``.

Detected means the study's "right" (``granbayes.calibration.outcome``): for a library term
``extended`` with exactly that term; for an effect outside the library ``misfit_remains``
or a law as good as the truth on a fresh replicate (there, "detected" is "not misled").

Usage::

    python benchmarks/power_curves.py [--kinds drag,viscous,...] [--per-size 10]
        [--tracked] [--nulls N] [--out DIR] [--seed S] [--workers N | --scheduler ADDRESS]
        [--resume] [--summarize-only] [--against EARLIER/results.csv]

With ``--nulls N`` the study is instead N cases without any effect on the same designs
(``power_case('null', 0.0, ...)``; with ``--tracked`` filmed as above): the false-alarm
arm, whose right verdict is ``baseline_adequate``; default OUT
``benchmarks/results/power_null`` (``power_tracked_null``). With ``--against`` the summary
compares the run case by case with an earlier one on the same seed (a rerun on other code).
"""

from __future__ import annotations

import argparse
import json
import math
from functools import partial
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import numpy as np
import pandas as pd
from _studies import (  # this folder
    add_campaign_options,
    chosen_kinds,
    run_study,
    summarize_finished,
)
from matplotlib.figure import Figure
from matplotlib.ticker import FixedFormatter, FixedLocator, NullLocator

from granbayes import __version__
from granbayes.calibration import (
    POWER_DESIGN,
    POWER_SIZES,
    POWER_TRACKING,
    STEP_BUDGET,
    clopper_pearson,
    detected,
    detection_sizes,
    power_case,
    power_table,
)
from granbayes.campaign import Task, spawn_seeds
from granbayes.report import markdown_table

HERE = Path(__file__).resolve().parent
SEED = 20261128


def tasks(kinds: list[str], per_size: int, seed: int, tracked: bool = False) -> list[Task]:
    """One task per kind, size and replicate; seeds spawned per (kind, size).

    Interleaved replicate by replicate (replicate 0 of every kind and size first), so a
    study stopped part-way has every point of every curve covered about equally.
    ``tracked``: the same cases with filmed jumps (``POWER_TRACKING``).
    """
    kwargs = {"tracking": POWER_TRACKING} if tracked else {}
    cells = []
    for kind in kinds:
        for j, size in enumerate(POWER_SIZES[kind]):
            seeds = spawn_seeds(seed + 1000 * list(POWER_SIZES).index(kind) + j, per_size)
            cells.append(
                [
                    Task(f"{kind}-size{j}-{i:03d}", power_case, (kind, size, i), kwargs, seed=s)
                    for i, s in enumerate(seeds)
                ]
            )
    return [cell[i] for i in range(per_size) for cell in cells]


def null_tasks(n: int, seed: int, tracked: bool = False) -> list[Task]:
    """``n`` cases without an effect on the same designs: the false-alarm arm.

    Their seeds are spawned apart from every kind's (``seed + 1000 x len(POWER_SIZES)``).
    """
    kwargs = {"tracking": POWER_TRACKING} if tracked else {}
    seeds = spawn_seeds(seed + 1000 * len(POWER_SIZES), n)
    return [
        Task(f"null-{i:03d}", power_case, ("null", 0.0, i), kwargs, seed=s)
        for i, s in enumerate(seeds)
    ]


def write_null_summary(
    out: Path, results: pd.DataFrame, seed: int, n_planned: int, tracked: bool = False
) -> None:
    """summary.md and summary.json of the null arm: every verdict, with exact intervals."""
    n = len(results)

    def rate(count: int) -> dict[str, float]:
        lo, hi = clopper_pearson(count, n)
        return {"count": count, "n": n, "rate": count / n, "lo": lo, "hi": hi}

    named = results["added"].fillna("").astype(str) != ""
    alarms = results["verdict"] == "misfit_remains"
    doc = {
        "seed": seed,
        "granbayes": __version__,
        "n_cases": n,
        "n_planned": n_planned,
        "design": POWER_DESIGN,
        "tracking": POWER_TRACKING if tracked else None,
        "verdicts": results["verdict"].value_counts().to_dict(),
        "false_discovery": rate(int(named.sum())),
        "false_alarm": rate(int((alarms & ~named).sum())),
        "median_time_per_case_s": float(results["wall_time_s"].median()),
    }
    (out / "summary.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    cols = [
        "task_id",
        "sigma_mm",
        "phis",
        "freqs_hz",
        "trials",
        *(["n_tracked", "n_frames"] if "n_tracked" in results else []),
        "verdict",
        "added",
        "elpd_gain",
        "elpd_gain_se",
        "n_residual_misfit",
        "lof_p_selected",
        "all_converged",
        "wall_time_s",
    ]
    fd, fa = doc["false_discovery"], doc["false_alarm"]
    lines = [
        "# No effect at all: the false-alarm arm of the power curves (SYNTHETIC data)",
        "",
        f"Generated by `benchmarks/power_curves.py --nulls` (seed {seed}) with "
        f"`granbayes.calibration.power_case('null', ...)`; {n} cases"
        + (f" (**a stopped study: {n} of {n_planned}**)" if n_planned > n else "")
        + ", the designs of the power curves (2-5 volume fractions, 1-2 frequencies, 2-5 "
        "trials, scatter 1.5-5 mm), the truth the depth law alone"
        + ("; **with tracked jumps** (`POWER_TRACKING`), fitted jointly" if tracked else "")
        + ". Right is `baseline_adequate`.",
        "",
        f"- a term named (false discovery): {fd['count']} of {n}, exact 95% interval "
        f"[{fd['lo']:.3f}, {fd['hi']:.3f}]",
        f"- `misfit_remains` with no term (false alarm): {fa['count']} of {n}, "
        f"[{fa['lo']:.3f}, {fa['hi']:.3f}]",
        "",
        markdown_table(results[[c for c in cols if c in results]], ".3g", missing=""),
    ]
    (out / "summary.md").write_text("\n".join(lines) + "\n")


def figure(
    table: pd.DataFrame, results: pd.DataFrame, curves: pd.DataFrame, stopped: str = ""
) -> Figure:
    """Detection probability against the effect's signal-to-noise ratio, one panel per kind.

    Each panel: every case at its own size (a tick at 1 if detected, 0 if not), the rate
    per size of the ladder at the median size of its cases with its exact 95% interval,
    and the logistic fit of ``curves`` (:func:`granbayes.calibration.detection_sizes` on
    ``effect_snr``) over the measured range, with its 50% and 90% sizes where detection grew
    with the size. ``stopped``: a line for the title of a study stopped part-way.
    """
    kinds = list(dict.fromkeys(table["kind"]))
    ncols = 5
    nrows = -(-len(kinds) // ncols)
    fig = Figure(figsize=(11.0, 2.3 * nrows + 0.9), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrows, ncols, sharex=True, sharey=True)).ravel()
    snr = results["effect_snr"].to_numpy(dtype=float)
    lo, hi = np.nanmin(snr) / 1.3, np.nanmax(snr) * 1.3
    ticks = [t for t in (1, 2, 5, 10, 20, 50, 100, 200) if lo <= t <= hi]
    hit = detected(results)
    for ax, kind in zip(axes, kinds, strict=False):
        g = table[table["kind"] == kind]
        cases = results["kind"] == kind
        y = hit[cases].to_numpy(dtype=float)
        ax.plot(
            results.loc[cases, "effect_snr"],
            np.where(y == 1, 1.04, -0.04),
            "|",
            color="0.45",
            ms=6,
            label="a case (1 detected, 0 not)",
        )
        err = np.vstack([g["p"] - g["p_lo"], g["p_hi"] - g["p"]])
        ax.errorbar(
            g["effect_snr"],
            g["p"],
            yerr=err,
            fmt="o",
            color="C0",
            capsize=2,
            ms=4,
            label="rate per size (exact 95%)",
        )
        row = curves[curves["kind"] == kind]
        if len(row) and np.isfinite(row["size_50"].iloc[0]):
            r = row.iloc[0]
            x = np.geomspace(r["range_lo"], r["range_hi"], 100)
            p = 1.0 / (1.0 + np.exp(-r["slope"] * (np.log(x) - np.log(r["size_50"]))))
            ax.plot(x, p, color="C3", lw=1.2, label="logistic fit")
            for level, size in ((0.5, r["size_50"]), (0.9, r["size_90"])):
                if r["range_lo"] <= size <= r["range_hi"]:
                    ax.plot([size], [level], "v", color="C3", ms=5)
        ax.set_title(f"{kind.replace('_', ' ')} (n={int(g['n'].sum())})", fontsize=8)
        ax.axhline(0.5, color="0.75", lw=0.6, ls=":")
        ax.axhline(0.9, color="0.75", lw=0.6, ls=":")
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(FixedLocator(ticks))
        ax.xaxis.set_major_formatter(FixedFormatter([str(t) for t in ticks]))
        ax.xaxis.set_minor_locator(NullLocator())
        ax.tick_params(labelsize=7)
    for ax in axes[len(kinds) :]:
        ax.set_visible(False)
    axes[0].set_xlim(lo, hi)
    axes[0].set_ylim(-0.08, 1.08)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="outside lower center", ncols=3)
    fig.suptitle(
        "SYNTHETIC data (granbayes.calibration.power_case, benchmarks/power_curves.py): "
        "where diagnose stops seeing"
        + (f"\n{stopped}" if stopped else "")
        + "\nx: effect size before refit, sqrt(sum over jumps of (height change / scatter)^2)"
        " [-]; y: detected",
        fontsize=9,
    )
    return fig


def _within_range(sizes: pd.DataFrame) -> pd.DataFrame:
    """The detection sizes as text, those beyond the sizes tried as "> hi" or "< lo".

    A logistic curve read outside the measured range is an extrapolation of a few cases
    (``summary.json`` keeps the fitted values).
    """
    out = sizes.copy()
    for col in [c for c in sizes.columns if c.startswith("size_")]:
        text = []
        for value, lo, hi in zip(sizes[col], sizes["range_lo"], sizes["range_hi"], strict=True):
            if not np.isfinite(value):
                text.append("-")
            elif value > hi:
                text.append(f"> {hi:.3g}")
            elif value < lo:
                text.append(f"< {lo:.3g}")
            else:
                text.append(f"{value:.3g}")
        out[col] = text
    return out


def paired_runs(
    results: pd.DataFrame, other: pd.DataFrame, names: tuple[str, str] = ("tracked", "heights")
) -> pd.DataFrame:
    """Each case of one run of the study beside the same case in another.

    Two runs with the same seed draw each case alike (the seed is spawned per task id):
    the tracked study against the heights-only one (the tracked one adds frames from a
    stream of their own, so the heights are the same), or a rerun on other code against
    an earlier run. Per kind and size: the pairs both runs finished, how many each
    detected, and the discordant pairs (detected in one run only); per kind over its
    sizes, the exact two-sided McNemar test (binomial on the discordant pairs).

    Parameters
    ----------
    results, other : pandas.DataFrame
        ``results.csv`` of the two runs.
    names : tuple of str
        What to call them in the columns (``detected_<name>``, ``only_<name>``).

    Returns
    -------
    pandas.DataFrame
        One row per kind and size (``size`` NaN: the kind's total, with ``mcnemar_p``).

    Raises
    ------
    ValueError
        If a pair's scatter differs (not the same case).
    """
    from scipy.stats import binomtest

    a, b = names
    both = results.assign(hit=detected(results)).merge(
        other.assign(hit=detected(other)), on="task_id", suffixes=(f"_{a}", f"_{b}")
    )
    if not np.array_equal(both[f"sigma_mm_{a}"], both[f"sigma_mm_{b}"]):
        raise ValueError("a case and its twin in the other run differ: not the same draw")
    both[f"only_{a}"] = both[f"hit_{a}"] & ~both[f"hit_{b}"]
    both[f"only_{b}"] = both[f"hit_{b}"] & ~both[f"hit_{a}"]
    rows = []
    for kind, g in both.groupby(f"kind_{a}", sort=False):
        for size, c in [*g.groupby(f"size_{a}", sort=True), (math.nan, g)]:
            row = {
                "kind": kind,
                "size": size,
                "pairs": len(c),
                f"detected_{b}": int(c[f"hit_{b}"].sum()),
                f"detected_{a}": int(c[f"hit_{a}"].sum()),
                f"only_{a}": int(c[f"only_{a}"].sum()),
                f"only_{b}": int(c[f"only_{b}"].sum()),
                "mcnemar_p": math.nan,
            }
            discordant = row[f"only_{a}"] + row[f"only_{b}"]
            if math.isnan(size) and discordant:
                row["mcnemar_p"] = binomtest(row[f"only_{a}"], discordant).pvalue
            rows.append(row)
    return pd.DataFrame(rows)


def write_summary(
    out: Path,
    results: pd.DataFrame,
    seed: int,
    n_planned: int,
    tracked: bool = False,
    against: Path | None = None,
) -> None:
    """summary.md, summary.json and power.png from the tidy results.

    ``against``: the ``results.csv`` of an earlier run with the same seed, compared case
    by case (:func:`paired_runs`).
    """
    table = power_table(results)
    by_snr = detection_sizes(results, "effect_snr")
    by_size = detection_sizes(results, "size")
    stopped = n_planned > len(results)
    doc = {
        "seed": seed,
        "granbayes": __version__,
        "n_cases": len(results),
        "n_planned": n_planned,
        "design": POWER_DESIGN,
        "tracking": POWER_TRACKING if tracked else None,
        "sizes": POWER_SIZES,
        "step_budget": STEP_BUDGET,
        "per_size": table.to_dict("records"),
        "detection_by_snr": by_snr.to_dict("records"),
        "detection_by_size": by_size.to_dict("records"),
        "median_time_per_case_s": float(results["wall_time_s"].median()),
    }
    lines = [
        "# Where diagnose stops seeing: detection against effect size (SYNTHETIC data)",
        "",
        f"Generated by `benchmarks/power_curves.py` (seed {seed}) with "
        f"`granbayes.calibration.power_case`; {len(results)} cases"
        + (
            f" (**a stopped study: {len(results)} of the {n_planned} planned cases; read "
            "the rates as a pilot, with their intervals**)"
            if stopped
            else ""
        )
        + ". Designs like a lab's: 2-5 volume fractions, 1-2 frequencies, 2-5 trials, "
        "scatter 1.5-5 mm, drawn per case"
        + (
            "; **with tracked jumps** (`POWER_TRACKING`: the single jump and the stutter "
            "filmed at every volume fraction, 1000 frames/s, 0.25 mm frame noise), fitted "
            "jointly with the heights"
            if tracked
            else ""
        )
        + ". Detected: a library term named alone or with a "
        "tie (`extended` with exactly it); an effect outside the library not blamed on a "
        "term (`misfit_remains`, or a law as good as the truth on a fresh replicate). "
        "`effect_rms_mm`: the RMS height change of the effect over cells; `effect_snr`: "
        "sqrt(sum over jumps (change / scatter)^2), before any refit (the baseline refits "
        "k and absorbs part of it). `p_lo`, `p_hi`: exact (Clopper-Pearson) 95% interval.",
        "",
        markdown_table(table, ".3g"),
        "",
        "## Sizes at 50% and 90% detection (logistic fit on log size)",
        "",
        "On the effect's signal-to-noise ratio (comparable across kinds):",
        "",
        markdown_table(_within_range(by_snr), ".3g", missing="-"),
        "",
        "On the effect's own parameter (`POWER_SIZES`; for unloading and Janssen "
        "saturation smaller is stronger):",
        "",
        markdown_table(_within_range(by_size), ".3g", missing="-"),
        "",
        "`> range_hi`, `< range_lo`: the curve reaches the level only beyond the sizes tried "
        "(its extrapolation is in `summary.json`); `-`: detection did not grow with the size, "
        "or never varied.",
        "",
        "![power](power.png)",
    ]
    heights_csv = HERE / "results" / "power" / "results.csv"
    if tracked and heights_csv.exists():
        paired = paired_runs(results, pd.read_csv(heights_csv))
        doc["paired_with_heights"] = paired.to_dict("records")
        lines += [
            "",
            "## The same cases fitted to their heights alone",
            "",
            "Each case beside itself in `benchmarks/results/power/` (the heights-only study: "
            "the same seed, the same heights): detected with and without the frames, the "
            "discordant pairs, and per kind (`size` empty) the exact two-sided McNemar test "
            "on them.",
            "",
            markdown_table(paired, ".3g", missing=""),
        ]
    if against is not None:
        changes = paired_runs(results, pd.read_csv(against), ("after", "before"))
        doc["against"] = str(against)
        doc["paired_with_earlier"] = changes.to_dict("records")
        lines += [
            "",
            f"## Against an earlier run of the study (`{against}`)",
            "",
            "The same cases (the same seed: the same drawn truths, designs and noise) in "
            "both runs, each case beside itself: detected before and after, the discordant "
            "pairs, and per kind (`size` empty) the exact two-sided McNemar test on them.",
            "",
            markdown_table(changes, ".3g", missing=""),
        ]
    (out / "summary.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    note = "; ".join(
        (
            [f"STOPPED STUDY: {len(results)} of {n_planned} planned cases (a pilot)"]
            if stopped
            else []
        )
        + (["heights AND tracked jumps (POWER_TRACKING), fitted jointly"] if tracked else [])
    )
    figure(table, results, by_snr, note).savefig(out / "power.png", dpi=130)


def main(argv: list[str] | None = None) -> int:
    """Run (or resume) the study and write its results."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_campaign_options(parser, HERE / "results" / "power", list(POWER_SIZES))
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--per-size", type=int, default=10, help="cases per size (10)")
    parser.add_argument(
        "--tracked", action="store_true", help="film some jumps too (POWER_TRACKING)"
    )
    parser.add_argument(
        "--nulls",
        type=int,
        default=0,
        metavar="N",
        help="instead: N cases without an effect (the false-alarm arm)",
    )
    parser.add_argument(
        "--against",
        type=Path,
        metavar="CSV",
        help="results.csv of an earlier run with the same seed: compare case by case",
    )
    args = parser.parse_args(argv)
    if args.out == HERE / "results" / "power":
        args.out = (
            HERE
            / "results"
            / ("power" + ("_tracked" if args.tracked else "") + ("_null" if args.nulls else ""))
        )
    kinds = chosen_kinds(args.kinds, list(POWER_SIZES))
    if kinds is None:
        return 2
    if args.nulls:
        todo = null_tasks(args.nulls, args.seed, args.tracked)
        summary = write_null_summary
    else:
        todo = tasks(kinds, args.per_size, args.seed, args.tracked)
        summary = partial(write_summary, against=args.against)
    if args.summarize_only:
        return summarize_finished(
            args.out,
            lambda results: summary(args.out, results, args.seed, len(todo), args.tracked),
        )
    description = {
        "kind": "granbayes.calibration.power_case",
        "seed": args.seed,
        "sizes": {k: POWER_SIZES[k] for k in kinds},
        "design": POWER_DESIGN,
    }
    if args.tracked:
        description["tracking"] = POWER_TRACKING
    if args.nulls:
        description["nulls"] = args.nulls
    result = run_study(todo, args, description)
    summary(result.folder, result.results, args.seed, len(todo), args.tracked)
    print((result.folder / "summary.md").read_text())
    return 0 if result.n_failed == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
