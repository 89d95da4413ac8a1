"""Test kit: an independent scipy oracle of the model and one seeded synthetic factory.

The oracle is a ``scipy.integrate.solve_ivp`` implementation of the jumping-robot model;
the factory makes the SYNTHETIC jump tables that the tests use.

This module is public so that tests, benchmarks and other implementations of the model can
check themselves against one reference (like ``arviz_base.testing``). It is not imported by
``granbayes`` itself. It holds:

* :func:`simulate_height_scipy`, the oracle (described below);
* :func:`fake_fit`, a seeded fit's DataTree with every group and attribute of a real one
  (``granbayes.fit``), made without a sampler or a simulator (a linear surrogate of the
  heights), for tests of statistics, figures and reports (like ``arviz_base.testing``);
* :func:`synthetic_jumps`, SYNTHETIC jump tables for tests: a known force law simulated
  for every cell of a small design plus seeded Gaussian scatter. It is a thin layer over
  the public generator :func:`granbayes.synthetic.make_jumps` (same draws, same rows), which
  adds what tests need: a constant law given as a mapping, the command-setting columns of
  a batch table, and no ``true_height_mm`` column unless asked for. Write a table as an
  experiment folder with :func:`granbayes.synthetic.write_experiment`.

:func:`simulate_height_scipy` follows ``docs/physics-model.md`` directly, with a Python
right-hand side and solve_ivp's own event machinery, and it is written for clarity rather
than speed. It shares nothing with the compiled integrator (``granbayes._kernel``) except
the command waveforms (:func:`granbayes.commands.build_command`), the robot/settings
containers (:mod:`granbayes.experiment`) and the parameter bounds and "off" values of the
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
"""

from __future__ import annotations

from ..forces import Parameter
from ..sampler import SamplerSettings
from ._fake import fake_fit
from ._oracle import COMPACTION_LENGTH, PARAMETER_DEFAULTS, simulate_height_scipy
from ._synthetic import synthetic_jumps

__all__ = [
    "COMPACTION_LENGTH",
    "fake_fit",
    "ENERGY_BOX_WIDENING",
    "PARAMETER_DEFAULTS",
    "QUICK_SAMPLER",
    "energy_test_box",
    "simulate_height_scipy",
    "synthetic_jumps",
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
