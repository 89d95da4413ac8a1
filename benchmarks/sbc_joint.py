"""Study: is the joint fit (heights + tracked jumps + intrusion curves) calibrated?

Simulation-based calibration (``granbayes.run_sbc``, a Dask campaign) of the law
depth + drag + added mass fitted to every kind of measurement at once, on a SYNTHETIC
design like a lab's at one volume fraction (phi 0.612; single and stutter jumps at 10 Hz,
3 trials each; the first trial of each command filmed at 500 frames/s from 20 ms before
the command to 300 ms after it, foot and rod; intrusion tests at 1 and 500 mm/s to 40 mm
every 1 mm). The design's values are replaced by every replicate: per replicate the force
law (k, c_d, kappa), the scatter of the heights, the frame noise of each coordinate, its
correlation time and the force noise are drawn from the fit's priors, and **the
independent oracle** (``granbayes.testing.replicate_measurements``, no code shared with
the fitting kernel) simulates every measurement with a clock offset per tracked jump
drawn from the likelihood's uniform prior. Each replicate is fitted with the default
sampler settings, and every true value ranked among 99 posterior draws.

The priors are the defaults except the noise of the measurements, narrowed to what a lab
with a camera and a force gauge has (its prior knowledge of its instruments): frame noise
log-uniform on [0.05, 2] mm, its correlation time on [0.1, 10] ms (white noise to a drift
over five frames), force noise on [0.05, 2] N. They are written in the results.

Writes ``benchmarks/results/sbc_joint.json`` and ``.md`` (per parameter: coverage of the
central 50% and 90% intervals with its binomial SE, the mean normalised rank, the
rank-uniformity tests; the log-posterior's rank as a test quantity of the whole parameter
vector; how spread the ranked draws are against every kept draw) and the campaign in
``--out``. ``--tau-factor F`` runs every chain to F autocorrelation times instead of the
sampler's 10 (a posterior sampled for longer: is the coverage the chains'?), and
``--name NAME`` writes ``sbc_joint_NAME.*`` instead.

Usage: ``python benchmarks/sbc_joint.py [--replicates 50] [--workers 2] [--out DIR]
[--resume] [--tau-factor F] [--name NAME] [--seed N] [--kinds K,...]``
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
from pathlib import Path

import pandas as pd

from granbayes import Prior, default_priors, load_experiment, load_measurements, stats
from granbayes._fitting import FitSettings
from granbayes._sampler import SamplerSettings
from granbayes._sbc import log_prob_rank_text, run_sbc
from granbayes.campaign import ClusterSettings
from granbayes.report import markdown_table
from granbayes.testing import LabDesign, synthetic_lab_data, write_lab_experiment

HERE = Path(__file__).resolve().parent
SEED = 20261127
TERMS = ("depth", "drag", "added_mass")
DESIGN = LabDesign(
    phis=(0.612,),
    commands=("single", "stutter"),
    trials=3,
    tracked_trials=1,
    fps=500.0,
    intrusion_speeds_mm_s=(1.0, 500.0),
    depth_step_mm=1.0,
)
#: A lab's prior knowledge of its instruments (module docstring).
NOISE_PRIORS = {
    "frame_sd_foot_mm": Prior("loguniform", 0.05, 2.0, unit="mm", why="camera tracking error"),
    "frame_sd_rod_mm": Prior("loguniform", 0.05, 2.0, unit="mm", why="camera tracking error"),
    "frame_tau_ms": Prior("loguniform", 0.1, 10.0, unit="ms", why="white to a 5-frame drift"),
    "force_sd_N": Prior("loguniform", 0.05, 2.0, unit="N", why="force gauge noise"),
}


def design_folder(path: Path) -> Path:
    """The design as an experiment folder (its values are replaced by every replicate)."""
    data = synthetic_lab_data({"k": 4000.0, "c_d": 10.0, "kappa": 1.5}, seed=SEED, design=DESIGN)
    return write_lab_experiment(path, data, truth_file=False)


def main(argv: list[str] | None = None) -> int:
    """Run (or resume) the study and write its table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicates", type=int, default=50)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("sbc-joint"))
    parser.add_argument("--resume", action="store_true")
    parser.add_argument(
        "--tau-factor", type=float, help="chains to this many autocorrelation times (10)"
    )
    parser.add_argument("--name", help="results named sbc_joint_NAME")
    parser.add_argument(
        "--seed", type=int, default=SEED, help=f"master seed ({SEED}): other data sets"
    )
    parser.add_argument(
        "--kinds",
        default="heights,trajectories,intrusions",
        help="the kinds of measurement fitted (and simulated): which one a departure needs",
    )
    args = parser.parse_args(argv)
    stem = "sbc_joint" + (f"_{args.name}" if args.name else "")
    sampler = SamplerSettings()
    if args.tau_factor is not None:
        sampler = dataclasses.replace(sampler, tau_factor=args.tau_factor)
    folder = design_folder(args.out.with_name(args.out.name + "-design"))
    experiment = load_experiment(folder)
    design = load_measurements(folder, experiment, use=args.kinds.split(","))
    priors = {**default_priors(), **NOISE_PRIORS}
    res = run_sbc(
        experiment,
        design,
        args.out,
        settings=FitSettings(terms=TERMS, sampler=sampler),
        n_replicates=args.replicates,
        seed=args.seed,
        priors=priors,
        cluster=ClusterSettings(n_workers=args.workers, numba_threads=1),
        resume=args.resume,
        data_source="SYNTHETIC design, benchmarks/sbc_joint.py",
    )
    table = stats.sbc_table(res.summary["parameters"]).drop(columns="phi")
    tasks = res.campaign.tasks
    elapsed = tasks.loc[tasks["status"] == "ok", "elapsed_s"].astype(float)
    counts = {kind: int(t.shape[0]) for kind, t in design.tables.items()}
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / f"{stem}.json").write_text(
        json.dumps(res.summary, indent=1, default=str) + "\n"
    )
    # the ranks and their ECDF figure, committed beside the table
    for name, saved in (
        ("ranks.csv", f"{stem}_ranks.csv"),
        ("sbc_ecdf.png", f"{stem}_ecdf.png"),
    ):
        shutil.copyfile(args.out / name, HERE / "results" / saved)
    lines = [
        "# SBC of the joint fit: heights + tracked jumps + intrusion curves (SYNTHETIC)",
        "",
        f"{args.replicates} replicates, seed {args.seed}, law {' + '.join(TERMS)}; replicates "
        "made by the independent oracle (`granbayes.testing.replicate_measurements`) from "
        f"prior draws; design (`benchmarks/sbc_joint.py`, kinds {args.kinds}): "
        f"{counts.get('heights', 0)} jumps, "
        f"{design.n_units_of('trajectories') if 'trajectories' in counts else 0} tracked jumps "
        f"({counts.get('trajectories', 0)} frames at {DESIGN.fps:g}/s), "
        f"{design.n_units_of('intrusions') if 'intrusions' in counts else 0} intrusion tests "
        f"({counts.get('intrusions', 0)} samples) at phi {DESIGN.phis[0]:g}. Noise priors: "
        + ", ".join(
            f"{k} {v.dist}[{v.lower:g}, {v.upper:g}] {v.unit}" for k, v in NOISE_PRIORS.items()
        )
        + f". Replicate time: median {elapsed.median():.0f} s "
        f"(range {elapsed.min():.0f}-{elapsed.max():.0f} s), one numba thread per worker, "
        f"{args.workers} workers"
        + (
            f"; every chain run to {args.tau_factor:g} autocorrelation times (the sampler's "
            f"rule: {SamplerSettings().tau_factor:g})"
            if args.tau_factor is not None
            else ""
        )
        + ".",
        "",
        markdown_table(table, ".3g"),
        "",
        "A calibrated fit: coverage near nominal (within about 2 SE), mean rank near 0.5, "
        "uniformity p-values that are not small.",
    ]
    mc = res.summary["mode_check"]
    lines += [
        "",
        f"Missed modes: {mc['n_missed']} of {mc['n_runs']} runs have a truth whose "
        f"log-posterior exceeds every kept draw's by more than {mc['gap_nats']:g} nats "
        f"(median excess of the truth over the best draw {mc['excess_nats_median']:.1f} "
        "nats; a posterior draw lies about d/2 = 4 nats below the mode)"
        + (
            ": "
            + ", ".join(
                f"replicate {m['replicate']} (+{m['excess_nats']:.0f})" for m in mc["missed"]
            )
            if mc["missed"]
            else ""
        )
        + ".",
    ]
    lines += _tails_lines(res.summary["log_prob_rank"], res.ranks)
    (HERE / "results" / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


def _tails_lines(lp: dict, ranks: pd.DataFrame) -> list[str]:
    """The log-posterior's rank (the summary's sentence) and the ranked draws' spread."""
    if not lp.get("n_runs"):
        return []
    spread = ranks.groupby("parameter", sort=False)["spread_ratio"].median()
    return [
        "",
        log_prob_rank_text(lp)
        + " Spread of the ranked draws (16-84% range over that of every kept draw; median "
        "over runs; about 1 if they are as spread as the run's sample): "
        + ", ".join(f"{name} {value:.2f}" for name, value in spread.items())
        + ".",
    ]


if __name__ == "__main__":
    raise SystemExit(main())
