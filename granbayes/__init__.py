"""granbayes: the force a granular bed exerts on a robot that jumps off it.

The package follows the flow of data:

experiment folder (``_experiment``, ``_measurements``) -> ``commands`` and ``forces`` (the
model) -> ``_simulator`` (batched, compiled) -> ``_likelihood`` and ``_priors`` ->
``_sampler`` -> ``_fitting`` (DataTree) -> ``_saved`` (a fit read back) -> ``_prediction``
-> ``_criticism`` -> ``report``.

**The public surface** is what ``granbayes`` exports (``__all__``, the README's API
section) and the public modules of :data:`PUBLIC_MODULES`: the registries
(:mod:`granbayes.forces`, :mod:`granbayes.commands`, :mod:`granbayes.kinds`), the layers
on the DataTree (:mod:`granbayes.stats`, :mod:`granbayes.figures`, :mod:`granbayes.report`),
the analyses' computations (:mod:`granbayes.analysis`), the experiment that settles a tie
(:mod:`granbayes.design`), campaigns and the verdict study (:mod:`granbayes.campaign`,
:mod:`granbayes.calibration`) and the test kit (:mod:`granbayes.testing`). Modules whose
names start with an underscore are the implementation: their names may change without
notice. ``tests/test_public_api.py`` holds that ``analyses/`` uses nothing else.

Settings objects are named ``*Settings``: :class:`FitSettings`, :class:`SamplerSettings`,
:class:`SolverSettings`, :class:`DiagnoseSettings`, and
:class:`granbayes.campaign.ClusterSettings`; an argument or attribute that holds one is
called ``settings``. Deprecated, with a ``DeprecationWarning`` naming the new name: the
former names ``FitConfig``, ``SolverOptions`` and ``DiagnoseConfig`` of the same classes,
the keywords ``config=``/``options=`` (now ``settings=``) and ``backend=`` (now
``checkpoint=``), the attribute ``.config`` of a fit, and the former module paths of the
implementation (``granbayes.fitting`` for ``granbayes._fitting``, ``granbayes.maps`` for
``granbayes.analysis.maps``, ...; :data:`MOVED_MODULES`).
"""

import importlib.metadata as _metadata
from typing import TYPE_CHECKING

from ._deprecated import install_moved_modules as _install_moved_modules
from ._deprecated import warn_alias as _warn_alias
from ._errors import InputError
from ._experiment import Experiment, Robot, load_experiment
from ._measurements import (
    Measurements,
    load_batch_table,
    load_intrusions,
    load_jumps,
    load_trajectories,
)
from ._simulator import (
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
from .commands import (
    COMMAND_NAMES,
    COMMANDS,
    Command,
    CommandProgram,
    CommandSettings,
    Segment,
    build_command,
)
from .forces import PARAMETER_NAMES, TERMS, ForceLaw

if TYPE_CHECKING:
    from ._criticism import DiagnoseSettings, Diagnosis, diagnose
    from ._fitting import (
        CommandComparison,
        FitResult,
        FitSettings,
        compare_commands,
        data_hash,
        fit,
    )
    from ._prediction import Prediction, predict
    from ._priors import Prior, default_priors, load_priors
    from ._sampler import SamplerSettings
    from ._saved import SavedFit, load_fit
    from ._sbc import SBCResult, run_sbc
    from ._synthetic import REFERENCE_DATA, make_jumps, write_experiment
    from .kinds import load_measurements
    from .stats import residual_table

try:  # the version is written once, in pyproject.toml
    __version__ = _metadata.version("granbayes")
except _metadata.PackageNotFoundError:  # a source tree that is not installed
    __version__ = "0+unknown"

#: Public names imported on first use (module of each), to keep ``import granbayes`` light.
_LAZY = {
    "fit": "_fitting",
    "compare_commands": "_fitting",
    "CommandComparison": "_fitting",
    "FitSettings": "_fitting",
    "FitResult": "_fitting",
    "data_hash": "_fitting",
    "SamplerSettings": "_sampler",
    "load_fit": "_saved",
    "SavedFit": "_saved",
    "predict": "_prediction",
    "Prediction": "_prediction",
    "diagnose": "_criticism",
    "DiagnoseSettings": "_criticism",
    "Diagnosis": "_criticism",
    "residual_table": "stats",
    "load_measurements": "kinds",
    "Prior": "_priors",
    "default_priors": "_priors",
    "load_priors": "_priors",
    "run_sbc": "_sbc",
    "SBCResult": "_sbc",
    "REFERENCE_DATA": "_synthetic",
    "make_jumps": "_synthetic",
    "write_experiment": "_synthetic",
}


#: Deprecated aliases of renamed settings classes (old name -> new name): importable from
#: here and from their modules, with a DeprecationWarning; not in ``__all__``.
_DEPRECATED = {
    "FitConfig": "FitSettings",
    "DiagnoseConfig": "DiagnoseSettings",
    "SolverOptions": "SolverSettings",
}

#: The public modules besides ``granbayes`` itself (their ``__all__`` is their surface).
PUBLIC_MODULES = (
    "granbayes.analysis",
    "granbayes.analysis.maps",
    "granbayes.analysis.mechanics",
    "granbayes.analysis.optimal",
    "granbayes.calibration",
    "granbayes.campaign",
    "granbayes.commands",
    "granbayes.design",
    "granbayes.figures",
    "granbayes.forces",
    "granbayes.kinds",
    "granbayes.report",
    "granbayes.stats",
    "granbayes.testing",
)

#: Former module paths of the implementation (old -> new), importable with a
#: DeprecationWarning until they are removed.
MOVED_MODULES = {
    **{
        f"granbayes.{name}": f"granbayes._{name}"
        for name in (
            "cli",
            "criticism",
            "datatree",
            "demo",
            "errors",
            "experiment",
            "fitting",
            "likelihood",
            "prediction",
            "priors",
            "sampler",
            "saved",
            "sbc",
            "simulator",
            "synthetic",
        )
    },
    "granbayes.maps": "granbayes.analysis.maps",
    "granbayes.mechanics": "granbayes.analysis.mechanics",
    "granbayes.optimal": "granbayes.analysis.optimal",
    "granbayes.plots": "granbayes.figures",
}
_install_moved_modules(MOVED_MODULES)


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
    "MOVED_MODULES",
    "PUBLIC_MODULES",
    "REFERENCE_DATA",
    "SBCResult",
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
    "data_hash",
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
    "make_jumps",
    "load_priors",
    "predict",
    "run_sbc",
    "residual_table",
    "simulate",
    "simulate_frames",
    "simulate_frames_rows",
    "simulate_rows",
    "simulate_table",
    "simulate_trajectory",
    "write_experiment",
]
