"""Study: coverage of ``k`` and ``c_d`` when the robot is known only to its calibration.

Simulation-based calibration (``granbayes.run_sbc``, a Dask campaign) on a SYNTHETIC
design (2 volume fractions x 5 commands x 2 trials at 10 Hz; the design's heights are
replaced by every replicate) of an experiment whose ``[robot.uncertainty]`` gives the
spring, the motor mass and the stroke a calibration sd (``granbayes.calibration.
MISCALIBRATION``). Every replicate draws the force law (depth + drag), the scatter AND the
robot's three parameters from their priors, simulates the design with the compiled kernel
(SBC checks the fit against its own generative model) and fits it twice over the same
replicates (same seeds): ignoring the calibration's uncertainty (``nominal``) and sampling
it (``sample``, each volume fraction's run its own copy, as its replicates draw one robot
per volume fraction). ``--modes pool`` fits with one robot for both volume fractions
(``calibration="pool"``), whose replicates draw one robot for both (the same seeds, so
the same laws and scatter but another robot and noise). Writes
``benchmarks/results/<name>.json`` and ``.md`` (``--name``, default ``sbc_calibration``): per
parameter and volume fraction the coverage of the central 50% and 90% intervals with its
binomial SE, the mean normalised rank (0.5 if calibrated) and the rank-uniformity tests
(chi-square, ArviZ's ``pot_c``).

Usage: ``python benchmarks/sbc_calibration.py [--replicates 50] [--workers 2] [--out DIR]
[--resume] [--modes nominal,sample] [--name sbc_calibration]``
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import pandas as pd

from granbayes import Experiment, stats
from granbayes._fitting import FitSettings
from granbayes._sampler import SamplerSettings
from granbayes._sbc import run_sbc
from granbayes.calibration import MISCALIBRATION
from granbayes.campaign import ClusterSettings, finished_tasks
from granbayes.report import markdown_table
from granbayes.testing import synthetic_jumps

HERE = Path(__file__).resolve().parent
SEED = 20261126


def main(argv: list[str] | None = None) -> int:
    """Run (or resume) both studies and write their table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicates", type=int, default=50)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("sbc-calibration"))
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--modes", default="nominal,sample", help="calibration modes, in turn")
    parser.add_argument("--name", default="sbc_calibration", help="name of the results files")
    parser.add_argument(
        "--finished-only",
        action="store_true",
        help="tabulate the replicates finished so far in OUT/<mode>.partial without running "
        "any (a stopped study; the table says how many finished)",
    )
    args = parser.parse_args(argv)
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    experiment = dataclasses.replace(
        Experiment(), calibration_sd=tuple(sorted(MISCALIBRATION.items()))
    )
    design = synthetic_jumps(
        {"k": 3000.0, "c_d": 20.0},
        2.0,
        seed=1,
        phis=(0.602, 0.622),
        trials=2,
        settings_columns=True,
        experiment=experiment,
    )
    sampler = SamplerSettings(n_walkers=8, n_ensembles=4, max_steps=5000)
    rows = []
    summaries = {}
    notes = []
    for mode in modes:
        if args.finished_only:  # a stopped study: the replicates that finished
            done, ranks = finished_tasks(args.out / mode)
            n_done = int(done["status"].eq("ok").sum())
            notes.append(
                f"A STOPPED study ({mode}): {n_done} of {args.replicates} replicates finished; "
                "the others were still running or not started and are not counted (a "
                "replicate that takes long is not a random one: the table may be biased)."
            )
            summaries[mode] = {"finished": n_done, "parameters": stats.summarize_ranks(ranks)}
            part = stats.sbc_table(summaries[mode]["parameters"])
            part.insert(0, "fit's robot", mode)
            rows.append(part)
            continue
        config = FitSettings(terms=("depth", "drag"), sampler=sampler, calibration=mode)
        res = run_sbc(
            experiment,
            design,
            args.out / mode,
            settings=config,
            n_replicates=args.replicates,
            seed=SEED,
            cluster=ClusterSettings(n_workers=args.workers, numba_threads=1),
            resume=args.resume,
            data_source="SYNTHETIC design, benchmarks/sbc_calibration.py",
        )
        summaries[mode] = res.summary
        part = stats.sbc_table(res.summary["parameters"])
        part.insert(0, "fit's robot", mode)
        rows.append(part)
    table = pd.concat(rows, ignore_index=True)
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / f"{args.name}.json").write_text(
        json.dumps(summaries, indent=1, default=str) + "\n"
    )
    lines = [
        "# SBC with a robot known only to its calibration (SYNTHETIC replicates)",
        "",
        *[line for note in notes for line in (note, "")],
        f"{args.replicates} replicates per way ({', '.join(modes)}), seed {SEED}; "
        "calibration sds " + ", ".join(f"{k} {v:g}" for k, v in MISCALIBRATION.items()) + ". "
        "`nominal`: the fit takes the robot as exact; `sample`: it samples the three robot "
        "parameters with their calibration as prior, each volume fraction's run its own "
        "copy (the replicates of both draw one robot per volume fraction: the same "
        "replicates); `pool`: one robot for both volume fractions, one run (its replicates "
        "draw one robot for both).",
        "",
        markdown_table(table, ".3g"),
    ]
    (HERE / "results" / f"{args.name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
