"""Study: coverage of a law smooth in phi when every bed's phi is known only to its measurement.

Simulation-based calibration (``granbayes.run_sbc``, a Dask campaign) of the ``quadratic``
fit (each coefficient a quadratic in ``phi - phi_c``, one scatter) on a SYNTHETIC design:
3 volume fractions (0.602, 0.612, 0.622) x 5 commands x 2 trials at 10 Hz, 30 jumps, in
an experiment whose ``[bed] phi_sd`` is 0.002. Every replicate draws the law's
coefficients and the scatter from the priors the fit uses, puts **every jump on its own
bed** whose true phi is ``Normal(written phi, 0.002)``, and simulates it there with the
independent oracle (``granbayes._sbc.draw_beds``: data the fitting kernel did not make).
The same replicates (same seed) are fitted each way:

- ``integrate``: each jump's bed integrated out of its likelihood (the default), and
- ``measured``: the written phi taken as exact (the fit a lab makes without ``phi_sd``).

Writes ``benchmarks/results/sbc_beds.json`` and ``.md``: per parameter (k, c_d at each
written phi; the scatter) the coverage of the central 50% and 90% intervals with its
binomial SE, the mean normalised rank and the rank-uniformity tests (chi-square, ArviZ's
``pot_c``). A way not run yet (``--ways``) is left out of the table.

Usage: ``python benchmarks/sbc_beds.py [--replicates 50] [--workers 2] [--ways
integrate,measured] [--out DIR] [--resume]``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd

from granbayes import Experiment, stats
from granbayes._fitting import FitSettings
from granbayes._sampler import SamplerSettings
from granbayes._sbc import run_sbc
from granbayes.campaign import ClusterSettings
from granbayes.report import markdown_table
from granbayes.testing import synthetic_jumps

HERE = Path(__file__).resolve().parent
SEED = 20261128
PHI_SD = 0.002
PHIS = (0.602, 0.612, 0.622)
WAYS = ("integrate", "measured")


def design(experiment: Experiment) -> pd.DataFrame:
    """The study's jumps (their heights are replaced by every replicate)."""
    return synthetic_jumps(
        {"k": 3000.0, "c_d": 20.0},
        2.0,
        seed=1,
        phis=PHIS,
        trials=2,
        settings_columns=True,
        experiment=experiment,
    )


def settings(way: str) -> FitSettings:
    """The fit of one way (``integrate`` or ``measured``)."""
    return FitSettings(
        terms=("depth", "drag"),
        phi_mode="quadratic",
        sigma_mode="global",
        bed_phi=way,
        sampler=SamplerSettings(n_walkers=8, n_ensembles=4, max_steps=5000),
    )


def main(argv: list[str] | None = None) -> int:
    """Run (or resume) the study's ways and write their table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicates", type=int, default=50)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--ways", default=",".join(WAYS), help="integrate,measured")
    parser.add_argument("--out", type=Path, default=Path("sbc-beds"))
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args(argv)
    ways = [w for w in args.ways.split(",") if w]
    if not ways or set(ways) - set(WAYS):
        parser.error(f"--ways: choose from {', '.join(WAYS)}")
    experiment = Experiment().replace(phi_sd=PHI_SD)
    jumps = design(experiment)
    summaries = {}
    results_json = HERE / "results" / "sbc_beds.json"
    if results_json.exists():  # the ways run before (another call of this script)
        summaries = json.loads(results_json.read_text())
    for way in ways:
        res = run_sbc(
            experiment,
            jumps,
            args.out / way,
            settings=settings(way),
            n_replicates=args.replicates,
            seed=SEED,
            cluster=ClusterSettings(n_workers=args.workers, numba_threads=1),
            resume=args.resume,
            data_source="SYNTHETIC design, benchmarks/sbc_beds.py",
        )
        summaries[way] = res.summary
        (HERE / "results").mkdir(exist_ok=True)
        results_json.write_text(json.dumps(summaries, indent=1, default=str) + "\n")
    rows = []
    for way in WAYS:
        if way in summaries:
            part = stats.sbc_table(summaries[way]["parameters"])
            part.insert(0, "bed phi in the fit", way)
            rows.append(part)
    lines = [
        "# SBC of the quadratic fit with every bed's phi known to 0.002 (SYNTHETIC replicates)",
        "",
        f"{args.replicates} replicates per way, seed {SEED}, the same replicates for each; "
        f"design: volume fractions {', '.join(map(str, PHIS))} x 5 commands x 2 trials; "
        f"every jump on its own bed, true phi ~ Normal(written, {PHI_SD}), simulated by the "
        "oracle (`granbayes._sbc.draw_beds`). `integrate`: the fit integrates each bed's "
        "phi out; `measured`: it takes the written phi as exact. k and c_d are ranked at "
        "each written phi (values of the same quadratic law), the scatter once per phi "
        "(one global scatter: the same rank three times).",
        "",
        markdown_table(pd.concat(rows, ignore_index=True), ".3g"),
    ]
    (HERE / "results" / "sbc_beds.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
