"""Benchmark and study: simulation-based calibration of ``fit`` on the reference design.

The SBC of ``granbayes.fit`` (depth + drag, one law per volume fraction, the default
priors) on the design of the SYNTHETIC reference data set ``granbayes/data/reference`` (5 volume
fractions x 5 commands x 2 frequencies x 5 trials; the heights themselves are not used):
``--replicates`` (default 100) prior draws, simulations and fits, run as a Dask campaign
on a local cluster, once per worker count of ``--workers`` (default ``1,2``; numba
threads per replicate = cores // workers, so the machine is never oversubscribed). The
same master seed gives the same replicates whatever the worker count, so the runs differ
only in wall time. The study's outputs (``ranks.csv``, ``summary.json``, ``summary.md``,
``sbc_ecdf.png``) of the last worker count are kept in ``--out``; the timings go to
``benchmarks/results/sbc_reference.json`` and ``.md``.

A killed run continues where it stopped with ``--resume`` (per worker count; the timing of
a resumed run then covers only the replicates it computed).

Usage::

    python benchmarks/sbc_reference.py --workers 2          # the study: >= 100 replicates
    python benchmarks/sbc_reference.py --workers 1,2 --replicates 12 --name sbc_scaling \
        --out /tmp/sbc-scaling                               # the scaling, 1 vs 2 workers
    python benchmarks/sbc_reference.py --replicates 4 --quick --out /tmp/sbc-check
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shutil
from pathlib import Path

import numba

from granbayes import load_experiment, load_jumps, simulate
from granbayes._fitting import FitSettings
from granbayes._sampler import SamplerSettings
from granbayes._sbc import run_sbc
from granbayes._synthetic import REFERENCE_DATA
from granbayes.campaign import ClusterSettings, local_cluster_size

HERE = Path(__file__).resolve().parent
DATA = REFERENCE_DATA
RESULTS = HERE / "results"

#: Sampler settings of ``granbayes fit`` (its CLI defaults): converged fits.
FULL = SamplerSettings()
#: Reduced settings to check the machinery quickly: capped, not converged.
QUICK = SamplerSettings(max_steps=300)


def main() -> None:
    """Run the study once per worker count and write the timings."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicates", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", default="1,2", help="comma-separated worker counts")
    parser.add_argument("--rank-draws", type=int, default=99)
    parser.add_argument("--quick", action="store_true", help="capped fits (300 steps)")
    parser.add_argument("--out", type=Path, default=Path("sbc-reference"))
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--results", type=Path, default=RESULTS, help="folder of the timing report")
    parser.add_argument(
        "--name",
        default=None,
        help="stem of the timing report (default sbc_reference, or sbc_reference_quick)",
    )
    args = parser.parse_args()
    worker_counts = [int(w) for w in args.workers.split(",")]
    simulate("single", 0.612, {"k": 3000.0})  # numba cache warm in this process
    experiment = load_experiment(DATA)
    design = load_jumps(DATA, experiment)
    sampler = QUICK if args.quick else FULL
    config = FitSettings(terms=("depth", "drag"), sampler=sampler)
    runs = []
    for workers in worker_counts:
        out = args.out.with_name(f"{args.out.name}-w{workers}")
        res = run_sbc(
            experiment,
            design,
            out,
            settings=config,
            n_replicates=args.replicates,
            seed=args.seed,
            n_rank_draws=args.rank_draws,
            cluster=ClusterSettings(n_workers=workers),
            resume=args.resume,
            data_source="granbayes/data/reference",
            log=print,
        )
        tasks = res.campaign.tasks
        elapsed = tasks.loc[tasks["status"] == "ok", "elapsed_s"].astype(float)
        runs.append(
            {
                "workers": workers,
                "numba_threads_per_replicate": local_cluster_size(workers)[1],
                "wall_s": res.campaign.wall_time_s,
                "replicates_run": res.campaign.n_run,
                "replicates_reused": res.campaign.n_reused,
                "replicates_failed": res.campaign.n_failed,
                "replicate_s_median": float(elapsed.median()),
                "replicate_s_max": float(elapsed.max()),
                "wall_s_per_replicate": res.campaign.wall_time_s / max(1, res.campaign.n_run),
                "folder": str(out),
            }
        )
        print(json.dumps(runs[-1], indent=2))
    last = args.out.with_name(f"{args.out.name}-w{worker_counts[-1]}")
    if args.out.exists():
        shutil.rmtree(args.out)
    shutil.copytree(last, args.out)
    summary = json.loads((args.out / "summary.json").read_text())
    base = runs[0]["wall_s"]
    for run in runs:
        run["speedup_vs_first"] = base / run["wall_s"]
    report = {
        "date": datetime.date.today().isoformat(),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
        "numba": numba.__version__,
        "replicates": args.replicates,
        "quick": args.quick,
        "sampler": {
            "n_walkers": sampler.n_walkers,
            "n_ensembles": sampler.n_ensembles,
            "max_steps": sampler.max_steps,
            "tau_factor": sampler.tau_factor,
        },
        "seed": args.seed,
        "runs": runs,
        "study": str(args.out),
        "calibration": summary["parameters"],
    }
    args.results.mkdir(parents=True, exist_ok=True)
    stem = args.name or ("sbc_reference_quick" if args.quick else "sbc_reference")
    (args.results / f"{stem}.json").write_text(json.dumps(report, indent=2) + "\n")
    lines = [
        f"# SBC of fit (depth + drag) on the reference design ({report['date']})",
        "",
        f"{args.replicates} replicates, seed {args.seed}, "
        + ("capped fits (--quick, 300 steps)" if args.quick else "converged fits")
        + f"; {os.cpu_count()} cores.",
        "",
        "| workers | numba threads each | wall [s] | per replicate [s] | median replicate [s] "
        "| speed-up |",
        "|---|---|---|---|---|---|",
    ]
    for r in runs:
        lines.append(
            f"| {r['workers']} | {r['numba_threads_per_replicate']} | {r['wall_s']:.0f} | "
            f"{r['wall_s_per_replicate']:.1f} | {r['replicate_s_median']:.1f} | "
            f"{r['speedup_vs_first']:.2f} |"
        )
    lines += ["", (args.out / "summary.md").read_text()]
    (args.results / f"{stem}.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
