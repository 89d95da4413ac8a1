"""The verdict study's grazing null case: does its fit converge now, and in how many steps?

Before 2026-11-26 the jump height ended at any fall of the foot through the surface after
the command, and a graze by a fraction of a millimetre made the height discontinuous in
``k`` (docs/physics-model.md section 10). The verdict study's first runs met it in their
null case 4: a 12 Hz delayed stutter on phi = 0.607 whose true ``k`` (1964.8 N/m) lay in
a 2 N/m window where the height fell from ~9.5 mm to ~0.1 mm; the baseline fit did not
converge within ``diagnose``'s cap (10,000 steps, then 20,000).

This script rebuilds that case (its robot, design, noise level and ``k(phi)`` law, as the
study drew them with seed 20261123; written out below) as SYNTHETIC data, with the true
heights from the independent oracle (``granbayes.testing.simulate_height_scipy``, which
shares no code with the fitting kernel) and seeded Gaussian scatter, and runs what
``diagnose`` runs first: the baseline fit (depth only, ``diagnose``'s sampler settings).
It reports the true heights of the grazing cell under the contract (the flight rule) and
the fit's steps, autocorrelation time, R-hat and ESS per volume fraction. Writes
``benchmarks/results/graze_case.{json,md}``.

Usage: ``python benchmarks/graze_case.py [--seed N]``
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import time
from pathlib import Path

import numpy as np
import pandas as pd

from granbayes import CommandSettings, Experiment, Robot
from granbayes._criticism import DiagnoseSettings
from granbayes._fitting import FitSettings, fit
from granbayes.testing import simulate_height_scipy

HERE = Path(__file__).resolve().parent

#: The case as the study drew it (granbayes.calibration before 2026-11-24, null case 4).
ROBOT = Robot(
    m_motor=0.9817830293780063,
    m_rod=0.2641413138276012,
    m_foot=0.09258289553240551,
    k_spring=4856.959267515818,
    c_spring=4.900005369056386,
    foot_radius=0.03983808792481511,
    grain_density=1100.0,
)
AMPLITUDE_MM = 16.403597907149862
PHIS = (0.607, 0.632)
FREQS_HZ = (8.0, 12.0)
SIGMA_MM = 2.498314446171891
TRIALS = 3
K_LAW = (2629.5293772851755, 136522.26426513738, 715787.5066919713)  # N/m, x = phi - 0.612
COMMANDS = ("single", "preload", "stutter", "delayed_stutter", "delayed_stutter_preload")


def k_of(phi: float) -> float:
    """True depth stiffness [N/m] at ``phi``."""
    x = phi - 0.612
    return K_LAW[0] + K_LAW[1] * x + K_LAW[2] * x * x


def make_data(seed: int) -> tuple[Experiment, pd.DataFrame]:
    """The SYNTHETIC jumps: oracle heights of the true law plus seeded scatter."""
    experiment = Experiment(robot=ROBOT, command=CommandSettings(amplitude_mm=AMPLITUDE_MM))
    rng = np.random.default_rng(seed)
    rows = []
    for phi in PHIS:
        for freq in FREQS_HZ:
            cell = experiment.replace(freq_hz=freq)
            for command in COMMANDS:
                h = simulate_height_scipy(command, phi, {"k": k_of(phi)}, experiment=cell)
                for trial in range(1, TRIALS + 1):
                    rows.append(
                        {
                            "phi": phi,
                            "command": command,
                            "freq_hz": freq,
                            "amplitude_mm": AMPLITUDE_MM,
                            "delay_ms": 50.0,
                            "settle_periods": 3.0,
                            "trial": trial,
                            "true_height_mm": h,
                            "height_mm": h + rng.normal(0.0, SIGMA_MM),
                            "source": f"synthetic: benchmarks/graze_case.py seed={seed}",
                        }
                    )
    return experiment, pd.DataFrame(rows)


def main() -> None:
    """Build the case, fit the baseline, write the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=4)
    args = parser.parse_args()
    experiment, table = make_data(args.seed)
    graze = table[(table["command"] == "delayed_stutter") & (table["freq_hz"] == 12.0)]
    true_graze = graze.groupby("phi")["true_height_mm"].first().to_dict()
    sampler = DiagnoseSettings().sampler
    t0 = time.perf_counter()
    result = fit(
        experiment,
        table.drop(columns="true_height_mm"),
        FitSettings(terms=("depth",), sampler=sampler, n_prior_draws=0),
        seed=args.seed,
    )
    wall = time.perf_counter() - t0
    diag = result.diagnostics()
    post = result.datatree.posterior["k"]
    report = {
        "date": datetime.date.today().isoformat(),
        "true_k_N_m": {f"{p:g}": k_of(p) for p in PHIS},
        "true_height_delayed_stutter_12hz_mm": {f"{p:g}": v for p, v in true_graze.items()},
        "sampler_cap_steps": sampler.max_steps,
        "converged": bool(result.converged),
        "runs": diag[["run", "n_steps", "tau_max", "rhat_max", "ess_min", "converged"]].to_dict(
            "records"
        ),
        "k_posterior_90": {
            f"{p:g}": [float(v) for v in np.quantile(post.sel(phi=p).values, [0.05, 0.5, 0.95])]
            for p in PHIS
        },
        "wall_s": wall,
        "seed": args.seed,
        "machine": f"{platform.platform()}, Python {platform.python_version()}",
    }
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "graze_case.json").write_text(json.dumps(report, indent=2) + "\n")
    lines = [
        f"### The verdict study's grazing null case, {report['date']} (SYNTHETIC data)",
        "",
        f"- true k: {', '.join(f'{k} N/m at phi = {p}' for p, k in report['true_k_N_m'].items())}",
        "- true height of the grazing cell (delayed stutter, 12 Hz; oracle, flight rule): "
        + ", ".join(
            f"{v:.2f} mm at phi = {p}"
            for p, v in report["true_height_delayed_stutter_12hz_mm"].items()
        ),
        f"- baseline fit (depth only, diagnose's sampler, cap {sampler.max_steps} steps): "
        f"converged {report['converged']} in {wall:.0f} s",
        "",
        "| run | steps | tau_max | R-hat max | ESS min | converged | k: 5%, 50%, 95% [N/m] |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in report["runs"]:
        q = report["k_posterior_90"][r["run"].removeprefix("phi=")]
        lines.append(
            f"| {r['run']} | {r['n_steps']} | {r['tau_max']:.1f} | {r['rhat_max']:.3f} | "
            f"{r['ess_min']:.0f} | {r['converged']} | {q[0]:.0f}, {q[1]:.0f}, {q[2]:.0f} |"
        )
    lines += ["", f"machine: {report['machine']}"]
    text = "\n".join(lines) + "\n"
    (HERE / "results" / "graze_case.md").write_text(text)
    print(text, end="")


if __name__ == "__main__":
    main()
