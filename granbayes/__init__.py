"""granbayes: the force a granular bed exerts on a robot that jumps off it.

The package follows the flow of data:

``experiment`` (folder, robot, settings) -> ``commands`` and ``forces`` (the model) ->
``simulator`` (batched, compiled) -> likelihood and priors -> sampler -> ``fitting``
(DataTree) -> ``saved`` (a fit read back) -> ``prediction`` -> ``criticism`` -> report.

The public API is what ``granbayes`` exports (``__all__``): reading experiments,
simulating, fitting (:func:`fit`, :class:`FitSettings`, :class:`FitResult`,
:class:`SamplerSettings`), reading a fit back (:func:`load_fit`, :class:`SavedFit`),
predicting (:func:`predict`, :class:`Prediction`) and criticising (:func:`diagnose`,
:class:`DiagnoseSettings`, :class:`Diagnosis`, :func:`residual_table`). The inference names are
imported on first use, so ``import granbayes`` stays as fast as the simulator needs.

Settings objects are named ``*Settings``: :class:`FitSettings`, :class:`SamplerSettings`,
:class:`SolverSettings`, :class:`DiagnoseSettings`. Their former names ``FitConfig``,
``SolverOptions`` and ``DiagnoseConfig`` are deprecated aliases of the same classes:
still importable (from ``granbayes`` and from their modules), with a
``DeprecationWarning``.

The analyses of the thesis's questions (``analyses/``) are built on submodules imported
explicitly: :mod:`granbayes.analysis` (posterior summaries), :mod:`granbayes.maps` (misfit
maps over a (k, c_d) grid), :mod:`granbayes.optimal` (settings search under a posterior),
:mod:`granbayes.mechanics` (added-mass impulse, actuator power, rigid floor) and the
figures of :mod:`granbayes.plots`.
"""

import importlib.metadata as _metadata
from typing import TYPE_CHECKING

from ._deprecated import warn_alias as _warn_alias
from ._measurements import (
    Measurements,
    load_batch_table,
    load_intrusions,
    load_jumps,
    load_trajectories,
)
from .commands import (
    COMMAND_NAMES,
    COMMANDS,
    Command,
    CommandProgram,
    CommandSettings,
    Segment,
    build_command,
)
from .errors import InputError
from .experiment import Experiment, Robot, load_experiment
from .forces import PARAMETER_NAMES, TERMS, ForceLaw
from .simulator import (
    Heights,
    SolverSettings,
    Status,
    TrackedHeights,
    TrackedJump,
    Trajectory,
    intrusion_force,
    intrusion_force_rows,
    simulate,
    simulate_frames,
    simulate_frames_rows,
    simulate_rows,
    simulate_table,
    simulate_trajectory,
)

if TYPE_CHECKING:
    from .criticism import DiagnoseSettings, Diagnosis, diagnose
    from .fitting import CommandComparison, FitResult, FitSettings, compare_commands, fit
    from .kinds import load_measurements
    from .prediction import Prediction, predict
    from .priors import Prior, default_priors, load_priors
    from .sampler import SamplerSettings
    from .saved import SavedFit, load_fit
    from .stats import residual_table

try:  # the version is written once, in pyproject.toml
    __version__ = _metadata.version("granbayes")
except _metadata.PackageNotFoundError:  # a source tree that is not installed
    __version__ = "0+unknown"

#: Public names imported on first use (module of each), to keep ``import granbayes`` light.
_LAZY = {
    "fit": "fitting",
    "compare_commands": "fitting",
    "CommandComparison": "fitting",
    "FitSettings": "fitting",
    "FitResult": "fitting",
    "SamplerSettings": "sampler",
    "load_fit": "saved",
    "SavedFit": "saved",
    "predict": "prediction",
    "Prediction": "prediction",
    "diagnose": "criticism",
    "DiagnoseSettings": "criticism",
    "Diagnosis": "criticism",
    "residual_table": "stats",
    "load_measurements": "kinds",
    "Prior": "priors",
    "default_priors": "priors",
    "load_priors": "priors",
}


#: Deprecated aliases of renamed settings classes (old name -> new name): importable from
#: here and from their modules, with a DeprecationWarning; not in ``__all__``.
_DEPRECATED = {
    "FitConfig": "FitSettings",
    "DiagnoseConfig": "DiagnoseSettings",
    "SolverOptions": "SolverSettings",
}


def __getattr__(name: str) -> object:
    if name in _DEPRECATED:
        new = _DEPRECATED[name]
        _warn_alias(__name__, name, new)
        return globals()[new] if new in globals() else _lazy(new)
    return _lazy(name)


def _lazy(name: str) -> object:
    """Import a public name of :data:`_LAZY` on first use."""
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
    "COMMANDS",
    "COMMAND_NAMES",
    "Command",
    "PARAMETER_NAMES",
    "TERMS",
    "CommandComparison",
    "CommandProgram",
    "CommandSettings",
    "DiagnoseSettings",
    "Diagnosis",
    "Experiment",
    "FitSettings",
    "FitResult",
    "ForceLaw",
    "Heights",
    "InputError",
    "Measurements",
    "Prediction",
    "Prior",
    "Robot",
    "SamplerSettings",
    "SavedFit",
    "Segment",
    "SolverSettings",
    "Status",
    "TrackedHeights",
    "TrackedJump",
    "Trajectory",
    "__version__",
    "build_command",
    "compare_commands",
    "default_priors",
    "diagnose",
    "fit",
    "intrusion_force",
    "intrusion_force_rows",
    "load_batch_table",
    "load_experiment",
    "load_fit",
    "load_intrusions",
    "load_jumps",
    "load_measurements",
    "load_trajectories",
    "load_priors",
    "predict",
    "residual_table",
    "simulate",
    "simulate_frames",
    "simulate_frames_rows",
    "simulate_rows",
    "simulate_table",
    "simulate_trajectory",
]
