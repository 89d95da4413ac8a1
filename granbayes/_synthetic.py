"""Seeded factories of SYNTHETIC jump-height data (for tests, benchmarks and examples).

Every row made here carries a ``source`` column ``"synthetic: <label> seed=<seed>"``, so
reports label the data as synthetic wherever they appear.
"""

from __future__ import annotations

import importlib.resources
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import pandas as pd

from ._deprecated import renamed_keyword
from ._experiment import Experiment
from ._jump_tables import jump_table
from ._simulator import SolverSettings, simulate
from .commands import COMMAND_NAMES

__all__ = ["REFERENCE_DATA", "make_jumps", "write_experiment"]

#: The shipped SYNTHETIC reference data set: an experiment folder installed with the package
#: (``granbayes/data/reference``; generator and seed: ``data/generate_reference.py`` in the
#: source repository; truth: ``TRUTH.md`` and ``truth.toml`` in the folder).
REFERENCE_DATA: Path = Path(str(importlib.resources.files("granbayes") / "data" / "reference"))


@renamed_keyword("options")
def make_jumps(
    truth: Callable[[float], Mapping[str, float]],
    sigma_mm: Callable[[float], float] | float,
    *,
    experiment: Experiment | None = None,
    phis: Sequence[float] = (0.592, 0.602, 0.612, 0.622, 0.632),
    freqs_hz: Sequence[float] = (8.0, 12.0),
    commands: Sequence[str] = COMMAND_NAMES,
    trials: int = 5,
    seed: int = 0,
    label: str = "granbayes.make_jumps",
    settings: SolverSettings | None = None,
    decimals: int | None = 3,
) -> pd.DataFrame:
    """Simulate the true law for every cell and add seeded Gaussian scatter.

    Parameters
    ----------
    truth : callable
        ``truth(phi)`` -> force-law parameters [SI] at volume fraction ``phi``.
    sigma_mm : callable or float
        Trial-to-trial scatter [mm], constant or per ``phi``.
    experiment : Experiment, optional
        Robot and command defaults (``freq_hz`` is set per row).
    phis, freqs_hz, commands : sequences
        The design.
    trials : int
        Jumps per cell.
    seed : int
        Seed of the ``numpy.random.Generator`` drawing the scatter (loop order: phi, freq,
        command, trial).
    label : str
        Generator named in the ``source`` column.
    settings : SolverSettings, optional
        Integrator settings (default: converged).
    decimals : int or None
        ``height_mm`` is rounded to this many decimals of a millimetre (3: micrometres, like
        a lab table); ``None`` keeps the unrounded sum of the true height and the scatter.

    Returns
    -------
    pandas.DataFrame
        ``phi, command, freq_hz, trial, height_mm, true_height_mm, source``.
    """
    exp = experiment or Experiment()
    opts = settings or SolverSettings.converged()

    def kernel_height(command, phi, params, cell_exp):
        return simulate(command, phi, params, experiment=cell_exp, settings=opts).height_mm[0]

    return jump_table(
        kernel_height,
        truth,
        sigma_mm,
        experiment=exp,
        phis=phis,
        freqs_hz=freqs_hz,
        commands=commands,
        trials=trials,
        seed=seed,
        label=label,
        decimals=decimals,
    )


def write_experiment(folder: Path, jumps: pd.DataFrame, experiment: Experiment) -> Path:
    """Write an experiment folder (``experiment.toml`` + ``jumps.csv``) for ``jumps``.

    Parameters
    ----------
    folder : Path
        Folder (created).
    jumps : pandas.DataFrame
        The jumps (``true_height_mm`` is dropped).
    experiment : Experiment
        Robot and command defaults.

    Returns
    -------
    Path
        The folder.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    r, c = experiment.robot, experiment.command
    lines = ["# SYNTHETIC data (granbayes.write_experiment)", "[robot]"]
    lines += [f"{k} = {float(v)!r}" for k, v in vars(r).items()]
    lines += ["", "[command]"] + [f"{k} = {float(v)!r}" for k, v in vars(c).items()]
    lines += ["", "[bed]", f"phi_c = {experiment.phi_c!r}", ""]
    (folder / "experiment.toml").write_text("\n".join(lines))
    jumps.drop(columns=["true_height_mm"], errors="ignore").to_csv(
        folder / "jumps.csv", index=False
    )
    return folder
