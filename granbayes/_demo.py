"""``granbayes demo``: five jumps, the hard-ground sweep and a fit of the reference data.

The demo's work lives here, not in the command line: :func:`run_demo` simulates the five
commands with a representative (not measured) law, sweeps the actuator frequency on a
rigid floor, and fits depth + drag to the SYNTHETIC reference data set
(:data:`granbayes.REFERENCE_DATA`), writing figures and tables. It prints its
progress; ``granbayes demo --quiet`` silences it.
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ._experiment import Experiment, load_experiment
from ._files import atomic_path
from ._simulator import simulate_table, simulate_trajectory
from ._synthetic import REFERENCE_DATA
from .commands import COMMAND_NAMES
from .forces import PARAMETERS

if TYPE_CHECKING:  # matplotlib is imported where a figure is drawn: a faster start-up
    from matplotlib.figure import Figure

__all__ = [
    "DEMO_PARAMS",
    "DEMO_PHI",
    "HARD_GROUND_FREQS_HZ",
    "HARD_GROUND_PARAMS",
    "law_text",
    "run_demo",
]

#: Volume fraction of the demo bed: the critical packing of the founding thesis [-].
DEMO_PHI = 0.612

#: Force law of the demo: a representative depth + drag law for poppy seeds, *not* a
#: measurement. ``k`` [N/m] depth stiffness, ``c_d`` [kg/m] quadratic drag, ``r_unload``
#: [-] the default plastic bed of physics-model.md section 3.
DEMO_PARAMS: dict[str, float] = {"k": 3000.0, "c_d": 50.0, "r_unload": 20.0}

#: A rigid floor for the hard-ground sweep (physics-model.md section 6): very stiff
#: ``k`` [N/m] and a bed that keeps its crater (``r_unload`` [-]).
HARD_GROUND_PARAMS: dict[str, float] = {"k": 1e6, "r_unload": 50.0}

#: Actuator frequencies of the hard-ground sweep [Hz].
HARD_GROUND_FREQS_HZ: np.ndarray = np.arange(4.0, 30.0 + 0.5, 1.0)


def law_text(params: dict[str, float]) -> str:
    """A force law in words with units, e.g. ``"k = 3000 N/m, c_d = 50 kg/m"``.

    Parameters
    ----------
    params : dict of str to float
        Parameter values [SI].

    Returns
    -------
    str
    """
    units = {p.name: p.unit for p in PARAMETERS}
    parts = []
    for name, value in params.items():
        unit = units[name]
        shown = re.sub(r"e\+?(-?)0*(\d)", r"e\1\2", f"{value:g}")  # 1e+06 -> 1e6
        parts.append(f"{name} = {shown}" + ("" if unit == "-" else f" {unit}"))
    return ", ".join(parts)


def _write_csv(table: pd.DataFrame, path: Path) -> None:
    with atomic_path(path) as tmp:
        table.to_csv(tmp, index=False)


def _write_figure(fig: Figure, path: Path) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=150)


def _demo_jumps(out: Path, experiment: Experiment) -> None:
    """The five commands at ``DEMO_PHI`` with ``DEMO_PARAMS``: table, CSV and figure."""
    from .figures import plot_jumps

    trajs = {
        c: simulate_trajectory(c, DEMO_PHI, DEMO_PARAMS, experiment=experiment)
        for c in COMMAND_NAMES
    }
    table = pd.DataFrame({"command": list(COMMAND_NAMES), "phi": DEMO_PHI} | DEMO_PARAMS)
    heights = simulate_table(table, experiment)
    print(f"Five jumps of the default robot at phi = {DEMO_PHI:g}, {law_text(DEMO_PARAMS)}:")
    print(f"  {'command':<25} {'height [mm]':>11}  status")
    for row in heights.itertuples():
        print(f"  {row.command:<25} {row.height_mm:>11.2f}  {row.status}")
    _write_csv(heights, out / "heights.csv")
    robot = experiment.robot
    title = (
        f"The five jump commands on a granular bed (φ = {DEMO_PHI:g}; representative law "
        f"{law_text(DEMO_PARAMS)})\nrobot: M = {robot.m_upper:g} kg, "
        f"m_foot = {robot.m_foot:g} kg, k_spring = {robot.k_spring:g} N/m; actuator "
        f"A = {experiment.command.amplitude_mm:g} mm, f = {experiment.command.freq_hz:g} Hz"
    )
    _write_figure(plot_jumps(trajs, title), out / "jumps.png")


def _demo_hard_ground(out: Path, experiment: Experiment) -> None:
    """Single and stutter jump height against frequency on a rigid floor."""
    from .figures import plot_hard_ground

    freqs = HARD_GROUND_FREQS_HZ
    table = pd.DataFrame(
        {
            "command": np.repeat(["single", "stutter"], freqs.size),
            "phi": DEMO_PHI,
            "freq_hz": np.tile(freqs, 2),
        }
        | HARD_GROUND_PARAMS
    )
    result = simulate_table(table, experiment)
    single = result["height_mm"].to_numpy()[: freqs.size]
    stutter = result["height_mm"].to_numpy()[freqs.size :]
    f0 = experiment.robot.f0_hz
    print(
        f"Rigid floor ({law_text(HARD_GROUND_PARAMS)}), f0 = {f0:.2f} Hz: best single "
        f"{freqs[np.nanargmax(single)]:g} Hz ({np.nanmax(single):.1f} mm), best stutter "
        f"{freqs[np.nanargmax(stutter)]:g} Hz ({np.nanmax(stutter):.1f} mm)"
    )
    _write_csv(result, out / "hard_ground.csv")
    title = (
        "Rigid floor: jump height vs actuator frequency\n"
        f"(default robot, A = {experiment.command.amplitude_mm:g} mm; "
        f"{law_text(HARD_GROUND_PARAMS)})"
    )
    _write_figure(
        plot_hard_ground(freqs, single, stutter, f0, title=title), out / "hard_ground.png"
    )


def _demo_fit(out: Path, data: Path, seed: int) -> None:
    """Fit depth + drag per volume fraction to ``data`` and answer the uniqueness question."""
    from ._fitting import FitSettings, compare_commands, fit
    from ._measurements import load_jumps
    from .report import load_truth, write_fit_report

    experiment = load_experiment(data)
    table = load_jumps(data, experiment)
    truth_file = data / "truth.toml"
    truth = load_truth(truth_file) if truth_file.exists() else None
    config = FitSettings(terms=("depth", "drag"))
    print(f"Fitting {config.terms} per volume fraction to {len(table)} jumps in {data} ...")
    out.mkdir(parents=True, exist_ok=True)
    source = os.path.relpath(data) if Path(data).is_absolute() else str(data)
    result = fit(experiment, table, config, seed=seed, data_source=source)
    print("One force law for all five commands? (PSIS-LOO per volume fraction) ...")
    uniqueness = compare_commands(experiment, table, result, seed=seed).table
    write_fit_report(result.datatree, out, truth=truth, uniqueness=uniqueness)
    for w in result.warnings:
        print(f"granbayes: warning: {w}", file=sys.stderr)
    print((out / "summary.md").read_text())


def run_demo(out: Path, data: Path | None = REFERENCE_DATA, seed: int = 0) -> None:
    """Run the demo: simulate, fit, print summaries and write figures and tables to ``out``.

    Writes ``heights.csv`` (the five jumps; a valid ``simulate --batch`` input),
    ``jumps.png`` (:func:`granbayes.figures.plot_jumps`), ``hard_ground.csv`` and
    ``hard_ground.png`` (:func:`granbayes.figures.plot_hard_ground`), and, if ``data`` is
    given, the Bayesian fit of depth + drag to it in ``out/fit`` (posterior, summary,
    corner plots, predictive check, the uniqueness table).

    Parameters
    ----------
    out : Path
        Output folder (created if needed).
    data : Path, optional
        Experiment folder to fit (default: the shipped synthetic reference data set).
    seed : int
        Seed of the fit.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out {out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    experiment = Experiment()
    _demo_jumps(out, experiment)
    _demo_hard_ground(out, experiment)
    written = ["heights.csv", "jumps.png", "hard_ground.csv", "hard_ground.png"]
    if data is not None:
        _demo_fit(out / "fit", Path(data), seed)
        written.append("fit/")
    print(f"Wrote {', '.join(written)} to {out}")
