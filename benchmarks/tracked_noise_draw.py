"""The frame noise the added-mass set's generator drew, jump by jump.

``benchmarks/tracked_likelihood_ratio.py --free-noise`` finds the SYNTHETIC added-mass
set's own frames at phi = 0.612 far from the generator's noise model (the likelihood rises
25.8 over the truth's noise, which none of 100 fresh draws does) while their force law is
not. This script reruns the generator (``data/generate_lab_reference.py``, the same seed:
the same bytes as the committed set) keeping the noise-free frames the lab writes beside
the measured ones, and reports per tracked jump and coordinate the noise it drew: its
standard deviation and lag-1 autocorrelation (the design's: 0.25 mm and 0.5; the lag-1
estimate of about 200 frames has a standard error of about 0.06).

Writes ``benchmarks/results/tracked_noise_draw.md``.

Usage: ``python benchmarks/tracked_noise_draw.py``
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from granbayes import load_experiment
from granbayes.report import markdown_table
from granbayes.testing import LabDesign, synthetic_lab_data

HERE = Path(__file__).resolve().parent
OUT = HERE / "results" / "tracked_noise_draw.md"


def main() -> None:
    """Rerun the generator and tabulate the frame noise it drew."""
    sys.path.insert(0, str(HERE.parent / "data"))
    import generate_lab_reference as generator

    ds = generator.data_sets()["added_mass"]
    design = LabDesign(**{**vars(generator.BASE_DESIGN), "sigma_mm": ds.lab_sigma_mm})
    data = synthetic_lab_data(
        ds.law,
        seed=ds.seed,
        design=design,
        experiment=load_experiment(generator.REFERENCE),
        label=generator.LABEL,
    )
    frames = data.trajectories[data.trajectories["command"].isin(ds.tracked_commands)]
    rows = []
    for jump, g in frames.groupby("jump", sort=False):
        for column in ("x_foot_mm", "x_rod_mm"):
            e = (g[column] - g["true_" + column]).to_numpy()
            rows.append(
                [
                    f"{g['phi'].iloc[0]:g}",
                    jump,
                    g["command"].iloc[0],
                    column,
                    len(e),
                    f"{e.std():.3f}",
                    f"{np.corrcoef(e[:-1], e[1:])[0, 1]:.2f}",
                ]
            )
    columns = ["phi", "jump", "command", "coordinate", "frames", "noise sd [mm]", "lag-1 corr"]
    text = [
        "# The frame noise the added-mass set's generator drew",
        "",
        "**SYNTHETIC data** (`data/generate_lab_reference.py`, `added_mass`, seed "
        f"{ds.seed}): measured minus noise-free frames per tracked jump; the design's noise "
        f"is AR(1) with sd {design.frame_sd_mm} mm and lag-1 correlation {design.frame_rho}. "
        "Written by `benchmarks/tracked_noise_draw.py`.",
        "",
        markdown_table(pd.DataFrame(rows, columns=columns)),
        "",
    ]
    OUT.write_text("\n".join(text))
    print("\n".join(text))


if __name__ == "__main__":
    main()
