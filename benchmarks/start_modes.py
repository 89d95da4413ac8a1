"""Study: how often do the Laplace start's climbs miss the truth's mode?

The replicates of the joint-fit SBC (``benchmarks/sbc_joint.py``: its SYNTHETIC design,
priors and master seed, so replicate ``r`` has the same truth and oracle data as the SBC's
replicate ``r``), fitted to heights + tracked jumps and to every kind, are started as a fit
is (``start="laplace"``) with 4 climbs per ensemble (4 ensembles), and every climb's final
log-posterior is recorded (``granbayes._sbc.replicate_start_modes``; no sampling). A start
*finds the truth's mode* if its best climb ends no more than the sampler's ``mode_gap``
(5 nats) below the log-posterior at the true values (the mode lies above the truth by
about d/2 nats, so a climb that stops in another mode falls far below). From the same
climbs, the miss rate of a start with ``c`` climbs per ensemble is read off the first
``c`` climbs of each ensemble (c = 1: the start before 2026-11-27; c = 3: the default).
With intrusion curves, the fit's global phase adds one climb per ensemble from the curves'
own mode; its ends are recorded apart (``anchor_ends``) and tabulated with each ``c``.
A Dask campaign (resumable).

Writes ``benchmarks/results/start_modes.csv`` and ``.md``: per kinds and ``c``, the
replicates whose start missed the truth's mode, with an exact (Clopper-Pearson) 95%
interval, and the fraction of single climbs that reach it.

Usage: ``python benchmarks/start_modes.py [--replicates 50] [--workers 2] [--out DIR]
[--resume]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import sbc_joint  # the SBC's design, priors and seed (this script's folder)

from granbayes import default_priors, load_experiment, load_measurements
from granbayes._fitting import FitSettings
from granbayes._sbc import replicate_start_modes
from granbayes.calibration import clopper_pearson
from granbayes.campaign import (
    ClusterSettings,
    Task,
    finished_tasks,
    run_campaign,
    spawn_seeds,
)
from granbayes.report import markdown_table

HERE = Path(__file__).resolve().parent
CLIMBS = 4
GAP_NATS = 5.0
KINDS = {
    "heights + trajectories": ("heights", "trajectories"),
    "every kind": ("heights", "trajectories", "intrusions"),
}


def _ends(texts: pd.Series, per_ensemble: int) -> np.ndarray:
    """``;``-separated climb ends -> (replicate, ensemble, climb)."""
    values = [[float(v) for v in str(t).split(";") if v != ""] for t in texts.fillna("")]
    return np.array(values).reshape(len(values), -1, per_ensemble)


def miss_table(results: pd.DataFrame) -> pd.DataFrame:
    """Per kinds and climbs per ensemble: starts that missed the truth's mode.

    With intrusion curves, also each ``c`` plus the global phase's climb (from the
    curves' own mode, one per ensemble): the start a fit makes with ``c`` climbs.
    """
    rows = []
    for label, kinds in KINDS.items():
        part = results[results["kinds"] == ",".join(kinds)]
        truth = part["log_prob_truth"].to_numpy()[:, None, None] - GAP_NATS
        reached = _ends(part["climb_ends"], CLIMBS) >= truth  # replicate, ensemble, climb
        anchored = (
            _ends(part["anchor_ends"], 1) >= truth
            if "intrusions" in kinds and "anchor_ends" in part
            else None
        )
        for with_anchor in (False, True) if anchored is not None else (False,):
            for c in range(1, CLIMBS + 1):
                hit = reached[:, :, :c]
                if with_anchor:
                    hit = np.concatenate([hit, anchored], axis=2)
                found = hit.any(axis=(1, 2))
                k = int((~found).sum())
                lo, hi = clopper_pearson(k, len(found))
                rows.append(
                    {
                        "data": label,
                        "climbs per ensemble": f"{c} + intrusion start" if with_anchor else c,
                        "replicates": len(found),
                        "start missed the truth's mode": k,
                        "rate": k / max(len(found), 1),
                        "95% interval": f"[{lo:.3f}, {hi:.3f}]",
                        "single climbs reaching it": float(
                            (anchored if with_anchor else reached).mean()
                        ),
                        "missed": " ".join(str(r) for r in part["replicate"][~found]),
                    }
                )
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    """Run (or resume) the study and write its table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicates", type=int, default=50)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("start-modes"))
    parser.add_argument("--resume", action="store_true")
    parser.add_argument(
        "--finished-only",
        action="store_true",
        help="tabulate the tasks finished so far in OUT.partial/tasks without running any "
        "(a stopped study; the table says how many ran)",
    )
    args = parser.parse_args(argv)
    folder = sbc_joint.design_folder(args.out.with_name(args.out.name + "-design"))
    experiment = load_experiment(folder)
    design = load_measurements(folder, experiment)
    priors = {**default_priors(), **sbc_joint.NOISE_PRIORS}
    settings = FitSettings(terms=sbc_joint.TERMS)
    seeds = spawn_seeds(sbc_joint.SEED, args.replicates)
    tasks = [
        Task(
            f"{'-'.join(kinds)}-{r:03d}",
            replicate_start_modes,
            (experiment, design, settings, priors, kinds, CLIMBS, r),
            seed=seeds[r],
        )
        for kinds in KINDS.values()
        for r in range(args.replicates)
    ]
    note = ""
    if args.finished_only:
        done, results = finished_tasks(args.out)  # a study under way or stopped
        ok = done["status"] == "ok"
        elapsed = done.loc[ok, "elapsed_s"].astype(float)
        n_failed = int((~ok).sum())
        note = (
            f" A STOPPED study: {int(ok.sum())} of {len(tasks)} tasks finished; the others "
            "were not run and are not counted."
        )
    else:
        res = run_campaign(
            tasks,
            args.out,
            description={"study": "start modes", "seed": sbc_joint.SEED, "climbs": CLIMBS},
            cluster=ClusterSettings(n_workers=args.workers, numba_threads=1),
            resume=args.resume,
            log=lambda m: print(m, file=sys.stderr),
        )
        results = res.results
        elapsed = res.tasks.loc[res.tasks["status"] == "ok", "elapsed_s"].astype(float)
        n_failed = res.n_failed
    results = results.sort_values(["kinds", "replicate"])
    (HERE / "results").mkdir(exist_ok=True)
    results.to_csv(HERE / "results" / "start_modes.csv", index=False)
    table = miss_table(results)
    lines = [
        "# Does the Laplace start find the truth's mode? (SYNTHETIC)",
        "",
        f"Replicates 0-{args.replicates - 1} of the joint-fit SBC (`benchmarks/sbc_joint.py`, seed "
        f"{sbc_joint.SEED}: the same truths and oracle data), law "
        f"{' + '.join(sbc_joint.TERMS)}, fitted to heights + tracked jumps and to every kind; "
        f"{CLIMBS} climbs per ensemble, 4 ensembles, every climb's end recorded "
        "(`benchmarks/start_modes.py`). A start finds the truth's mode if its best climb "
        f"ends at most {GAP_NATS:g} nats below the log-posterior at the truth; with c climbs "
        "per ensemble, the first c of each. With intrusion curves a fit adds one climb per "
        "ensemble from the curves' own mode (the global phase, "
        "`granbayes._fitting._closed_form_anchors`): the rows 'c + intrusion start' (its "
        "'single climbs' column: the fraction of those climbs that reach the truth's mode). "
        "Failed tasks: "
        f"{n_failed}. Task time: median {elapsed.median():.0f} s (one numba thread, "
        f"{args.workers} workers).{note}",
        "",
        markdown_table(table, ".3g"),
        "",
        "A start that misses the truth's mode gives a run that can pass every convergence "
        "check in the wrong mode: every ensemble starts there.",
    ]
    (HERE / "results" / "start_modes.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
