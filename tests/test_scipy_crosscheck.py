"""Cross-check of the compiled simulator against an independent solve_ivp implementation.

``benchmarks/scipy_model.py`` integrates the same model with ``scipy.integrate.solve_ivp``
(a Python right-hand side and solve_ivp's event functions for the regime changes). The two
share no integration code, so agreement to 0.05 mm checks the model logic of both (regimes,
bed memory, added mass, start states, height window) as well as the integrator accuracy.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

import granbayes
from granbayes.experiment import COMMAND_NAMES, Experiment
from granbayes.forces import typical_ranges
from granbayes.simulator import SolverOptions

SCIPY_MODEL = Path(__file__).resolve().parents[1] / "benchmarks" / "scipy_model.py"

#: Required agreement of ``granbayes.simulate`` (default settings) with solve_ivp [mm].
TOLERANCE_MM = 0.05


def _load_scipy_model() -> ModuleType:
    name = "granbayes_benchmarks_scipy_model"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, SCIPY_MODEL)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look the module up while it executes
    spec.loader.exec_module(module)
    return module


scipy_model = _load_scipy_model()

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
        command, phi, params, experiment=experiment, options=SolverOptions.converged()
    )
    assert default.ok.all() and converged.ok.all()
    reference = scipy_model.simulate_height_scipy(command, phi, params, experiment)
    return float(default.height_mm[0]), float(converged.height_mm[0]), reference


@pytest.mark.parametrize(("command", "phi", "params", "changes"), FAST_CASES + MORE_CASES)
def test_simulate_matches_solve_ivp(
    command: str, phi: float, params: dict[str, float], changes: dict[str, float]
) -> None:
    default, converged, reference = _heights(command, phi, params, changes)
    assert abs(default - reference) <= TOLERANCE_MM
    # tight settings on both sides: the two implementations solve the same equations
    assert abs(converged - reference) <= 1e-3


def test_cases_cover_commands_and_terms() -> None:
    cases = [p.values for p in FAST_CASES + MORE_CASES]
    assert {c[0] for c in cases} == set(COMMAND_NAMES)
    used = {name for c in cases for name in c[2]}
    assert used >= {"k", "c_d", "kappa", "k2", "b", "r_unload", "c_comp"}


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
