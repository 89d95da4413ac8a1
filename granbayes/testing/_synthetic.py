"""SYNTHETIC jump tables for tests, made by the independent oracle.

The true heights come from :func:`granbayes.testing.simulate_height_scipy`, which shares no
numerical code with the compiled kernel that the fits use: a flaw of the kernel cannot be in
the data that test it. The design loop and the random draws are those of the public
generator :func:`granbayes.make_jumps` (which uses the kernel, for users' own
synthetic experiments), so a table differs from ``make_jumps``'s only by the difference of
the two implementations (below 1e-4 mm at converged settings, ``tests/test_testing.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence

import pandas as pd

from .._experiment import Experiment
from .._jump_tables import jump_table
from ..commands import COMMAND_NAMES
from ._effects import Effect
from ._oracle import simulate_height_scipy


def synthetic_jumps(
    truth: Mapping[str, float] | Callable[[float], Mapping[str, float]],
    sigma_mm: float | Callable[[float], float],
    *,
    seed: int,
    experiment: Experiment | None = None,
    phis: Sequence[float] = (0.612,),
    freqs_hz: Sequence[float] = (10.0,),
    commands: Sequence[str] = COMMAND_NAMES,
    trials: int = 3,
    label: str = "granbayes.testing.synthetic_jumps",
    effects: Effect | Iterable[Effect] | None = None,
    decimals: int | None = 3,
    settings_columns: bool = False,
    true_heights: bool = False,
) -> pd.DataFrame:
    """A SYNTHETIC jumps table: a known law simulated for every cell, plus seeded scatter.

    The true heights are the oracle's (:func:`granbayes.testing.simulate_height_scipy`, at
    its default converged tolerances), never the fitting kernel's. The rows and the random
    draws are those of :func:`granbayes.make_jumps` with the same arguments (loop
    order phi, frequency, command, trial; one ``numpy.random.Generator`` seeded with
    ``seed``), so a table is fixed by its arguments. Cost: the oracle's, about 40-110 ms per
    cell.

    Parameters
    ----------
    truth : mapping or callable
        The true force-law parameters [SI]: one mapping for every volume fraction, or
        ``truth(phi)`` -> mapping.
    sigma_mm : float or callable
        Trial-to-trial scatter [mm], constant or ``sigma_mm(phi)``.
    seed : int
        Seed of the scatter.
    experiment : Experiment, optional
        Robot and command settings (default ``Experiment()``); ``freq_hz`` is set per row.
    phis : sequence of float
        Volume fractions [-].
    freqs_hz : sequence of float
        Actuator frequencies [Hz].
    commands : sequence of str
        Jump commands.
    trials : int
        Jumps per cell.
    label : str
        Named in the ``source`` column (``"synthetic: <label> seed=<seed>"``).
    effects : Effect or iterable of Effect, optional
        Out-of-library physics of the oracle added to the law (e.g.
        :class:`~granbayes.testing.PauseStiffening`); default none.
    decimals : int or None
        ``height_mm`` rounded to this many decimals [mm]; ``None``: not rounded.
    settings_columns : bool
        Add the command settings of ``experiment`` (``amplitude_mm``, ``delay_ms``,
        ``settle_periods``) as columns, as a batch table has them.
    true_heights : bool
        Keep the noise-free ``true_height_mm`` column.

    Returns
    -------
    pandas.DataFrame
        ``phi, command, freq_hz, trial, height_mm, source`` (then ``true_height_mm`` and
        the settings columns, if asked for), one row per jump.

    Examples
    --------
    >>> from granbayes.testing import synthetic_jumps
    >>> t = synthetic_jumps(lambda phi: {"k": 4000.0 * phi / 0.612}, 3.0, seed=5,
    ...                     phis=(0.602, 0.622), commands=("single",), trials=2)
    >>> t[["phi", "command", "trial"]].values.tolist()
    [[0.602, 'single', 1], [0.602, 'single', 2], [0.622, 'single', 1], [0.622, 'single', 2]]
    """
    exp = experiment if experiment is not None else Experiment()
    law = truth if callable(truth) else (lambda _phi: truth)

    def oracle_height(command, phi, params, cell_exp):
        return simulate_height_scipy(command, phi, params, cell_exp, effects=effects)

    table = jump_table(
        oracle_height,
        law,
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
    if not true_heights:
        table = table.drop(columns="true_height_mm")
    if settings_columns:
        c = exp.command
        table = table.assign(
            amplitude_mm=c.amplitude_mm, delay_ms=c.delay_ms, settle_periods=c.settle_periods
        )
    return table
