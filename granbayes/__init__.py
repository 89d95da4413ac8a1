"""granbayes: what force does a granular bed exert on a robot that jumps off it?

The package follows the flow of data:

``experiment`` (folder, robot, settings) -> ``commands`` and ``forces`` (the model) ->
``simulator`` (batched, compiled) -> likelihood and priors -> sampler -> DataTree ->
criticism -> report.
"""

import importlib.metadata as _metadata

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

try:  # the version is written once, in pyproject.toml
    __version__ = _metadata.version("granbayes")
except _metadata.PackageNotFoundError:  # a source tree that is not installed
    __version__ = "0+unknown"

__all__ = [
    "COMMAND_NAMES",
    "PARAMETER_NAMES",
    "TERMS",
    "CommandProgram",
    "CommandSettings",
    "Experiment",
    "ForceLaw",
    "Heights",
    "InputError",
    "Robot",
    "Segment",
    "SolverOptions",
    "Status",
    "Trajectory",
    "__version__",
    "build_command",
    "load_batch_table",
    "load_experiment",
    "load_jumps",
    "simulate",
    "simulate_rows",
    "simulate_table",
    "simulate_trajectory",
]
