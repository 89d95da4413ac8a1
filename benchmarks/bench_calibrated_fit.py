"""Benchmark: the cost and the answer of sampling the robot's calibration in a fit.

The issue's lab (SYNTHETIC, the oracle of ``granbayes.testing``): 200 jumps (5 volume
fractions x 2 frequencies x 5 commands x 4 trials), a depth-only truth ``k(phi) = 3000
exp(25 (phi - phi_c))`` N/m, scatter 1 mm, from a robot whose spring is 4% stiffer, motor
3% heavier and stroke 3% shorter than nominal (1.33, 1.5 and 1.5 calibration sds;
``[robot.uncertainty]`` k_spring 172.8 N/m, m_motor 0.02 kg, amplitude_mm 0.4 mm). For
each seed of the scatter, the same data are fitted (terms ``depth``, ``per_phi``, default
sampler) taking the robot as exact (``nominal``), sampling the three parameters with a
copy per volume fraction's run (``sample``) and with one robot for every volume fraction
(``pool``: one run of them all), in turn in one process, so the ratios of wall times are
measured under the same load. Records per fit the wall time, the steps of every run,
convergence, and ``k``'s posterior against the truth (z = (mean - truth) / sd) at every
volume fraction; and the posterior of the robot parameters against their calibration.
Writes ``benchmarks/results/calibrated_fit.json`` and ``.md``.

Usage: ``python benchmarks/bench_calibrated_fit.py [--seeds 3]``
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numba
import numpy as np
import pandas as pd

import granbayes as gb
from granbayes._fitting import FitSettings, fit
from granbayes.commands import COMMAND_NAMES
from granbayes.report import markdown_table
from granbayes.testing import LabDesign, synthetic_lab_data, write_lab_experiment

HERE = Path(__file__).resolve().parent
PHIS = (0.592, 0.602, 0.612, 0.622, 0.632)
SD = {"k_spring": 172.8, "m_motor": 0.02, "amplitude_mm": 0.4}
TRUE = {"k_spring": 5760.0 * 1.04, "m_motor": 1.03, "amplitude_mm": 19.4}
MODES = ("nominal", "sample", "pool")


def true_k(phi: float) -> float:
    """The truth's depth stiffness [N/m] at ``phi``."""
    return 3000.0 * float(np.exp(25.0 * (phi - 0.612)))


def one_fit(exp, data, calibration: str, seed: int) -> dict:
    """Fit and summarise."""
    config = FitSettings(terms=("depth",), calibration=calibration, n_prior_draws=0)
    t0 = time.perf_counter()
    res = fit(exp, data, config, seed=seed)
    wall = time.perf_counter() - t0
    post = res.datatree["posterior"]
    k = post["k"]
    mean, sd = k.mean(("chain", "draw")).values, k.std(("chain", "draw")).values
    truth = np.array([true_k(p) for p in post["phi"].values])
    row = {
        "calibration": calibration,
        "seed": seed,
        "wall_s": wall,
        "converged": res.converged,
        "steps": [int(p.run.n_steps) for p in res.parts],
        "k_z": ((mean - truth) / sd).round(2).tolist(),
        "sigma_mm": post["sigma_mm"].mean(("chain", "draw")).values.round(3).tolist(),
    }
    for name in SD:
        if name in post:
            v = post[name]
            row[name] = {
                "mean_per_phi": v.mean(("chain", "draw")).values.round(4).tolist(),
                "sd_per_phi": v.std(("chain", "draw")).values.round(4).tolist(),
            }
    return row


def main(argv: list[str] | None = None) -> int:
    """Run the pairs and write the results."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args(argv)
    design = LabDesign(
        phis=PHIS,
        commands=COMMAND_NAMES,
        freqs_hz=(10.0, 12.0),
        trials=4,
        sigma_mm=1.0,
        tracked_trials=0,
        intrusion_speeds_mm_s=(),
        robot_sd=SD,
        robot_true=TRUE,
    )
    rows = []
    for seed in range(args.seeds):
        lab = synthetic_lab_data(lambda phi: {"k": true_k(phi)}, seed=seed, design=design)
        with tempfile.TemporaryDirectory() as tmp:
            folder = write_lab_experiment(Path(tmp) / "lab", lab)
            exp = gb.load_experiment(folder)
            data = gb.load_measurements(folder, exp)
            for calibration in MODES:
                rows.append(one_fit(exp, data, calibration, seed))
                print(json.dumps(rows[-1]), flush=True)
    wall = {m: [r["wall_s"] for r in rows if r["calibration"] == m] for m in MODES}
    ratios = [s / n for n, s in zip(wall["nominal"], wall["sample"], strict=True)]
    pool_ratios = [p / n for n, p in zip(wall["nominal"], wall["pool"], strict=True)]
    pool_over_sample = [p / s for s, p in zip(wall["sample"], wall["pool"], strict=True)]
    result = {
        "date": datetime.date.today().isoformat(),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "data": "SYNTHETIC: granbayes.testing.synthetic_lab_data, seeds 0..N-1 (design above)",
        "true_robot": TRUE,
        "calibration_sd": SD,
        "fits": rows,
        "median_ratio_sample_over_nominal": float(np.median(ratios)),
        "ratios": ratios,
        "median_ratio_pool_over_nominal": float(np.median(pool_ratios)),
        "pool_ratios": pool_ratios,
        "median_ratio_pool_over_sample": float(np.median(pool_over_sample)),
        "pool_over_sample": pool_over_sample,
        "numba_threads": numba.get_num_threads(),
    }
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "calibrated_fit.json").write_text(json.dumps(result, indent=1) + "\n")
    table = [
        {
            "seed": r["seed"],
            "robot": r["calibration"],
            "wall [s]": round(r["wall_s"], 1),
            "steps per run": " ".join(map(str, r["steps"])),
            "converged": r["converged"],
            "z of k per phi": " ".join(f"{z:+.1f}" for z in r["k_z"]),
            "sigma_mm per phi (truth 1)": " ".join(f"{s:.2f}" for s in r["sigma_mm"]),
            "k_spring per phi [N/m] (truth 5990)": " ".join(
                f"{m:.0f}±{s:.0f}"
                for m, s in zip(
                    r.get("k_spring", {}).get("mean_per_phi", []),
                    r.get("k_spring", {}).get("sd_per_phi", []),
                    strict=True,
                )
            )
            or "-",
        }
        for r in rows
    ]
    lines = [
        "# Sampling the robot's calibration: cost and answer (SYNTHETIC lab data)",
        "",
        f"{result['date']}, {result['machine']}; data: {result['data']}. Truth: depth-only "
        "k(phi) = 3000 exp(25 (phi - 0.612)) N/m, scatter 1 mm, robot k_spring 5990 N/m, "
        "m_motor 1.03 kg, stroke 19.4 mm (nominal 5760, 1.0, 20.0; calibration sds 172.8, "
        "0.02, 0.4). Fits: terms depth, per_phi, default sampler; `sample` samples the "
        "three robot parameters (each volume fraction's run its own copy); `pool` samples "
        "one robot for every volume fraction (one run of them all). numba threads: "
        f"{result['numba_threads']}.",
        "",
        f"Median wall-time ratios, paired by seed: sample / nominal "
        f"{result['median_ratio_sample_over_nominal']:.2f} "
        f"({', '.join(f'{r:.2f}' for r in ratios)}); pool / nominal "
        f"{result['median_ratio_pool_over_nominal']:.2f} "
        f"({', '.join(f'{r:.2f}' for r in pool_ratios)}); pool / sample "
        f"{result['median_ratio_pool_over_sample']:.2f} "
        f"({', '.join(f'{r:.2f}' for r in pool_over_sample)}).",
        "",
        markdown_table(pd.DataFrame(table)),
    ]
    (HERE / "results" / "calibrated_fit.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
