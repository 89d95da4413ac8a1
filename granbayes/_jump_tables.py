"""The design loop of a SYNTHETIC jumps table, shared by the public generator and the test kit.

:func:`granbayes.make_jumps` (heights from the compiled kernel, for users' own
synthetic experiments) and :func:`granbayes.testing.synthetic_jumps` (heights from the
independent oracle, for the tests) differ only in who computes the true height; this
module holds what they share: the loop order, the seeded scatter and the columns. It
imports no simulator, so the test kit stays free of the kernel.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from ._experiment import Experiment

#: ``true_height(command, phi, params, experiment) -> height [mm]``.
HeightFunction = Callable[[str, float, Mapping[str, float], Experiment], float]


def jump_table(
    true_height: HeightFunction,
    truth: Callable[[float], Mapping[str, float]],
    sigma_mm: Callable[[float], float] | float,
    *,
    experiment: Experiment,
    phis: Sequence[float],
    freqs_hz: Sequence[float],
    commands: Sequence[str],
    trials: int,
    seed: int,
    label: str,
    decimals: int | None,
) -> pd.DataFrame:
    """Every cell's true height plus seeded Gaussian scatter, one row per jump.

    Loop order phi, frequency, command, trial; one ``numpy.random.Generator`` seeded with
    ``seed`` draws ``trials`` values per cell, so a table is fixed by its arguments.
    Columns ``phi, command, freq_hz, trial, height_mm, true_height_mm, source``
    (``true_height_mm`` rounded to 0.1 um; ``height_mm`` to ``decimals`` decimals of a
    millimetre, unrounded if ``None``).
    """
    rng = np.random.default_rng(seed)
    sigma = sigma_mm if callable(sigma_mm) else (lambda _phi: float(sigma_mm))
    rows = []
    for phi in phis:
        for freq in freqs_hz:
            cell_exp = experiment.replace(freq_hz=float(freq))
            for command in commands:
                true_h = float(true_height(command, phi, truth(phi), cell_exp))
                noise = rng.normal(0.0, sigma(phi), size=trials)
                for trial in range(trials):
                    height = true_h + noise[trial]
                    rows.append(
                        {
                            "phi": phi,
                            "command": command,
                            "freq_hz": freq,
                            "trial": trial + 1,
                            "height_mm": height if decimals is None else round(height, decimals),
                            "true_height_mm": round(true_h, 4),
                            "source": f"synthetic: {label} seed={seed}",
                        }
                    )
    return pd.DataFrame(rows)
