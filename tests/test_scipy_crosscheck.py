"""Cross-check of the compiled simulator against the independent solve_ivp oracle.

:func:`granbayes.testing.simulate_height_scipy` integrates the same model with
``scipy.integrate.solve_ivp`` (a Python right-hand side and solve_ivp's event functions for
the regime changes). The two share no integration code, so agreement to 0.05 mm checks the
model logic of both (regimes, bed memory, compaction, added mass, start states, height
window) as well as the integrator accuracy.
"""

from __future__ import annotations

import doctest

import numpy as np
import pytest

import granbayes
import granbayes.testing
from granbayes._experiment import Experiment
from granbayes._simulator import SolverSettings, Status
from granbayes.commands import COMMAND_NAMES
from granbayes.forces import PARAMETER_NAMES, PARAMETERS, typical_ranges
from granbayes.testing import simulate_height_scipy

#: Required agreement of ``granbayes.simulate`` (default settings) with solve_ivp [mm].
TOLERANCE_MM = 0.05
#: Required agreement with converged settings on both sides [mm] (observed <= 3e-8 mm).
CONVERGED_TOLERANCE_MM = 1e-4

# (command, phi, params, experiment changes): all five commands and every force term
FAST_CASES = [
    pytest.param("single", 0.612, {"k": 3000.0, "c_d": 50.0, "b": 20.0}, {}, id="single-drag"),
    pytest.param(
        "delayed_stutter_preload",
        0.600,
        {"k": 5000.0, "kappa": 1.0, "r_unload": 10.0, "k2": 1e5},
        {},
        id="dsp-added-mass",
    ),
]
MORE_CASES = [
    pytest.param("preload", 0.625, {"k": 8000.0, "k2": 1.5e5, "r_unload": 40.0}, {}, id="preload"),
    pytest.param(
        "stutter",
        0.595,
        {"k": 2000.0, "c_d": 80.0, "kappa": 1.8, "r_unload": 5.0},
        {},
        id="stutter-added-mass",
    ),
    pytest.param(
        "delayed_stutter",
        0.612,
        {"k": 4000.0, "b": 40.0, "r_unload": 1.0},
        {},
        id="delayed-stutter-elastic-bed",
    ),
    pytest.param(
        "delayed_stutter",
        0.605,
        {"k": 3000.0, "kappa": 1.0, "r_unload": 5.0, "c_comp": 0.7},
        {},
        id="delayed-stutter-compaction",
    ),
    pytest.param(
        "preload",
        0.610,
        {"k": 1000.0, "r_unload": 1.0},
        {"freq_hz": 6.0, "amplitude_mm": 30.0, "m_foot": 0.3, "c_spring": 0.0},
        id="preload-other-robot",
    ),
]


def _heights(
    command: str, phi: float, params: dict[str, float], changes: dict[str, float]
) -> tuple[float, float, float]:
    experiment = Experiment().replace(**changes)
    default = granbayes.simulate(command, phi, params, experiment=experiment)
    converged = granbayes.simulate(
        command, phi, params, experiment=experiment, settings=SolverSettings.converged()
    )
    assert default.ok.all() and converged.ok.all()
    reference = simulate_height_scipy(command, phi, params, experiment)
    return float(default.height_mm[0]), float(converged.height_mm[0]), reference


@pytest.mark.parametrize(("command", "phi", "params", "changes"), FAST_CASES + MORE_CASES)
def test_simulate_matches_solve_ivp(
    command: str, phi: float, params: dict[str, float], changes: dict[str, float]
) -> None:
    default, converged, reference = _heights(command, phi, params, changes)
    assert abs(default - reference) <= TOLERANCE_MM
    # tight settings on both sides: the two implementations solve the same equations
    assert abs(converged - reference) <= CONVERGED_TOLERANCE_MM


def test_cases_cover_commands_and_terms() -> None:
    cases = [p.values for p in FAST_CASES + MORE_CASES]
    assert {c[0] for c in cases} == set(COMMAND_NAMES)
    used = {name for c in cases for name in c[2]}
    assert used >= set(PARAMETER_NAMES)


# ----------------------------------------------------------------------------------------
# the compaction term: re-anchoring at every episode end, settled placement compacting
COMPACTION_CASES = [
    pytest.param(
        "single",
        0.600,
        {"k": 3000.0, "c_comp": 2.0, "r_unload": 10.0, "c_d": 30.0},
        id="single-drag",
    ),
    pytest.param(
        "preload",
        0.600,
        {"k": 1500.0, "c_comp": 1.0, "k2": 1e5, "r_unload": 3.0},
        id="preload-stiffening",
    ),
    pytest.param("stutter", 0.590, {"k": 3000.0, "c_comp": 0.7, "r_unload": 1.5}, id="stutter"),
    pytest.param(
        "delayed_stutter",
        0.600,
        {"k": 2000.0, "c_comp": 3.0, "kappa": 1.0, "r_unload": 20.0, "b": 20.0},
        id="delayed_stutter-added_mass-viscous",
    ),
    pytest.param(
        "delayed_stutter_preload",
        0.620,
        {"k": 5000.0, "c_comp": 0.5, "k2": 2e5, "r_unload": 1.0},
        id="delayed_stutter_preload-elastic-stiffening",
    ),
]


@pytest.mark.parametrize(("command", "phi", "params"), COMPACTION_CASES)
def test_compaction_matches_solve_ivp(command: str, phi: float, params: dict[str, float]) -> None:
    """Kernel and oracle agree on compaction jumps: 0.05 mm at default settings, 1e-4 mm converged.

    Both re-anchor the loading curve at every episode end with m = 1 + c_comp (1 -
    exp(-z_c / l_c)) and compact the bed under the settled (preload) start; a difference in
    either rule would shift the heights by millimetres. Observed: default within 2e-3 mm,
    converged within 3e-8 mm of the oracle.
    """
    default, converged, reference = _heights(command, phi, params, {})
    assert abs(default - reference) <= TOLERANCE_MM, (default, reference)
    assert abs(converged - reference) <= CONVERGED_TOLERANCE_MM, (converged, reference)
    # the term matters in every case: without it the height differs by far more
    without = simulate_height_scipy(command, phi, {**params, "c_comp": 0.0})
    assert abs(without - reference) > 100 * CONVERGED_TOLERANCE_MM


def test_compaction_cases_cover_every_command() -> None:
    cases = [p.values for p in COMPACTION_CASES]
    assert {c[0] for c in cases} == set(COMMAND_NAMES)
    assert all(c[2]["c_comp"] > 0.0 for c in cases)


# ----------------------------------------------------------------------------------------
# the oracle itself
def test_oracle_docstring_examples() -> None:
    """The examples in the granbayes.testing docstring run and print what they claim."""
    assert doctest.testmod(granbayes.testing).failed == 0


def test_oracle_implements_every_registered_parameter() -> None:
    """A term added to the registry must have its physics in the oracle too.

    The oracle lists the parameters it implements; their defaults are the registry's.
    """
    assert set(granbayes.testing.PARAMETER_DEFAULTS) | {"k"} == set(PARAMETER_NAMES)
    for p in PARAMETERS:
        if p.absent is not None:
            assert granbayes.testing.PARAMETER_DEFAULTS[p.name] == p.absent, p.name
    assert granbayes.testing.COMPACTION_LENGTH == granbayes._kernel.COMPACTION_LENGTH


@pytest.mark.parametrize(
    ("params", "error", "piece"),
    [
        ({"k": 3000.0, "r_unload": 0.5}, ValueError, "r_unload must be >= 1"),
        ({"k": 3000.0, "c_comp": -0.1}, ValueError, "c_comp must be >= 0"),
        ({"k": -1.0}, ValueError, "k must be > 0"),
        ({"c_d": 1.0}, ValueError, "'k' is required"),
        ({"k": 3000.0, "dilation": 1.0}, KeyError, "dilation"),
    ],
)
def test_oracle_refuses_what_the_kernel_refuses(
    params: dict[str, float], error: type[Exception], piece: str
) -> None:
    """Parameters the kernel answers with BAD_INPUT make the oracle raise, saying why."""
    with pytest.raises(error, match=piece):
        simulate_height_scipy("single", 0.6, params)
    if error is ValueError and "k" in params:
        assert granbayes.simulate("single", 0.6, params).status[0] == Status.BAD_INPUT


@pytest.mark.slow
def test_random_jumps_match_solve_ivp() -> None:
    """150 jumps drawn over the realistic parameter ranges, all commands."""
    rng = np.random.default_rng(20240611)
    ranges = typical_ranges()
    worst = 0.0
    for i in range(150):
        command = COMMAND_NAMES[i % len(COMMAND_NAMES)]
        params = {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in ranges.items()}
        phi = float(rng.uniform(0.592, 0.632))
        default, converged, reference = _heights(command, phi, params, {})
        assert abs(converged - reference) <= 1e-3, (command, phi, params)
        worst = max(worst, abs(default - reference))
    assert worst <= TOLERANCE_MM
