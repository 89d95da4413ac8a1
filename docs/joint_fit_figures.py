"""Regenerate ``docs/figures/trajectories.png`` and ``intrusions.png`` (SYNTHETIC data).

The README's figures of a joint fit of jump heights, tracked jumps and intrusion curves:
the small lab ``granbayes.testing.SMALL_LAB`` (2 volume fractions, the single jump,
3 trials, one filmed per cell at 1000 frames/s with 0.2 mm correlated tracking noise,
intrusions at 1 and 200 mm/s), simulated by the independent oracle
(``granbayes.testing.synthetic_lab_data``, seed 11; truth k = 3000 N/m, c_d = 20 kg/m),
fitted as a user would (``granbayes fit DIR --terms depth,drag --seed 2``), and the two
figures of the report copied here. It prints what the README quotes of that fit: each run's
steps, R-hat and ESS, the 90% intervals of the law and noise parameters, and the fit's
wall time (the whole ``granbayes fit``, report included, in this process).

Usage: ``python docs/joint_fit_figures.py`` (about half a minute on 2 cores).
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

from granbayes._cli import main
from granbayes.testing import SMALL_LAB, synthetic_lab_data, write_lab_experiment

HERE = Path(__file__).resolve().parent / "figures"

#: ``tests/test_kinds.py``'s ``TRUTH`` (its design is ``SMALL_LAB``).
LAW = {"k": 3000.0, "c_d": 20.0}
SEED_DATA, SEED_FIT = 11, 2


def make(out: Path = HERE) -> list[Path]:
    """Simulate the lab, fit it and copy the two figures into ``out``."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_lab_experiment(
            Path(tmp) / "exp", synthetic_lab_data(LAW, seed=SEED_DATA, design=SMALL_LAB)
        )
        report = Path(tmp) / "fit"
        argv = ["fit", str(folder), "--terms", "depth,drag", "--seed", str(SEED_FIT)]
        start = time.perf_counter()
        code = main([*argv, "--out", str(report), "--quiet"])
        wall_s = time.perf_counter() - start
        if code != 0:
            raise SystemExit(f"granbayes fit exited with {code}")
        runs = pd.read_csv(report / "diagnostics.csv")
        print(runs[["run", "n_steps", "rhat_max", "ess_min", "converged"]].to_string(index=False))
        summary = pd.read_csv(report / "summary.csv").set_index("parameter")
        for name, row in summary.iterrows():
            if not str(name).startswith(("k[", "c_d[", "frame_", "force_sd")):
                continue
            print(f"{name}: {row['mean']:.5g} [{row['eti90_lb']:.5g}, {row['eti90_ub']:.5g}]")
        print(f"granbayes fit (report included): {wall_s:.1f} s wall")
        return [
            Path(shutil.copy(report / name, out / name))
            for name in ("trajectories.png", "intrusions.png")
        ]


if __name__ == "__main__":
    for path in make():
        print(path)
    sys.exit(0)
