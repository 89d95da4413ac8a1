"""The figures layer: pictures of simulations, fits, criticism and the analyses.

Every function takes simulation results, DataTrees or the tables the statistics layer
(:mod:`granbayes.stats`) computes, and returns a :class:`matplotlib.figure.Figure`; none
fits, samples or writes a file (the reports save them). Units are in every axis label.
Corner plots are drawn by ``corner``, trace, rank, LOO-PIT, prior-posterior and SBC plots
by ``arviz-plots`` (those come from ``pyplot``: close them once saved).

* Simulated jumps: :func:`plot_trajectory`, :func:`plot_jumps`, :func:`plot_hard_ground`.
* A fit: :func:`plot_predictive`, :func:`plot_corner`, :func:`plot_parameters_vs_phi`,
  :func:`plot_prior_posterior`, :func:`plot_loo_pit`, :func:`plot_trace`,
  :func:`plot_rank`, :func:`plot_sbc_ecdf`.
* Other kinds of measurement: :func:`plot_tracked_jumps` (trajectories over predictive
  bands, residuals against time), :func:`plot_intrusions` (force-depth curves per speed).
* Criticism: :func:`plot_residual_heatmap`.
* The analyses: :func:`plot_heights_vs_phi`, :func:`plot_misfit_maps`,
  :func:`plot_valleys`, :func:`plot_optimum_vs_frequency`, :func:`plot_delay_curves`,
  :func:`plot_optimum_vs_phi`, :func:`plot_vs_kappa`, :func:`plot_added_mass`,
  :func:`plot_coefficients_vs_phi`, and their shared :data:`COMMAND_COLORS`,
  :data:`COMMAND_MARKERS`, :func:`command_offsets`, :func:`panel_grid`.
* Labels: :func:`data_label` (the "SYNTHETIC data" label of every figure of synthetic
  data), :func:`source_label`, :func:`param_label`, :func:`param_unit`, and
  :func:`value_with_errors` (an estimate to the precision of its interval).
"""

from ._analyses import (
    COMMAND_COLORS,
    COMMAND_MARKERS,
    command_offsets,
    panel_grid,
    plot_added_mass,
    plot_coefficients_vs_phi,
    plot_delay_curves,
    plot_heights_vs_phi,
    plot_misfit_maps,
    plot_optimum_vs_frequency,
    plot_optimum_vs_phi,
    plot_valleys,
    plot_vs_kappa,
)
from ._criticism import plot_residual_heatmap
from ._fit import (
    plot_corner,
    plot_loo_pit,
    plot_parameters_vs_phi,
    plot_predictive,
    plot_prior_posterior,
    plot_rank,
    plot_sbc_ecdf,
    plot_trace,
)
from ._jumps import REGIME_COLORS, plot_hard_ground, plot_jumps, plot_trajectory
from ._kinds import plot_intrusions, plot_tracked_jumps
from ._style import data_label, param_label, param_unit, source_label, value_with_errors

__all__ = [
    "COMMAND_COLORS",
    "COMMAND_MARKERS",
    "REGIME_COLORS",
    "command_offsets",
    "data_label",
    "panel_grid",
    "param_label",
    "param_unit",
    "plot_intrusions",
    "plot_tracked_jumps",
    "plot_added_mass",
    "plot_coefficients_vs_phi",
    "plot_corner",
    "plot_delay_curves",
    "plot_hard_ground",
    "plot_heights_vs_phi",
    "plot_jumps",
    "plot_loo_pit",
    "plot_misfit_maps",
    "plot_optimum_vs_frequency",
    "plot_optimum_vs_phi",
    "plot_parameters_vs_phi",
    "plot_predictive",
    "plot_prior_posterior",
    "plot_rank",
    "plot_residual_heatmap",
    "plot_sbc_ecdf",
    "plot_trace",
    "plot_trajectory",
    "plot_valleys",
    "plot_vs_kappa",
    "source_label",
    "value_with_errors",
]
