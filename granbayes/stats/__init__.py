"""The statistics layer: numbers computed from fits' DataTrees.

Every function here takes DataTrees (or arrays and tables drawn from them) and returns
numbers and tables; none samples, simulates a law or fits. The figures layer
(:mod:`granbayes.figures`) draws what these compute, and reports write both. ArviZ's
statistics (``arviz-stats``: PSIS-LOO, LOO-PIT, R-hat, ESS, uniformity tests) are called
from here.

* Intervals: :data:`CI_PROB` (90%, equal-tailed: passed explicitly everywhere, ArviZ's
  default being 89%), :func:`eti_probs`, :func:`interval`, :func:`fmt_triple`,
  :func:`fmt_interval`.
* Residual cells of jump heights (one command at one volume fraction and setting,
  :data:`CELL_KEYS`): :func:`residual_table`, :func:`misfit_threshold`, :func:`lack_of_fit`,
  :func:`describe_cell`, :func:`rmse_mm`, :func:`cell_statistics`,
  :func:`mean_discrepancy`, :func:`observed_jumps`; of the other kinds of measurement
  (phases of tracked jumps, depth bins of intrusion curves): :func:`trajectory_cells`,
  :func:`intrusion_cells`, :func:`predictive_cells`.
* Predictive accuracy: :func:`loo` (every unit of every kind of measurement:
  :func:`unit_log_likelihood`, :func:`unit_phi_name`, :func:`unit_kinds`),
  :func:`elpd_difference` (stratified by kind where there are several), :func:`compare`,
  :func:`cell_loo`, :func:`loo_pit`, :func:`pit_uniformity`, and the fallback for
  unreliable PSIS, :func:`moment_match` (Paananen et al. 2021, batched over observations).
* Summaries: :func:`summary_table`, :func:`run_diagnostics`, :func:`by_ensemble`,
  :func:`identifiability_table`, :func:`posterior_draws`, :func:`posterior_intervals`,
  :func:`p_greater`, :func:`correlation`.
* Simulation-based calibration: :func:`summarize_ranks`, :func:`normalised_ranks`,
  :func:`sbc_uniformity`, :func:`sbc_table`.
"""

from ._cells import (
    CELL_KEYS,
    cell_keys,
    cell_statistics,
    describe_cell,
    lack_of_fit,
    mean_discrepancy,
    misfit_threshold,
    observed_jumps,
    residual_table,
    rmse_mm,
)
from ._intervals import CI_PROB, eti_probs, fmt_interval, fmt_triple, interval
from ._kind_cells import intrusion_cells, predictive_cells, trajectory_cells
from ._loo import (
    cell_loo,
    compare,
    elpd_difference,
    loo,
    loo_pit,
    pit_uniformity,
    unit_kinds,
    unit_log_likelihood,
    unit_phi_name,
)
from ._moment_matching import MomentMatch, moment_match, moment_match_search
from ._sbc import COVERAGE_LEVELS, normalised_ranks, sbc_table, sbc_uniformity, summarize_ranks
from ._summaries import (
    IDENTIFIABILITY_LEVELS,
    by_ensemble,
    correlation,
    identifiability_table,
    p_greater,
    pearson_rows,
    posterior_draws,
    posterior_intervals,
    run_diagnostics,
    spearman_rows,
    summary_table,
)

__all__ = [
    "CELL_KEYS",
    "CI_PROB",
    "COVERAGE_LEVELS",
    "IDENTIFIABILITY_LEVELS",
    "MomentMatch",
    "by_ensemble",
    "cell_keys",
    "cell_loo",
    "cell_statistics",
    "compare",
    "correlation",
    "describe_cell",
    "elpd_difference",
    "eti_probs",
    "fmt_interval",
    "fmt_triple",
    "identifiability_table",
    "interval",
    "intrusion_cells",
    "loo",
    "loo_pit",
    "mean_discrepancy",
    "misfit_threshold",
    "moment_match",
    "moment_match_search",
    "normalised_ranks",
    "observed_jumps",
    "p_greater",
    "pearson_rows",
    "pit_uniformity",
    "posterior_draws",
    "posterior_intervals",
    "predictive_cells",
    "lack_of_fit",
    "residual_table",
    "rmse_mm",
    "run_diagnostics",
    "sbc_table",
    "sbc_uniformity",
    "spearman_rows",
    "summarize_ranks",
    "trajectory_cells",
    "unit_kinds",
    "unit_log_likelihood",
    "unit_phi_name",
    "summary_table",
]
