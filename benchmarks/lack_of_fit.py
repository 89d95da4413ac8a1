"""Study: would an omnibus lack-of-fit test see what the cell test misses?

Every case of the verdict study of 160a653 (``benchmarks/results/verdicts_160a653``:
SYNTHETIC data from the oracle, ``granbayes.calibration.make_case``; sampler replicate 0,
one row per case) is drawn again
from its task seed, and the law its diagnosis selected (the baseline plus the terms it
added) refitted with the diagnosis's sampler settings
(``granbayes.calibration.lack_of_fit_case``; a Dask campaign, resumable). Its omnibus
lack-of-fit test (``granbayes.stats.lack_of_fit``: the cell means against the law,
against the pure error of the repeats, all cells together) is read against the study's
outcome: on the cases the diagnosis got right, a p-value below ``--alpha`` is a false
alarm the test would add; on the false claims and misses outside the library, one it
would catch.

This reads the test on the selected law alone, not inside ``diagnose``: a rule that used
it would also try terms where it fires on the baseline, which this does not replay.

Writes into OUT (default ``benchmarks/results/lack_of_fit``): ``results.csv`` (the study's
row of each case with the refit's test) and ``summary.md`` / ``summary.json`` (per kind and
outcome, how many the test flags, with exact 95% intervals; the uniformity of its p-values
where the law is right).

Usage::

    python benchmarks/lack_of_fit.py [--study benchmarks/results/verdicts_160a653]
        [--alpha 0.05] [--out DIR] [--workers N | --scheduler ADDRESS] [--resume]
        [--summarize-only]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd
from _studies import (  # this folder
    add_campaign_options,
    run_study,
    summarize_finished,
)
from scipy import stats

from granbayes import __version__
from granbayes.calibration import (
    FALSE_CLAIM,
    LIBRARY_EFFECTS,
    NOT_DETECTED,
    RIGHT,
    RIGHT_TIED,
    clopper_pearson,
    lack_of_fit_case,
    outcome,
    primary_rows,
)
from granbayes.campaign import Task
from granbayes.report import markdown_table

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def study_rows(study: Path) -> pd.DataFrame:
    """The study's primary rows with their task seeds and outcomes."""
    rows = pd.read_csv(study / "results.csv", keep_default_na=False, na_values=[""])
    rows = primary_rows(rows)
    seeds = pd.read_csv(study / "tasks.csv").set_index("task_id")["seed"]
    rows = rows[rows["verdict"] != "over_budget"].copy()
    rows["seed"] = [int(seeds[t]) for t in rows["task_id"]]
    rows["outcome"] = [outcome(r) for r in rows.to_dict("records")]
    return rows.reset_index(drop=True)


def tasks(rows: pd.DataFrame) -> list[Task]:
    """One refit per case."""
    return [
        Task(
            r.task_id,
            lack_of_fit_case,
            (r.kind, int(r.index), tuple(r.added.split("+")) if isinstance(r.added, str) else ()),
            seed=int(r.seed),
        )
        for r in rows.itertuples()
    ]


def _shown(path: Path) -> str:
    """A path as the repository names it."""
    try:
        return str(Path(path).resolve().relative_to(ROOT))
    except ValueError:
        return str(path)


def _count(flags: pd.Series) -> str:
    k, n = int(flags.sum()), int(flags.size)
    if n == 0:
        return "-"
    lo, hi = clopper_pearson(k, n)
    return f"{k}/{n} [{lo:.2f}, {hi:.2f}]"


def summary_tables(merged: pd.DataFrame, alpha: float) -> dict[str, pd.DataFrame]:
    """Flags per kind and outcome; the false-alarm and catch rates; p-value uniformity."""
    merged = merged.assign(flagged=merged["lof_p_value"] < alpha)
    right = merged["outcome"].isin([RIGHT, RIGHT_TIED])
    group = np.where(
        merged["kind"] == "null",
        "null",
        np.where(merged["kind"].isin(LIBRARY_EFFECTS), "library term", "outside the library"),
    )
    merged = merged.assign(group=group, right=right)
    in_library = merged["group"] != "outside the library"
    per_kind = (
        merged.groupby(["kind", "outcome"], sort=False)
        .apply(
            lambda g: pd.Series(
                {
                    "cases": len(g),
                    "flagged": _count(g["flagged"]),
                    "median p": float(g["lof_p_value"].median()),
                    "median cell max |z|": float(g["max_abs_z"].median()),
                }
            ),
            include_groups=False,
        )
        .reset_index()
    )
    rates = []
    for name, mask in (
        ("right verdicts, null data (false alarms)", right & (merged["group"] == "null")),
        (
            "right verdicts, library terms (false alarms)",
            right & (merged["group"] == "library term"),
        ),
        ("right verdicts, null and library (false alarms)", right & in_library),
        (
            "right verdicts outside the library (flagged too)",
            right & ~in_library,
        ),
        (
            "false claims outside the library (caught)",
            (merged["group"] == "outside the library") & (merged["outcome"] == FALSE_CLAIM),
        ),
        (
            "not detected outside the library (caught)",
            (merged["group"] == "outside the library") & (merged["outcome"] == NOT_DETECTED),
        ),
        (
            "not detected, library terms (seen)",
            (merged["group"] == "library term") & (merged["outcome"] == NOT_DETECTED),
        ),
    ):
        part = merged[mask]
        rates.append({"cases": name, f"p < {alpha:g}": _count(part["flagged"])})
    p_right = merged.loc[right & in_library, "lof_p_value"].dropna()
    ks = stats.kstest(p_right, "uniform")
    uniform = pd.DataFrame(
        [
            {
                "right verdicts (null, library)": len(p_right),
                "share p < 0.05": float(np.mean(p_right < 0.05)),
                "share p < 0.10": float(np.mean(p_right < 0.10)),
                "median p": float(np.median(p_right)),
                "KS statistic": float(ks.statistic),
                "KS p-value": float(ks.pvalue),
            }
        ]
    )
    return {"rates": pd.DataFrame(rates), "per_kind": per_kind, "uniform": uniform}


def write_summary(out: Path, results: pd.DataFrame, rows: pd.DataFrame, args) -> None:
    """results.csv (joined with the study), summary.md and summary.json."""
    merged = rows.merge(
        results.drop(columns=["kind", "index"]), left_on="task_id", right_on="task_id"
    )
    merged.to_csv(out / "results.csv", index=False)
    tables = summary_tables(merged, args.alpha)
    doc = {
        "study": _shown(args.study),
        "alpha": args.alpha,
        "granbayes": __version__,
        "n_cases": len(merged),
        "n_planned": len(rows),
        "all_converged": bool(merged["converged"].all()),
        **{k: v.to_dict("records") for k, v in tables.items()},
    }
    (out / "summary.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    stopped = len(merged) < len(rows)
    lines = [
        "# An omnibus lack-of-fit test on the verdict study's selected laws (SYNTHETIC data)",
        "",
        f"Generated by `benchmarks/lack_of_fit.py` from `{_shown(args.study)}` (its cases "
        "drawn again from their task seeds by `granbayes.calibration.lack_of_fit_case`, the "
        f"selected law refitted); {len(merged)} cases"
        + (f" (**a stopped study: {len(merged)} of {len(rows)}**)" if stopped else "")
        + f", every fit converged: {doc['all_converged']}. Flagged: the test's p-value "
        f"below {args.alpha:g} (`granbayes.stats.lack_of_fit`). Exact (Clopper-Pearson) 95% "
        "intervals. The test is read on the law the diagnosis selected, not inside "
        "`diagnose` (a rule using it would also try terms where it fires on the baseline).",
        "",
        markdown_table(tables["rates"]),
        "",
        "Its p-values where the diagnosis was right on null data and hidden library terms "
        "(a calibrated test: uniform, or larger since the law was selected on these data):",
        "",
        markdown_table(tables["uniform"], ".3g"),
        "",
        "Per kind and outcome:",
        "",
        markdown_table(tables["per_kind"], ".3g"),
    ]
    (out / "summary.md").write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    """Run (or resume) the study and write its results."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_campaign_options(parser, HERE / "results" / "lack_of_fit", [])
    parser.add_argument("--study", type=Path, default=HERE / "results" / "verdicts_160a653")
    parser.add_argument("--alpha", type=float, default=0.05)
    args = parser.parse_args(argv)
    rows = study_rows(args.study)
    todo = tasks(rows)
    if args.summarize_only:
        return summarize_finished(
            args.out, lambda results: write_summary(args.out, results, rows, args)
        )
    description = {"kind": "granbayes.calibration.lack_of_fit_case", "study": str(args.study)}
    result = run_study(todo, args, description)
    write_summary(result.folder, result.results, rows, args)
    print((result.folder / "summary.md").read_text())
    return 0 if result.n_failed == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
