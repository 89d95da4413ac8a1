"""Benchmark: ``granbayes fit`` on the SYNTHETIC reference data set, terms depth + drag.

Target (speed issue): ``granbayes fit`` on the reference data, converged by the
multi-ensemble rule, in <= 15 s wall for the whole process on the 2-core machine (this
script times it in-process; the whole process is timed from outside, README). Runs the
fit as the CLI does (HDF5 checkpoint, report with figures) under cProfile and reports
where the time goes.
Writes ``benchmarks/results/fit.json`` and ``fit.md`` (``--name``: other names).

Usage: ``python benchmarks/bench_fit.py [--seed N] [--no-report] [--name NAME]``
"""

from __future__ import annotations

import argparse
import cProfile
import datetime
import json
import os
import platform
import pstats
import tempfile
import time
from pathlib import Path

import numba

from granbayes import load_experiment, load_jumps, simulate
from granbayes._fitting import FitSettings, fit
from granbayes._synthetic import REFERENCE_DATA
from granbayes.report import write_fit_report

HERE = Path(__file__).resolve().parent
DATA = REFERENCE_DATA

#: (label, function name fragment in the profile) rows of the time breakdown.
BREAKDOWN = (
    ("simulator (compiled kernel, via simulate_rows)", "simulate_rows"),
    ("dispersed, optimised starts of the ensembles", "_find_starts_many"),
    ("sampling, every ensemble side by side, incl. likelihood", "run_side_by_side"),
    ("  of which HDF5 checkpoints", "save_checkpoint"),
    ("  of which convergence checks (tau, R-hat, ESS)", "_check"),
    ("DataTree: draws, posterior and prior predictive, log-likelihood", "_assemble"),
    ("  of which prior draws and prior predictive", "_prior_draws"),
)


def _cumtime(stats: pstats.Stats, fragment: str) -> float:
    total = 0.0
    for (_, _, name), (_, _, _, ct, _) in stats.stats.items():
        if name == fragment:
            total = max(total, ct)
    return total


def main() -> None:
    """Run the benchmark and print a Markdown report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-report", action="store_true", help="skip figures and tables")
    parser.add_argument(
        "--name",
        default="fit",
        help="results file names: results/NAME.json and NAME.md (default fit; e.g. one per "
        "machine kind)",
    )
    args = parser.parse_args()
    simulate("single", 0.612, {"k": 3000.0})  # compile / load the cache outside the timing
    experiment = load_experiment(DATA)
    table = load_jumps(DATA, experiment)
    config = FitSettings(terms=("depth", "drag"))
    with tempfile.TemporaryDirectory() as tmp:
        prof = cProfile.Profile()
        t0 = time.perf_counter()
        prof.enable()
        result = fit(experiment, table, config, seed=args.seed, checkpoint=Path(tmp) / "chains")
        t_fit = time.perf_counter() - t0
        prof.disable()
        t1 = time.perf_counter()
        if not args.no_report:
            write_fit_report(result.datatree, Path(tmp))
        t_report = time.perf_counter() - t1
        wall = time.perf_counter() - t0
    stats = pstats.Stats(prof)
    diag = result.diagnostics()
    rows = [(label, _cumtime(stats, frag)) for label, frag in BREAKDOWN]
    rows.append(("report: tables, LOO, figures, netCDF (not profiled)", t_report))
    n_sims = int((diag["n_steps"] * diag["n_chains"]).sum()) * 10
    report = {
        "date": datetime.date.today().isoformat(),
        "wall_s": wall,
        "fit_s": t_fit,
        "converged": bool(diag["converged"].all()),
        "runs": diag[
            [
                "run",
                "n_ensembles",
                "n_chains",
                "n_steps",
                "tau_max",
                "rhat_max",
                "ess_min",
                "acceptance",
                "converged",
            ]
        ].to_dict("records"),
        "breakdown_s": dict(rows),
        "approx_simulations": n_sims,
        "numba_threads": numba.get_num_threads(),
        "machine": (
            f"{platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"
        ),
        "seed": args.seed,
    }
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / f"{args.name}.json").write_text(json.dumps(report, indent=2, default=float))
    lines: list[str] = []
    emit = lines.append
    emit(f"### `granbayes fit` on the synthetic reference data (depth + drag), {report['date']}")
    emit("")
    emit(
        f"- wall time: **{wall:.1f} s** (the fit {t_fit:.1f} s, the report the rest; "
        "target for the whole process <= 15 s); "
        f"converged: {report['converged']}; numba threads: {report['numba_threads']}"
    )
    emit(f"- about {n_sims:,} jump simulations")
    emit("")
    emit("| where the time goes | s |")
    emit("|---|---|")
    for label, t in rows:
        emit(f"| {label} | {t:.1f} |")
    emit("")
    cols = ["run", "n_steps", "tau_max", "rhat_max", "ess_min", "acceptance", "converged"]
    emit("| " + " | ".join(cols) + " |")
    emit("|" + "---|" * len(cols))
    for r in diag[cols].itertuples(index=False):
        emit(
            f"| {r.run} | {r.n_steps} | {r.tau_max:.1f} | {r.rhat_max:.3f} | {r.ess_min:.0f} "
            f"| {r.acceptance:.2f} | {r.converged} |"
        )
    emit("")
    emit(f"machine: {report['machine']}")
    text = "\n".join(lines) + "\n"
    (HERE / "results" / f"{args.name}.md").write_text(text)
    print(text, end="")


if __name__ == "__main__":
    main()
