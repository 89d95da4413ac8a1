"""Posterior summaries shared by the analyses: intervals, joint draws, paired comparisons.

Small, general tools that the analysis scripts (``analyses/``) and the analysis modules
(:mod:`granbayes.analysis.maps`, :mod:`granbayes.analysis.optimal`,
:mod:`granbayes.analysis.mechanics`) build on:

* :func:`interval`, :func:`fmt_triple`, :func:`fmt_interval`: the median and the
  equal-tailed interval of a sample, and their text;
* :func:`posterior_draws`: joint posterior draws of named parameters at one volume
  fraction of a fit's DataTree (correlations kept); :func:`posterior_intervals`: their
  medians and intervals per volume fraction, as a table;
* :func:`cell_experiment`: the experiment with one data row's command settings applied;
* :func:`p_greater`: a paired probability over common posterior draws;
* :func:`correlation`: Pearson and Spearman correlation across cells, from the cells'
  medians and propagated draw by draw;
* :func:`cell_statistics`: mean, standard deviation and standard error of measured
  heights per cell; :func:`mean_discrepancy`: a measured cell mean against the posterior
  predictive of the mean of its jumps.

Heights are in mm; everything else is in the units of its input.
"""

from __future__ import annotations

from collections.abc import Mapping

import pandas as pd

from .._experiment import Experiment
from ..commands import SETTINGS as SETTING_COLUMNS

__all__ = [
    "cell_experiment",
]


def cell_experiment(experiment: Experiment, row: Mapping[str, object]) -> Experiment:
    """The experiment with the command settings of one data row (or cell) applied.

    Parameters
    ----------
    experiment : Experiment
    row : mapping
        May hold ``freq_hz`` [Hz], ``amplitude_mm`` [mm], ``delay_ms`` [ms],
        ``settle_periods`` [periods]; missing or NaN ones keep the experiment's value.

    Returns
    -------
    Experiment
    """
    return experiment.replace(
        **{k: float(row[k]) for k in SETTING_COLUMNS if k in row and pd.notna(row[k])}
    )
