"""Study: do the jumps `granbayes design` proposes break ties better than random jumps?

SYNTHETIC cases of the verdict study (``granbayes.calibration.make_case``: the independent
oracle, a drawn robot, design and noise; kind = the true term, seeds spawned from the
master seed) are fitted with the baseline plus the true term and plus its rival, as
``diagnose`` fits a law. Where the paired PSIS-LOO difference is short of the rule's margin
(a tie), ``granbayes.design.design_jumps`` proposes up to ``--max-jumps`` new jumps (every
command, the case's two volume fractions, the study's frequencies 7, 8, 10, 12 Hz); the
control is the same number of jumps at settings drawn uniformly from the same
candidates. Both sets are simulated from the truth by the oracle and both laws refitted
on the data plus each set (``granbayes.calibration.design_tie_case``). A Dask campaign
(resumable).

Writes ``benchmarks/results/design_ties_<kind>_<rival>[_max<N>].csv`` and ``.md`` (``_max<N>``
for a budget other than 40): among the ties, how often the rule then separates the laws
the right way, designed against random, with exact (Clopper-Pearson) 95% intervals, and
how the design's expected difference compares with the one reached.

Usage: ``python benchmarks/design_ties.py [--kind drag] [--rival viscous] [--cases 20]
[--max-jumps 40] [--workers 2] [--out DIR] [--resume] [--finished-only]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

from granbayes.calibration import clopper_pearson, design_tie_case
from granbayes.campaign import ClusterSettings, Task, run_campaign, spawn_seeds
from granbayes.report import markdown_table

HERE = Path(__file__).resolve().parent
MASTER_SEED = 20261127


def main(argv: list[str] | None = None) -> int:
    """Run (or resume) the study and write its tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", default="drag", help="the true term (default drag)")
    parser.add_argument("--rival", default="viscous", help="its rival (default viscous)")
    parser.add_argument("--cases", type=int, default=20)
    parser.add_argument("--max-jumps", type=int, default=40)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("design-ties"))
    parser.add_argument("--resume", action="store_true")
    parser.add_argument(
        "--finished-only",
        action="store_true",
        help="tabulate the cases finished so far in OUT.partial/tasks (a stopped study)",
    )
    args = parser.parse_args(argv)
    seeds = spawn_seeds(MASTER_SEED, args.cases)
    tasks = [
        Task(
            f"{args.kind}-{i:03d}",
            design_tie_case,
            (args.kind, i, args.rival),
            {"max_jumps": args.max_jumps, "n_threads": 1},
            seed=s,
        )
        for i, s in enumerate(seeds)
    ]
    description = {
        "study": "design ties",
        "kind": args.kind,
        "rival": args.rival,
        "max_jumps": args.max_jumps,
        "master_seed": MASTER_SEED,
    }
    note = ""
    if args.finished_only:
        folder = args.out if args.out.exists() else Path(f"{args.out}.partial")
        done = [json.loads(f.read_text()) for f in sorted(folder.glob("tasks/*.json"))]
        table = pd.DataFrame([r for d in done if d["status"] == "ok" for r in d["rows"]])
        if table["index"].nunique() < len(tasks):
            note = (
                f"A STOPPED study: {table['index'].nunique()} of {len(tasks)} cases finished; "
                "the others are not counted."
            )
    else:
        res = run_campaign(
            tasks,
            args.out,
            description=description,
            cluster=ClusterSettings(n_workers=args.workers, numba_threads=1),
            resume=args.resume,
            log=lambda m: print(m, file=sys.stderr),
        )
        table = res.results
    table = table.sort_values(["index", "arm"], kind="stable")
    name = f"design_ties_{args.kind}_{args.rival}" + (
        f"_max{args.max_jumps}" if args.max_jumps != 40 else ""
    )
    (HERE / "results").mkdir(exist_ok=True)
    table.to_csv(HERE / "results" / f"{name}.csv", index=False)
    (HERE / "results" / f"{name}.md").write_text(summary(table, args, note) + "\n")
    print((HERE / "results" / f"{name}.md").read_text())
    return 0


def summary(table: pd.DataFrame, args: argparse.Namespace, note: str) -> str:
    """The study's Markdown table and reading."""
    before = table[table["arm"] == "before"]
    ties = before[~before["settled"] & ~before["wrong_way"]]["index"]
    arms = table[table["index"].isin(ties)]
    rows = []
    for arm in ("designed", "random"):
        a = arms[arms["arm"] == arm]
        k, n = int(a["settled"].sum()), len(a)
        lo, hi = clopper_pearson(k, n) if n else (float("nan"), float("nan"))
        rows.append(
            {
                "new jumps": arm,
                "ties": n,
                "settled the right way": k,
                "rate": k / n if n else float("nan"),
                "95% CI": f"[{lo:.2f}, {hi:.2f}]",
                "settled the wrong way": int(a["wrong_way"].sum()),
                "median new jumps": float(a["n_new"].median()) if n else float("nan"),
                "median diff [nats]": float(a["elpd_diff"].median()) if n else float("nan"),
                "all converged": bool(a["converged"].all()),
            }
        )
    designed = arms[arms["arm"] == "designed"]
    promise = []
    for said, rows_ in designed.groupby("design_settled", sort=False):
        k, n = int(rows_["settled"].sum()), len(rows_)
        lo, hi = clopper_pearson(k, n)
        promise.append(
            {
                "the design expected": "to settle the tie"
                if said
                else f"not to settle it within {args.max_jumps} jumps",
                "ties": n,
                "settled": k,
                "95% CI": f"[{lo:.2f}, {hi:.2f}]",
                "median expected diff [nats]": float(rows_["expected_diff"].median()),
                "median reached [nats]": float(rows_["elpd_diff"].median()),
            }
        )
    cols = [
        "index",
        "truth_effect",
        "sigma_mm",
        "phis",
        "freqs_hz",
        "trials",
        "arm",
        "n_new",
        "elpd_diff",
        "elpd_diff_se",
        "expected_diff",
        "expected_se",
        "settled",
        "max_pareto_k",
        "converged",
    ]
    shown = table[[c for c in cols if c in table]].round(2)
    return "\n".join(
        [
            f"# Designed jumps against random ones: ties of {args.kind} (truth) and "
            f"{args.rival} on SYNTHETIC data",
            "",
            *([note, ""] if note else []),
            f"Cases `granbayes.calibration.make_case({args.kind!r}, seed)` (the oracle of "
            f"`granbayes.testing`), seeds spawned from {MASTER_SEED} "
            f"(`benchmarks/design_ties.py --kind {args.kind} --rival {args.rival} --cases "
            f"{args.cases} --max-jumps {args.max_jumps}`). {len(before)} cases fitted; "
            f"{len(ties)} were ties (paired PSIS-LOO difference short of > 4 nats and "
            f"> 2 SE either way), {int(before['settled'].sum())} already separated, "
            f"{int(before['wrong_way'].sum())} separated the wrong way. On each tie the "
            f"design proposed at most {args.max_jumps} jumps; the control has as many at "
            "random settings of the same candidates; both simulated from the truth by the "
            "oracle, both laws refitted.",
            "",
            markdown_table(pd.DataFrame(rows)),
            "",
            "Does the design know when its plan will do? (designed arm, by what it expected):",
            "",
            markdown_table(pd.DataFrame(promise)) if promise else "",
            "",
            "Expected against reached (designed arm): the design's expected difference "
            f"truth - rival had median {designed['expected_diff'].median():.1f} nats; the "
            f"refits reached median {designed['elpd_diff'].median():.1f}."
            if len(designed)
            else "",
            "",
            "## Every case",
            "",
            markdown_table(shown),
        ]
    )


if __name__ == "__main__":
    raise SystemExit(main())
