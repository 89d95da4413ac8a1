"""Test kit: the independent scipy oracle, its out-of-library physics, and data factories.

This module is public so that tests, benchmarks and other implementations of the model can
check themselves against one reference (like ``arviz_base.testing``). The package imports it
in two places only: the verdict study (``granbayes.calibration``) makes its data sets with
the oracle, and the simulation-based calibration of a joint fit (``granbayes sbc`` on
several kinds of measurement) its replicates. The oracle is the source of the data that
test the fitting code: the compiled kernel never makes its own test data
(``tests/test_layers.py`` checks who imports what). It holds:

* the oracle, a ``scipy.integrate.solve_ivp`` implementation of ``docs/physics-model.md``
  that shares no numerical code with the compiled integrator (``granbayes._kernel``):
  :func:`simulate_height_scipy` (the jump height, section 5),
  :func:`simulate_trajectory_scipy` (foot height and rod displacement at any frame times,
  from the dense output, with the height of the same simulation: an
  :class:`OracleTrajectory`) and :func:`intrusion_force_scipy` (the force-depth curve of
  a constant-speed intrusion, section 5b). Its cost per jump is in the docstring of
  ``granbayes.testing._oracle`` ("What it costs");
* out-of-library physics, ground forces the force-term library cannot express, for
  verdict studies, passed as ``effects=(...)`` to every oracle function
  (``effects=None`` is the library model, unchanged): :class:`DepthDependentDrag`,
  :class:`JanssenSaturation`, :class:`PauseStiffening`, :class:`RateStiffening` (force
  laws, references and the energy argument in ``granbayes.testing._effects``);
* :func:`synthetic_lab_data`, a SYNTHETIC lab campaign made by the oracle only (jump
  heights with scatter, filmed jumps with AR(1) frame noise and clock offsets, intrusion
  tests with force noise, a robot off its nominal values, beds whose true phi scatters,
  hidden effects), designed by a :class:`LabDesign` (:data:`SMALL_LAB`: a small lab of
  every kind) and returned as :class:`LabData`;
  :func:`write_lab_experiment` writes it as an experiment folder;
* :func:`replicate_measurements`, an experiment's own design (its jumps, tracked jumps
  and intrusion tests) with every value simulated by the oracle from a given truth and
  the noise of the observation models, clock offsets from the likelihood's prior: the
  replicates of simulation-based calibration of a joint fit (``granbayes sbc``);
* :func:`fake_fit`, a seeded fit's DataTree with every group and attribute of a real one
  (``granbayes.fit``), made without a sampler or a simulator (a linear surrogate of the
  heights), for tests of statistics, figures and reports (like ``arviz_base.testing``);
* :func:`synthetic_jumps`, SYNTHETIC jump tables for tests: a known force law simulated
  by the oracle for every cell of a small design plus seeded Gaussian scatter, with the
  rows and draws of the public generator :func:`granbayes.make_jumps` (which
  uses the kernel, for users' own synthetic experiments) and what tests need: a constant
  law given as a mapping, oracle effects, the command-setting columns of a batch table,
  and no ``true_height_mm`` column unless asked for. Write a table as an
  experiment folder with :func:`granbayes.write_experiment`.

The oracle follows ``docs/physics-model.md`` directly, with Python right-hand sides and
solve_ivp's own event machinery. It shares nothing with the compiled integrator except the
command waveforms (:func:`granbayes.commands.build_command`), the robot/settings
containers (:mod:`granbayes._experiment`) and the parameter bounds and "off" values of the
force-term registry (:mod:`granbayes.forces`); its only numerical dependency is scipy.

It also holds the parameter box of the energy-identity property test
(:func:`energy_test_box`), derived from the registry so that a new term is tested
without another edit.

Examples
--------
>>> from granbayes.testing import simulate_height_scipy, synthetic_jumps
>>> round(simulate_height_scipy("single", 0.612, {"k": 3000.0, "r_unload": 1.0}), 1)
67.7
>>> synthetic_jumps({"k": 3000.0}, 2.0, seed=1, commands=("single",)).shape
(3, 6)
>>> from granbayes.testing import intrusion_force_scipy, RateStiffening
>>> law = {"k": 3000.0, "c_d": 20.0}
>>> intrusion_force_scipy(0.612, law, [10.0], 100.0).round(3).tolist()
[30.2]
>>> faster = RateStiffening(0.5)
>>> intrusion_force_scipy(0.612, law, [10.0], 100.0, effects=(faster,)).round(3).tolist()
[46.679]
"""

from __future__ import annotations

from .._sampler import SamplerSettings
from ..forces import Parameter
from ._effects import (
    DepthDependentDrag,
    Effect,
    JanssenSaturation,
    PauseStiffening,
    RateStiffening,
)
from ._fake import fake_fit
from ._lab import SMALL_LAB, LabData, LabDesign, synthetic_lab_data, write_lab_experiment
from ._oracle import (
    COMPACTION_LENGTH,
    PARAMETER_DEFAULTS,
    TRACK_AFTER_END,
    OracleTrajectory,
    intrusion_force_scipy,
    simulate_height_scipy,
    simulate_trajectory_scipy,
)
from ._replicate import replicate_measurements
from ._synthetic import synthetic_jumps

__all__ = [
    "COMPACTION_LENGTH",
    "DepthDependentDrag",
    "Effect",
    "ENERGY_BOX_WIDENING",
    "JanssenSaturation",
    "LabData",
    "LabDesign",
    "OracleTrajectory",
    "PARAMETER_DEFAULTS",
    "PauseStiffening",
    "QUICK_SAMPLER",
    "RateStiffening",
    "SMALL_LAB",
    "TRACK_AFTER_END",
    "energy_test_box",
    "fake_fit",
    "intrusion_force_scipy",
    "replicate_measurements",
    "simulate_height_scipy",
    "simulate_trajectory_scipy",
    "synthetic_jumps",
    "synthetic_lab_data",
    "write_lab_experiment",
]

#: <= 1.05, ESS >= 50, at most 600 steps). Not for results anyone quotes.
QUICK_SAMPLER = SamplerSettings(
    n_walkers=8,
    n_ensembles=2,
    check_every=50,
    max_steps=600,
    n_draws=60,
    min_ess=50,
    max_rhat=1.05,
)

#: How far the energy-test box reaches beyond the realistic range of a dimensional
#: coefficient: 5 times its upper end.
ENERGY_BOX_WIDENING = 5.0


def energy_test_box(parameter: Parameter) -> tuple[float, float]:
    """The box of a parameter over which the energy identity is tested [parameter's unit].

    The registry's hard bounds (``k`` up to 1e9 N/m, ``k2`` up to 1e12 N/m^2, ``r_unload``
    up to 1e6) are limits of validity, not beds a robot jumps on. The box is the union of
    what a fit can ever propose (the support of the parameter's default prior) and its
    realistic range, widened to :data:`ENERGY_BOX_WIDENING` times the upper end for a
    dimensional coefficient. A dimensionless ratio (unit ``"-"``) stops at its prior's
    upper bound, which is its physical scale. For the library: ``k`` from 200 N/m (the
    prior's floor: the settled robot sinks 64 mm) to 5e4 N/m, ``c_d`` to 500 kg/m, ``k2``
    to 1e6 N/m^2, ``b`` to 250 N s/m; ``kappa`` to 3 full cones, ``c_comp`` to 3 (a
    compacted bed 4 times stiffer), ``r_unload`` to 200 (a plastic bed). The lower ends are
    0, and ``r_unload = 1``, the elastic bed where the identity is tightest.

    Parameters
    ----------
    parameter : Parameter
        A registered force-term parameter (its ``typical`` range, ``unit`` and ``prior``
        are used).

    Returns
    -------
    tuple of float
        ``(lower, upper)`` in the parameter's unit.

    Examples
    --------
    >>> from granbayes.forces import parameter
    >>> energy_test_box(parameter("k")), energy_test_box(parameter("r_unload"))
    ((200.0, 50000.0), (1.0, 200.0))
    """
    lower = float(min(parameter.typical[0], parameter.prior.lower))
    upper = float(parameter.prior.upper)
    if parameter.unit != "-":
        upper = max(upper, ENERGY_BOX_WIDENING * float(parameter.typical[1]))
    return lower, upper
