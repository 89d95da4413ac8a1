"""Study: does a robot known only to its calibration make ``diagnose`` claim missing physics?

Null data (the truth is the baseline, a depth-only ``k(phi)``) from a SYNTHETIC lab whose
robot's true spring, motor mass and stroke are drawn from their calibration
(``granbayes.calibration.diagnose_miscalibrated``; the independent oracle, seeds 0..N-1),
each diagnosed twice: taking the nominal robot as exact (``--calibration nominal``, what
every version before this one did) and sampling the three parameters with their
calibration as prior (``sample``, the default). A Dask campaign (resumable). Writes
``benchmarks/results/miscalibrated_null.csv`` and ``.md``: the false-discovery rate of each
way with its exact (Clopper-Pearson) 95% interval.

Usage: ``python benchmarks/miscalibrated_null.py [--seeds 20] [--first-seed 0] [--workers 2]
[--out DIR] [--resume] [--modes nominal,sample] [--finished-only]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from granbayes.calibration import MISCALIBRATION, clopper_pearson, diagnose_miscalibrated
from granbayes.campaign import ClusterSettings, Task, finished_tasks, run_campaign
from granbayes.report import markdown_table

HERE = Path(__file__).resolve().parent
MODES = ("nominal", "sample")
#: The issue's robot, in calibration sds from nominal (spring 5990.4 N/m = +4%, motor
#: 1.03 kg = +3%, stroke 19.4 mm = -3%).
ISSUE_ROBOT = {"k_spring": 230.4 / 172.8, "m_motor": 1.5, "amplitude_mm": -1.5}


def main(argv: list[str] | None = None) -> int:
    """Run (or resume) the study and write its table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("miscalibrated-null"))
    parser.add_argument("--resume", action="store_true")
    parser.add_argument(
        "--first-seed",
        type=int,
        default=0,
        help="seeds first-seed..first-seed+seeds-1 (default 0); with another first seed "
        "the results are named ..._from<first-seed> (and ..._<mode> for one mode)",
    )
    parser.add_argument(
        "--issue-robot",
        action="store_true",
        help="the issue's robot instead of draws: spring +4%% (+1.33 sd), motor +3%% "
        "(+1.5 sd), stroke -3%% (-1.5 sd); results named miscalibrated_null_issue_robot",
    )
    parser.add_argument(
        "--phi-sd",
        type=float,
        default=0.0,
        help="each jump's bed's true phi scatters by this much about the written one, and "
        "[bed] phi_sd says so (the issue's lab: 0.002); results named ..._phi",
    )
    parser.add_argument(
        "--finished-only",
        action="store_true",
        help="tabulate the tasks finished so far in OUT.partial/tasks without running any "
        "(a stopped study; the table says how many ran)",
    )
    parser.add_argument(
        "--modes",
        default=",".join(MODES),
        help="comma-separated ways to diagnose (default nominal,sample)",
    )
    args = parser.parse_args(argv)
    modes = tuple(m for m in args.modes.split(",") if m)
    if not modes or set(modes) - set(MODES):
        parser.error(f"--modes {args.modes}: choose from {', '.join(MODES)}")
    offsets = ISSUE_ROBOT if args.issue_robot else None
    name = "miscalibrated_null_issue_robot" if args.issue_robot else "miscalibrated_null"
    name += "_phi" if args.phi_sd > 0 else ""
    name += f"_from{args.first_seed}" if args.first_seed else ""
    name += "" if modes == MODES else "_" + "_".join(modes)
    options = {"offsets_sd": offsets, **({"phi_sd": args.phi_sd} if args.phi_sd > 0 else {})}
    tasks = [
        Task(f"{mode}-{s:03d}", diagnose_miscalibrated, (mode,), options, seed=s)
        for s in range(args.first_seed, args.first_seed + args.seeds)
        for mode in modes
    ]
    description = {"kind": "miscalibrated null", "calibration_sd": MISCALIBRATION}
    if args.phi_sd > 0:
        description["phi_sd"] = args.phi_sd
    if modes != MODES:
        description["modes"] = list(modes)
    if offsets:
        description["offsets_sd"] = offsets
    if args.finished_only:
        done, results = finished_tasks(args.out)  # a study under way or stopped
        table = results.sort_values(["seed", "calibration"])
        note = (
            f"A STOPPED study: {len(table)} of {len(tasks)} diagnoses finished; the others "
            "were still running when it was stopped and are not counted."
        )
        failed = int((done["status"] != "ok").sum())
    else:
        res = run_campaign(
            tasks,
            args.out,
            description=description,
            cluster=ClusterSettings(n_workers=args.workers, numba_threads=1),
            resume=args.resume,
            log=lambda m: print(m, file=sys.stderr),
        )
        table = res.results.sort_values(["seed", "calibration"])
        note, failed = "", res.n_failed
    (HERE / "results").mkdir(exist_ok=True)
    table.to_csv(HERE / "results" / f"{name}.csv", index=False)
    rates = []
    for mode in modes:
        rows = table[table["calibration"] == mode]
        k = int((rows["verdict"] != "baseline_adequate").sum())
        lo, hi = clopper_pearson(k, len(rows))
        rates.append(
            {
                "robot": mode,
                "data sets": len(rows),
                "false discoveries": k,
                "rate": k / max(len(rows), 1),
                "95% CI": f"[{lo:.2f}, {hi:.2f}]",
                "terms named": ", ".join(sorted(set(rows["added"].dropna()) - {""})) or "-",
                "median wall [s]": float(rows["wall_s"].median()),
            }
        )
    shown = table.drop(columns=["elpd_gain_se"])
    lines = [
        "# `diagnose` on SYNTHETIC null data from a robot known only to its calibration",
        "",
        *([note, ""] if note else []),
        f"Data sets of seeds {sorted(set(table['seed']))}, each diagnosed "
        f"with {', '.join(modes)} (where finished); generator "
        "`granbayes.calibration.diagnose_miscalibrated` (the oracle of `granbayes.testing`), "
        "calibration sds "
        + ", ".join(f"{k} {v:g}" for k, v in MISCALIBRATION.items())
        + "; truth: a depth-only k(phi). `nominal`: the robot taken as exact; `sample`: "
        "the three parameters sampled with their calibration as prior. A verdict other "
        "than `baseline_adequate` is a false discovery."
        + (
            " Robot: the issue's (spring +1.33 sd, motor +1.5 sd, stroke -1.5 sd), not drawn."
            if offsets
            else " Robot: drawn from its calibration per data set."
        )
        + (
            f" Beds: each jump's true phi ~ Normal(written, {args.phi_sd:g}) (one bed per "
            "jump), and experiment.toml says so; `diagnose` fits per volume fraction, whose "
            "coefficients absorb it."
            if args.phi_sd > 0
            else ""
        ),
        "",
        markdown_table(pd.DataFrame(rates), ".3g"),
        "",
        markdown_table(shown, ".3g"),
    ]
    (HERE / "results" / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0 if failed == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
