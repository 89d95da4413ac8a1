"""granbayes: what force does a granular bed exert on a robot that jumps off it?

The package follows the flow of data:

``experiment`` (folder, robot, settings) -> ``commands`` and ``forces`` (the model) ->
``simulator`` (batched, compiled) -> likelihood and priors -> sampler -> ``fitting``
(DataTree) -> ``saved`` (a fit read back) -> ``prediction`` -> ``criticism`` -> report.

The public API is what ``granbayes`` exports (``__all__``): reading experiments,
simulating, fitting (:func:`fit`, :class:`FitConfig`, :class:`FitResult`,
:class:`SamplerSettings`), reading a fit back (:func:`load_fit`, :class:`SavedFit`),
predicting (:func:`predict`, :class:`Prediction`) and criticising (:func:`diagnose`,
:class:`DiagnoseConfig`, :class:`Diagnosis`, :func:`residual_table`). The inference names are
imported on first use, so ``import granbayes`` stays as fast as the simulator needs.

The analyses of the thesis's questions (``analyses/``) are built on submodules imported
explicitly: :mod:`granbayes.analysis` (posterior summaries), :mod:`granbayes.maps` (misfit
maps over a (k, c_d) grid), :mod:`granbayes.optimal` (settings search under a posterior),
:mod:`granbayes.mechanics` (added-mass impulse, actuator power, rigid floor) and the
figures of :mod:`granbayes.plots`.
"""

import importlib.metadata as _metadata
from typing import TYPE_CHECKING

from .commands import CommandProgram, Segment, build_command
from .errors import InputError
from .experiment import (
    COMMAND_NAMES,
    CommandSettings,
    Experiment,
    Robot,
    load_batch_table,
    load_experiment,
    load_jumps,
)
from .forces import PARAMETER_NAMES, TERMS, ForceLaw
from .simulator import (
    Heights,
    SolverOptions,
    Status,
    Trajectory,
    simulate,
    simulate_rows,
    simulate_table,
    simulate_trajectory,
)

if TYPE_CHECKING:
    from .criticism import DiagnoseConfig, Diagnosis, diagnose, residual_table
    from .fitting import FitConfig, FitResult, compare_commands, fit
    from .prediction import Prediction, predict
    from .priors import Prior, default_priors, load_priors
    from .sampler import SamplerSettings
    from .saved import SavedFit, load_fit

try:  # the version is written once, in pyproject.toml
    __version__ = _metadata.version("granbayes")
except _metadata.PackageNotFoundError:  # a source tree that is not installed
    __version__ = "0+unknown"

#: Public names imported on first use (module of each), to keep ``import granbayes`` light.
_LAZY = {
    "fit": "fitting",
    "compare_commands": "fitting",
    "FitConfig": "fitting",
    "FitResult": "fitting",
    "SamplerSettings": "sampler",
    "load_fit": "saved",
    "SavedFit": "saved",
    "predict": "prediction",
    "Prediction": "prediction",
    "diagnose": "criticism",
    "DiagnoseConfig": "criticism",
    "Diagnosis": "criticism",
    "residual_table": "criticism",
    "Prior": "priors",
    "default_priors": "priors",
    "load_priors": "priors",
}


def __getattr__(name: str) -> object:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'granbayes' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "COMMAND_NAMES",
    "PARAMETER_NAMES",
    "TERMS",
    "CommandProgram",
    "CommandSettings",
    "DiagnoseConfig",
    "Diagnosis",
    "Experiment",
    "FitConfig",
    "FitResult",
    "ForceLaw",
    "Heights",
    "InputError",
    "Prediction",
    "Prior",
    "Robot",
    "SamplerSettings",
    "SavedFit",
    "Segment",
    "SolverOptions",
    "Status",
    "Trajectory",
    "__version__",
    "build_command",
    "compare_commands",
    "default_priors",
    "diagnose",
    "fit",
    "load_batch_table",
    "load_experiment",
    "load_fit",
    "load_jumps",
    "load_priors",
    "predict",
    "residual_table",
    "simulate",
    "simulate_rows",
    "simulate_table",
    "simulate_trajectory",
]
