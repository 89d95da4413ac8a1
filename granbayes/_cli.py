"""The ``granbayes`` command line (shared/data-format.md, "Command line").

Subcommands
-----------
``granbayes simulate``
    One jump (``--command``, ``--phi``, ``--param NAME=VALUE``) or a batch table
    (``--batch IN.csv --out OUT.csv``).
``granbayes fit``, ``granbayes diagnose``, ``granbayes sbc``
    Bayesian fit, model criticism and simulation-based calibration of an experiment.
``granbayes predict``
    Predictive heights at new settings from a saved fit (``posterior.nc``).
``granbayes report``
    A fit's report re-rendered from its ``posterior.nc``.
``granbayes priors``
    The default priors as TOML (``--priors FILE`` reads it back).
``granbayes demo``
    The five jumps of the default robot and the hard-ground frequency sweep, with figures.

Exit codes
----------
0
    Success.
2
    Bad input: a command-line usage error or a problem with a user's file or value. One
    line ``granbayes: error: <message>`` is printed to stderr (naming the file, row and
    column where there is one) and nothing is written.
3
    The simulation ran but at least one jump did not finish (status ``failed:...``, height
    NaN). Everything requested is still printed and written.
4
    ``fit`` or ``diagnose``: a sampler run did not converge (``granbayes._sampler``: the
    autocorrelation, cross-ensemble R-hat and ESS criteria). Everything is written, with
    the warnings; ``--allow-unconverged`` turns this into exit code 0.
5
    A campaign (``granbayes sbc``) finished but at least one of its tasks failed; the
    error is in ``OUT/tasks.csv`` and everything else is written.

Adding a subcommand
-------------------
Write ``_add_<name>_arguments(parser)`` and ``_run_<name>(args) -> int`` and append a
:class:`Subcommand` to :data:`SUBCOMMANDS`. ``run`` raises :class:`~granbayes.InputError`
(or :class:`UsageError`) for bad input; :func:`main` turns it into the one-line message
and exit code 2.

Length: about 1,300 lines of argument definitions, validation messages and exit codes
for eight subcommands; it computes nothing of its own.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import difflib
import io
import json
import math
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import numpy as np
import pandas as pd

from . import __version__
from ._demo import (
    DEMO_PARAMS,
    DEMO_PHI,
    HARD_GROUND_FREQS_HZ,
    HARD_GROUND_PARAMS,
    law_text,
    run_demo,
)
from ._errors import InputError
from ._experiment import Experiment, load_experiment
from ._files import atomic_path, staged_folder
from ._measurements import _load_batch
from ._simulator import Status, simulate, simulate_table, simulate_trajectory
from ._synthetic import REFERENCE_DATA
from .commands import COMMAND_NAMES
from .forces import PARAMETER_NAMES, PARAMETERS, TERMS, parameter_term

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "DEMO_PARAMS",
    "DEMO_PHI",
    "EXIT_FAILED_JUMP",
    "EXIT_FAILED_TASK",
    "EXIT_INPUT",
    "EXIT_OK",
    "EXIT_UNCONVERGED",
    "HARD_GROUND_FREQS_HZ",
    "HARD_GROUND_PARAMS",
    "SUBCOMMANDS",
    "Subcommand",
    "UsageError",
    "atomic_path",
    "build_parser",
    "main",
    "parse_params",
    "run_demo",
]

#: Exit code of a successful run.
EXIT_OK = 0
#: Exit code of a fit or diagnosis whose sampler did not converge (results still written).
EXIT_UNCONVERGED = 4
#: Exit code of bad input (usage, files, values); nothing is written.
EXIT_INPUT = 2
#: Exit code when a jump did not finish (status ``failed:...``); outputs are still written.
EXIT_FAILED_JUMP = 3
#: Exit code when a campaign task failed (recorded in ``OUT/tasks.csv``); outputs written.
EXIT_FAILED_TASK = 5


class UsageError(ValueError):
    """A bad command-line argument; the message names the argument."""


class _Parser(argparse.ArgumentParser):
    """Argument parser whose errors are one line and exit code 2 (no usage dump)."""

    def error(self, message: str) -> NoReturn:
        hint = f" (see '{self.prog} --help')"
        self.exit(EXIT_INPUT, f"granbayes: error: {message}{hint}\n")


@dataclass(frozen=True)
class Subcommand:
    """One ``granbayes`` subcommand.

    Parameters
    ----------
    name : str
        The word typed after ``granbayes``.
    help : str
        One line for ``granbayes --help``.
    add_arguments : callable
        Adds the subcommand's options to its parser.
    run : callable
        Runs it with the parsed arguments and returns the exit code.
    description : str
        Longer text for ``granbayes NAME --help`` (default: ``help``).
    """

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    description: str = ""


# ----------------------------------------------------------------------------------------
# Helpers: validation and safe writing
# ----------------------------------------------------------------------------------------


def _suggest(word: str, options: Sequence[str]) -> str:
    close = difflib.get_close_matches(word, list(options), n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _check_command(name: str) -> str:
    if name not in COMMAND_NAMES:
        raise UsageError(
            f"--command {name}: unknown command{_suggest(name, COMMAND_NAMES)}; "
            f"valid commands: {', '.join(COMMAND_NAMES)}"
        )
    return name


def _check_phi(text: str) -> float:
    try:
        phi = float(text)
    except ValueError:
        raise UsageError(f"--phi {text}: expected a number") from None
    if not (math.isfinite(phi) and 0.0 < phi < 1.0):
        raise UsageError(f"--phi {text}: must be a volume fraction in the open interval (0, 1)")
    return phi


def parse_params(items: Sequence[str]) -> dict[str, float]:
    """Parse and validate ``--param NAME=VALUE`` arguments.

    Parameters
    ----------
    items : sequence of str
        The ``NAME=VALUE`` strings, in command-line order.

    Returns
    -------
    dict of str to float
        Parameter name to value [SI], in command-line order.

    Raises
    ------
    UsageError
        Naming the offending argument: malformed, unknown name, repeated name, not a
        number, outside the parameter's bounds (``Parameter.check``), or a required
        parameter (``k``, the depth term) missing.
    """
    by_name = {p.name: p for p in PARAMETERS}
    params: dict[str, float] = {}
    for item in items:
        name, sep, text = (part.strip() for part in item.partition("="))
        if not sep or not name or not text:
            raise UsageError(f"--param {item}: expected NAME=VALUE, e.g. --param k=3000")
        if name not in by_name:
            raise UsageError(
                f"--param {item}: unknown force parameter '{name}'"
                f"{_suggest(name, PARAMETER_NAMES)}; expected one of "
                + ", ".join(f"{p.name} [{p.unit}] ({parameter_term(p.name)})" for p in PARAMETERS)
            )
        if name in params:
            raise UsageError(f"--param {item}: {name} is given more than once")
        try:
            value = float(text)
        except ValueError:
            raise UsageError(f"--param {item}: {name} must be a number, got '{text}'") from None
        problem = by_name[name].check(value)
        if problem:
            raise UsageError(f"--param {item}: {problem}")
        params[name] = value
    for term in TERMS.values():
        for p in term.parameters:
            if p.absent is None and p.name not in params:
                raise UsageError(
                    f"--param {p.name}=VALUE is required: the {term.name} term "
                    f"({p.description}, {p.name} [{p.unit}]) is part of every force law"
                )
    return params


def _check_target(path: Path, option: str) -> Path:
    """Check before any computation that ``path`` can be written as a file."""
    if path.is_dir():
        raise UsageError(f"{option} {path}: is a folder, expected a file name")
    if not path.parent.is_dir():
        raise UsageError(f"{option} {path}: folder {path.parent} does not exist")
    return path


def _write_csv(table: pd.DataFrame, path: Path) -> None:
    with atomic_path(path) as tmp:
        table.to_csv(tmp, index=False)


def _csv_numbers(values: np.ndarray) -> list[str]:
    """Floats as CSV cells, as ``DataFrame.to_csv`` writes them.

    Parameters
    ----------
    values : numpy.ndarray
        float64 values.

    Returns
    -------
    list of str
        The shortest text that reads back as the same float (``repr``); NaN empty.
    """
    text = list(map(repr, values.tolist()))
    missing = np.isnan(values)
    if not missing.any():
        return text
    return np.where(missing, "", np.array(text, dtype=object)).tolist()


def _write_figure(fig: Figure, path: Path) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=150)


def _json_number(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _load_experiment(path: str | None) -> Experiment:
    return Experiment() if path is None else load_experiment(path)


# ----------------------------------------------------------------------------------------
# granbayes simulate
# ----------------------------------------------------------------------------------------


def _add_simulate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--experiment",
        metavar="DIR|FILE.toml",
        help="experiment folder or experiment.toml with the robot and command settings "
        "(default: the representative robot of the physics model)",
    )
    one = parser.add_argument_group("one jump")
    one.add_argument("--command", metavar="NAME", help=f"one of {', '.join(COMMAND_NAMES)}")
    one.add_argument("--phi", metavar="PHI", help="volume fraction of the bed, in (0, 1)")
    units = ", ".join(f"{p.name} [{p.unit}]" for p in PARAMETERS)
    required = " and ".join(p.name for p in PARAMETERS if p.absent is None)
    required += " is" if required.count(" and ") == 0 else " are"
    one.add_argument(
        "--param",
        metavar="NAME=VALUE",
        action="append",
        default=[],
        help=f"force-term parameter, repeatable; {required} required. Parameters: {units}",
    )
    settings = parser.add_argument_group(
        "command settings (override the experiment's; in --batch mode, the defaults of rows "
        "that do not give them)"
    )
    for flag, metavar, text in _SETTING_FLAGS:
        settings.add_argument(flag, metavar=metavar, type=str, help=text)
    one.add_argument("--json", action="store_true", help="print one JSON object")
    one.add_argument(
        "--trajectory", metavar="OUT.csv", type=Path, help="write the jump's time series"
    )
    one.add_argument(
        "--plot", metavar="OUT.png", type=Path, help="write a figure of the trajectory"
    )
    batch = parser.add_argument_group("batch of jumps")
    batch.add_argument(
        "--batch",
        metavar="IN.csv",
        type=Path,
        help="table with columns command, phi, optional force parameters and per-row "
        "robot/command overrides; one jump per row",
    )
    batch.add_argument(
        "--out",
        metavar="OUT.csv",
        type=Path,
        help="batch output: the input plus height_mm and status ('-': standard output)",
    )
    batch.add_argument(
        "--threads", metavar="N", type=int, help="threads for the batch (default: all)"
    )


#: Command-setting flags of ``simulate`` and ``predict``: flag, metavar, help.
_SETTING_FLAGS = (
    ("--freq-hz", "HZ", "actuator frequency [Hz], > 0"),
    ("--amplitude-mm", "MM", "actuator amplitude A [mm] (half the stroke), > 0"),
    ("--delay-ms", "MS", "hold of the delayed stutter [ms], >= 0"),
    ("--settle-periods", "N", "hold of the delayed stutter preload [actuator periods], >= 0"),
)


def _setting_values(args: argparse.Namespace, lists: bool = False) -> dict[str, list[float]]:
    """The command settings given as flags (``--freq-hz`` ...), checked: name -> values.

    With ``lists``, each flag takes a comma-separated list of values.
    """
    out: dict[str, list[float]] = {}
    for flag, _, _ in _SETTING_FLAGS:
        name = flag[2:].replace("-", "_")
        text = getattr(args, name)
        if text is None:
            continue
        items = [t.strip() for t in text.split(",")] if lists else [text.strip()]
        values = []
        for item in items:
            try:
                value = float(item)
            except ValueError:
                raise UsageError(f"{flag} {text}: expected a number, got '{item}'") from None
            zero_ok = name in ("delay_ms", "settle_periods")
            if not math.isfinite(value) or value < 0 or (value == 0 and not zero_ok):
                raise UsageError(f"{flag} {text}: must be {'>= 0' if zero_ok else '> 0'}")
            values.append(value)
        out[name] = values
    return out


def _run_simulate(args: argparse.Namespace) -> int:
    if args.batch is not None:
        return _simulate_batch(args)
    return _simulate_one(args)


def _simulate_experiment(args: argparse.Namespace) -> Experiment:
    """The experiment with the command-setting flags applied."""
    settings = {k: v[0] for k, v in _setting_values(args).items()}
    return _load_experiment(args.experiment).replace(**settings)


def _simulate_one(args: argparse.Namespace) -> int:
    given = [o for o in ("out", "threads") if getattr(args, o) is not None]
    if given:
        raise UsageError(f"--{given[0]} is only used with --batch")
    if args.command is None or args.phi is None:
        missing = "--command" if args.command is None else "--phi"
        raise UsageError(f"{missing} is required (or give --batch IN.csv --out OUT.csv)")
    command = _check_command(args.command)
    phi = _check_phi(args.phi)
    params = parse_params(args.param)
    _setting_values(args)
    if args.trajectory is not None:
        _check_target(args.trajectory, "--trajectory")
    if args.plot is not None:
        _check_target(args.plot, "--plot")
    experiment = _simulate_experiment(args)

    result = simulate(command, phi, params, experiment=experiment)
    height = float(result.height_mm[0])
    status = Status(int(result.status[0]))
    if args.trajectory is not None or args.plot is not None:
        traj = simulate_trajectory(command, phi, params, experiment=experiment)
        if args.trajectory is not None:
            _write_csv(traj.data, args.trajectory)
        if args.plot is not None:
            from .figures import plot_trajectory

            shown = f"height {height:.1f} mm" if math.isfinite(height) else "no height"
            title = (
                f"{command.replace('_', ' ')} jump at φ = {phi:g}: {shown} ({status.label})\n"
                f"{law_text(params)}"
            )
            _write_figure(plot_trajectory(traj, title=title), args.plot)

    if args.json:
        record = {
            "command": command,
            "phi": phi,
            "height_mm": _json_number(height),
            "status": status.label,
            "params": params,
            # every parameter of the library as simulated (absent terms at their default)
            "effective_params": {p.name: params.get(p.name, p.absent) for p in PARAMETERS},
            "robot": dataclasses.asdict(experiment.robot),
            "command_settings": dataclasses.asdict(experiment.command),
            "phi_c": experiment.phi_c,
            "experiment": experiment.source,
            "n_steps": int(result.n_steps[0]),
            "trajectory": None if args.trajectory is None else str(args.trajectory),
            "plot": None if args.plot is None else str(args.plot),
            "granbayes_version": __version__,
        }
        print(json.dumps(record, allow_nan=False))
    else:
        shown = f"{height:.2f} mm" if math.isfinite(height) else "none"
        print(f"{command} at phi={phi:g}: height {shown} ({status.label})")
    return EXIT_OK if status == Status.OK else EXIT_FAILED_JUMP


def _simulate_batch(args: argparse.Namespace) -> int:
    single = ("command", "phi", "trajectory", "plot")
    given = [o for o in single if getattr(args, o) is not None]
    given += ["param"] if args.param else []
    given += ["json"] if args.json else []
    if given:
        raise UsageError(f"--{given[0]} cannot be used with --batch")
    if args.out is None:
        raise UsageError("--batch needs --out OUT.csv (or --out - for standard output)")
    if args.threads is not None and args.threads < 1:
        raise UsageError(f"--threads {args.threads}: must be >= 1")
    to_stdout = str(args.out) == "-"
    if not to_stdout:
        _check_target(args.out, "--out")
    shown = "the output" if to_stdout else str(args.out)
    _setting_values(args)
    experiment = _simulate_experiment(args)
    table, cells = _load_batch(args.batch)
    if "height_mm" in table.columns:
        print(
            f"granbayes: note: {args.batch} already has a height_mm column; "
            f"{shown} gets the simulated heights in it",
            file=sys.stderr,
        )
    out = simulate_table(table, experiment, n_threads=args.threads)
    # The input as read (each number as the file spells it) plus the results, built in bulk.
    results = {
        "height_mm": _csv_numbers(out["height_mm"].to_numpy()),
        "status": out["status"].tolist(),
    }
    if to_stdout:
        sys.stdout.write(cells.to_text(results))
        sys.stdout.flush()
    else:
        text = cells.to_text(results, line_end=os.linesep)
        with atomic_path(args.out) as tmp, open(tmp, "w", encoding="utf-8", newline="") as f:
            f.write(text)
    failed = int((out["status"] != Status.OK.label).sum())
    if failed:
        print(
            f"granbayes: warning: {failed} of {len(out)} jumps did not finish "
            f"(see the status column of {shown})",
            file=sys.stderr,
        )
        return EXIT_FAILED_JUMP
    return EXIT_OK


# ----------------------------------------------------------------------------------------
# granbayes demo
# ----------------------------------------------------------------------------------------


def _add_demo_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        metavar="DIR",
        type=Path,
        default=Path("demo-output"),
        help="folder for the figures and tables (created; default: demo-output)",
    )
    parser.add_argument(
        "--data",
        type=Path,
        default=REFERENCE_DATA,
        help="experiment folder to fit (default: the synthetic reference data set)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the fit (default 0)")
    parser.add_argument("--no-fit", action="store_true", help="only the simulations")
    parser.add_argument("--quiet", action="store_true", help="print nothing (files only)")


def _run_demo(args: argparse.Namespace) -> int:
    data = None if args.no_fit else args.data
    if data is not None and not Path(data).is_dir():
        raise UsageError(f"--data {data}: no such experiment folder")
    quiet = contextlib.redirect_stdout(io.StringIO()) if args.quiet else contextlib.nullcontext()
    if args.out.exists() and not args.out.is_dir():
        raise UsageError(f"--out {args.out}: exists and is not a folder")
    with quiet:
        run_demo(args.out, data, args.seed)
    return EXIT_OK


# ----------------------------------------------------------------------------------------
# granbayes fit
# ----------------------------------------------------------------------------------------


def _add_inference_arguments(
    parser: argparse.ArgumentParser,
    max_steps: int,
    threads_help: str = "numba threads (default: all cores)",
    pool: bool = True,
) -> None:
    """Arguments shared by ``fit``, ``diagnose`` and ``sbc`` (same names everywhere).

    ``pool``: whether ``--calibration pool`` is offered (not by ``diagnose``, whose fits
    are per volume fraction).
    """
    parser.add_argument("data", metavar="DIR", type=Path, help="experiment folder")
    parser.add_argument(
        "--out",
        metavar="OUT",
        type=Path,
        required=True,
        help="output folder (replaced only when the run succeeds)",
    )
    parser.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    parser.add_argument("--priors", type=Path, help="TOML file of prior overrides")
    parser.add_argument(
        "--walkers",
        type=int,
        default=8,
        help="emcee walkers per ensemble (default 8; raised to 4 x dimensions if fewer)",
    )
    parser.add_argument(
        "--ensembles",
        type=int,
        default=4,
        help="independent ensembles per run, which must agree (default 4)",
    )
    parser.add_argument(
        "--max-steps", type=int, default=max_steps, help=f"step cap (default {max_steps})"
    )
    parser.add_argument(
        "--start",
        choices=("auto", "search", "laplace"),
        default="auto",
        help="where each ensemble's walkers start: auto (the default) and laplace climb to "
        "the posterior mode and draw them from its Laplace approximation; search, a ball "
        "about the best point of a random search (cheaper, but slower to converge on narrow "
        "posteriors such as those of tracked jumps)",
    )
    parser.add_argument("--threads", type=int, help=threads_help)
    pooled = (
        "; pool: one value for every volume fraction also in per_phi mode (one sampler run "
        "of every volume fraction's law)"
        if pool
        else ""
    )
    parser.add_argument(
        "--calibration",
        choices=("sample", "pool", "nominal") if pool else ("sample", "nominal"),
        default="sample",
        help="robot parameters with an uncertainty in experiment.toml: sampled with their "
        "calibration as prior (default; per_phi mode: each volume fraction its own copy)"
        f"{pooled}; nominal: taken at their nominal values as exact",
    )
    parser.add_argument(
        "--quiet", action="store_true", help="no progress bars or progress messages"
    )
    parser.add_argument(
        "--allow-unconverged",
        action="store_true",
        help=f"exit 0 even if a sampler run did not converge (default: exit {EXIT_UNCONVERGED})",
    )


def _sampler_arguments(args: argparse.Namespace) -> dict:
    """The ``SamplerSettings`` fields that ``_add_inference_arguments`` sets."""
    return {
        "n_walkers": args.walkers,
        "n_ensembles": args.ensembles,
        "max_steps": args.max_steps,
        "start": args.start,
    }


def _add_kinds_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--data",
        dest="kinds",
        metavar="KINDS",
        help="kinds of measurement to use, comma-separated (heights, trajectories, "
        "intrusions; default: every measurement file in the folder)",
    )


def _load_measurements(args: argparse.Namespace, experiment: Experiment):
    """The measurements ``--data`` asks for (default: every file in the folder)."""
    from .kinds import load_measurements

    use = None
    if args.kinds is not None:
        use = [k.strip() for k in args.kinds.split(",") if k.strip()]
        if not use:
            raise UsageError(f"--data {args.kinds!r}: name at least one kind")
    return load_measurements(args.data, experiment, use)


def _check_inference_arguments(args: argparse.Namespace) -> None:
    if args.walkers < 4 or args.walkers % 2:
        raise UsageError(f"--walkers {args.walkers}: must be an even number >= 4")
    if args.ensembles < 2:
        raise UsageError(
            f"--ensembles {args.ensembles}: must be >= 2 (convergence compares ensembles)"
        )
    if args.max_steps < 100:
        raise UsageError(f"--max-steps {args.max_steps}: must be >= 100")
    if args.threads is not None and args.threads < 1:
        raise UsageError(f"--threads {args.threads}: must be >= 1")
    if args.out.exists() and not args.out.is_dir():
        raise UsageError(f"--out {args.out}: exists and is not a folder")


def _add_fit_arguments(parser: argparse.ArgumentParser) -> None:
    _add_inference_arguments(parser, max_steps=20_000)
    parser.add_argument(
        "--terms",
        default="depth,drag",
        help=f"comma-separated force terms (default depth,drag; available: {', '.join(TERMS)})",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue an interrupted run from its checkpoints in OUT.partial/chains/",
    )
    _add_phi_arguments(parser)
    parser.add_argument(
        "--noise",
        choices=("normal", "student_t"),
        default="normal",
        help="scatter of a jump about its simulated height: Gaussian (default) or Student-t "
        "with --nu degrees of freedom (heavy tails: robust to outlying jumps)",
    )
    parser.add_argument("--nu", type=float, default=4.0, help="Student-t degrees of freedom")
    _add_kinds_argument(parser)
    parser.add_argument(
        "--compare-commands",
        action="store_true",
        help="also fit each command separately and compare by PSIS-LOO",
    )
    parser.add_argument(
        "--truth", type=Path, help="truth.toml of synthetic data, overlaid on figures"
    )


def _add_phi_arguments(parser: argparse.ArgumentParser) -> None:
    """How the law depends on phi, the beds and the scatter (``fit`` and ``sbc``)."""
    parser.add_argument(
        "--phi-mode",
        choices=("per_phi", "quadratic"),
        default="per_phi",
        help="independent laws per volume fraction, or quadratic in phi-phi_c",
    )
    parser.add_argument(
        "--bed-phi",
        choices=("integrate", "measured"),
        default="integrate",
        help="with [bed] phi_sd in experiment.toml and --phi-mode quadratic: each jump's and "
        "intrusion test's bed phi latent about the measured value, integrated out by "
        "quadrature (default), or taken as measured",
    )
    parser.add_argument(
        "--sigma",
        choices=("per_phi", "global"),
        default="per_phi",
        help="scatter per volume fraction or global (quadratic mode)",
    )


def _fit_config(args: argparse.Namespace):
    from ._fitting import FitSettings
    from ._sampler import SamplerSettings

    _check_inference_arguments(args)
    terms = tuple(t.strip() for t in args.terms.split(",") if t.strip())
    sampler = SamplerSettings(**_sampler_arguments(args))
    try:
        return FitSettings(
            terms=terms,
            phi_mode=args.phi_mode,
            noise=args.noise,
            nu=args.nu,
            sigma_mode=args.sigma,
            sampler=sampler,
            n_threads=args.threads,
            calibration=args.calibration,
            bed_phi=args.bed_phi,
        )
    except ValueError as exc:
        raise UsageError(f"--terms {args.terms}: {exc}") from None


def run_fit(args: argparse.Namespace) -> int:
    """``granbayes fit``: validate everything, sample, write the report atomically."""
    from ._fitting import compare_commands, fit
    from ._priors import load_priors
    from .report import load_truth, write_fit_report

    config = _fit_config(args)
    experiment = load_experiment(args.data)
    data = _load_measurements(args, experiment)
    priors = load_priors(args.priors) if args.priors else None
    truth = load_truth(args.truth) if args.truth else None
    with staged_folder(args.out, args.resume) as work, ProgressBars(args.quiet) as bars:
        result = fit(
            experiment,
            data,
            config,
            seed=args.seed,
            priors=priors,
            checkpoint=work / "chains",
            resume=args.resume,
            data_source=str(args.data),
            progress=bars,
        )
        if args.compare_commands and "heights" not in data.tables:
            raise UsageError("--compare-commands compares laws on jump heights: none given")
        uniqueness = (
            compare_commands(
                experiment, data.tables["heights"], result, seed=args.seed, priors=priors
            ).table
            if args.compare_commands
            else None
        )
        write_fit_report(result.datatree, work, truth=truth, uniqueness=uniqueness)
    for w in result.warnings:
        print(f"granbayes: warning: {w}", file=sys.stderr)
    if not args.quiet:
        print((args.out / "summary.md").read_text())
    return _converged_exit(result.converged, args)


def _converged_exit(converged: bool, args: argparse.Namespace) -> int:
    """EXIT_OK, or EXIT_UNCONVERGED for an unconverged run unless it is allowed."""
    if converged or args.allow_unconverged:
        return EXIT_OK
    print(
        "granbayes: error: a sampler run did not converge (see the warnings above); "
        "results are written; raise --max-steps, or pass --allow-unconverged",
        file=sys.stderr,
    )
    return EXIT_UNCONVERGED


class ProgressBars:
    """One labelled progress bar per sampler run (``fit(progress=...)``).

    Each bar shows the run's label (volume fraction), steps against the cap, the largest
    autocorrelation time, R-hat across ensembles, the smallest ESS and whether the run has
    converged. Bars are drawn on stderr when it is a terminal and ``quiet`` is false.
    With ``leave=False`` (``diagnose``: many fits) a run's bar is removed when the run
    converges or reaches its step cap.
    """

    def __init__(self, quiet: bool = False, *, leave: bool = True) -> None:
        self.enabled = not quiet and sys.stderr.isatty()
        self.leave = leave
        self.bars: dict = {}

    def __enter__(self) -> ProgressBars:
        return self

    def __exit__(self, *exc: object) -> None:
        for bar in self.bars.values():
            bar.close()

    def __call__(self, label: str, info) -> None:
        """Update the bar of run ``label`` with a ``granbayes._sampler.ProgressInfo``."""
        if not self.enabled:
            return
        from tqdm import tqdm

        bar = self.bars.get(label)
        if bar is None:
            bar = tqdm(total=info.max_steps, desc=label, unit="step", leave=self.leave)
            self.bars[label] = bar
        bar.update(info.step - bar.n)
        bar.set_postfix(
            tau=f"{info.tau_max:.0f}",
            rhat=f"{info.rhat_max:.3f}",
            ess=f"{info.ess_min:.0f}",
            converged=info.converged,
        )
        if info.converged:
            bar.total = info.step
            bar.refresh()
        if not self.leave and (info.converged or info.step >= info.max_steps):
            bar.close()
            del self.bars[label]


# ----------------------------------------------------------------------------------------
# granbayes diagnose
# ----------------------------------------------------------------------------------------


def _add_diagnose_arguments(parser: argparse.ArgumentParser) -> None:
    _add_inference_arguments(parser, max_steps=10_000, pool=False)
    _add_kinds_argument(parser)
    parser.add_argument(
        "--baseline", default="depth", help="comma-separated terms of the baseline law"
    )
    parser.add_argument(
        "--candidates", help="comma-separated terms to try (default: every other term)"
    )
    parser.add_argument(
        "--no-screen",
        action="store_true",
        help="fit every candidate in full (default: candidates whose largest log-likelihood "
        "gain cannot win are screened out without a full posterior)",
    )
    parser.add_argument(
        "--lack-of-fit-alpha",
        default="0.01",
        metavar="ALPHA",
        help="level at which the omnibus lack-of-fit test (every height cell together) shows "
        "misfit, as a misfit cell does; 'none': the test is reported only (default 0.01)",
    )


def run_diagnose(args: argparse.Namespace) -> int:
    """``granbayes diagnose``: the model-criticism loop, written atomically to OUT."""
    import dataclasses as dc

    from ._criticism import DiagnoseSettings, diagnose
    from ._priors import load_priors
    from .design import save_tie_laws
    from .forces import terms_of
    from .report import write_diagnosis_report

    def terms(text: str, option: str) -> tuple[str, ...]:
        names = tuple(t.strip() for t in text.split(",") if t.strip())
        try:
            terms_of(names)
        except ValueError as exc:
            raise UsageError(f"{option} {text}: {exc}") from None
        return names

    _check_inference_arguments(args)
    alpha = None
    if args.lack_of_fit_alpha.strip().lower() != "none":
        try:
            alpha = float(args.lack_of_fit_alpha)
        except ValueError:
            alpha = math.nan
        if not 0.0 < alpha < 1.0:
            raise UsageError(
                f"--lack-of-fit-alpha {args.lack_of_fit_alpha}: a level in (0, 1), or 'none'"
            )
    config = DiagnoseSettings(
        baseline=terms(args.baseline, "--baseline"),
        candidates=None if args.candidates is None else terms(args.candidates, "--candidates"),
        screen=not args.no_screen,
        n_threads=args.threads,
        calibration=args.calibration,
        lack_of_fit_alpha=alpha,
    )
    config = dc.replace(
        config,
        sampler=dc.replace(config.sampler, **_sampler_arguments(args)),
    )
    experiment = load_experiment(args.data)
    data = _load_measurements(args, experiment)
    priors = load_priors(args.priors) if args.priors else None
    log = (lambda *a, **k: None) if args.quiet else (lambda *a, **k: print(*a, **k, flush=True))
    bars = ProgressBars(args.quiet, leave=False)
    with staged_folder(args.out, resume=False) as work, bars:
        result = diagnose(
            experiment,
            data,
            config,
            seed=args.seed,
            priors=priors,
            data_source=str(args.data),
            log=log,
            progress=bars,
        )
        write_diagnosis_report(result.to_json(), result.selected.datatree, work)
        save_tie_laws(result, work)  # the posteriors granbayes design reads
    if not args.quiet:
        print((args.out / "report.md").read_text())
    return _converged_exit(result.converged, args)


# ----------------------------------------------------------------------------------------
# granbayes design
# ----------------------------------------------------------------------------------------


def _add_design_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "data", metavar="DIR", type=Path, help="the diagnosed (or fitted) experiment folder"
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument(
        "--diagnosis",
        metavar="OUT",
        type=Path,
        help="output folder of granbayes diagnose on DIR (diagnosis.json, laws/): its tie, "
        "or without one the unidentified parameters of its selected law",
    )
    source.add_argument(
        "--fit",
        metavar="FIT",
        type=Path,
        help="a fit of DIR (posterior.nc or its folder): design for its parameters",
    )
    parser.add_argument(
        "--out",
        metavar="DESIGN",
        type=Path,
        required=True,
        help="output folder (design.json, plan.csv, candidates.csv, design.md; replaced "
        "only when complete)",
    )
    _add_kinds_argument(parser)
    parser.add_argument(
        "--tie",
        type=int,
        default=0,
        help="which tie of the diagnosis, in the order of diagnosis.json (default 0)",
    )
    parser.add_argument(
        "--max-jumps",
        type=int,
        default=60,
        help="budget: jumps added until the tie is settled (or the parameters reach their "
        "goal) in expectation (default 60)",
    )
    params = parser.add_argument_group(
        "parameters (--fit, or --diagnosis without a tie or with --parameter)"
    )
    params.add_argument(
        "--parameter",
        metavar="NAME[,NAME]",
        help="force parameters to narrow at every volume fraction (default: those whose "
        "posterior-to-prior contraction is below 0.5)",
    )
    goal = params.add_mutually_exclusive_group()
    goal.add_argument(
        "--goal-contraction",
        type=float,
        default=0.9,
        help="contraction each parameter should reach (default 0.9: well identified)",
    )
    goal.add_argument(
        "--sd-ratio",
        type=float,
        help="instead: the share of its present posterior SD each parameter should reach",
    )
    cands = parser.add_argument_group(
        "settings a next jump may have (comma-separated; default: within the measured ones)"
    )
    cands.add_argument("--command", metavar="NAME[,NAME]", help="commands (default: all five)")
    cands.add_argument(
        "--phi", metavar="PHI[,PHI]", help="volume fractions (default: the measured ones)"
    )
    cands.add_argument(
        "--freq-hz",
        metavar="HZ[,HZ]",
        help="frequencies [Hz] (default: 5 from the lowest measured to the highest)",
    )
    cands.add_argument(
        "--delay-ms",
        metavar="MS[,MS]",
        help="holds of the delayed stutter [ms] (default: the measured ones)",
    )
    parser.add_argument(
        "--draws",
        type=int,
        default=800,
        help="posterior draws per law (default 800)",
    )
    parser.add_argument(
        "--seed", type=int, default=0, help="seed of the draws' selection (default 0)"
    )
    parser.add_argument("--quiet", action="store_true", help="do not print the plan")


def _run_design(args: argparse.Namespace) -> int:
    from ._fitting import data_hash
    from .design import candidate_settings, design_from_diagnosis, ties_of

    if args.max_jumps < 1:
        raise UsageError(f"--max-jumps {args.max_jumps}: must be >= 1")
    if args.draws < 10:
        raise UsageError(f"--draws {args.draws}: must be >= 10")
    if args.diagnosis is not None and not (args.diagnosis / "diagnosis.json").is_file():
        raise UsageError(f"--diagnosis {args.diagnosis}: no diagnosis.json there")
    if not 0.0 < args.goal_contraction < 1.0:
        raise UsageError(f"--goal-contraction {args.goal_contraction}: must be in (0, 1)")
    if args.sd_ratio is not None and not 0.0 < args.sd_ratio < 1.0:
        raise UsageError(f"--sd-ratio {args.sd_ratio}: must be in (0, 1)")
    if args.out.exists() and not args.out.is_dir():
        raise UsageError(f"--out {args.out}: exists and is not a folder")
    experiment = load_experiment(args.data)
    data = _load_measurements(args, experiment)
    commands = None
    if args.command:
        commands = [_check_command(c.strip()) for c in args.command.split(",") if c.strip()]
    phis = None
    if args.phi:
        phis = [_check_phi(p.strip()) for p in args.phi.split(",") if p.strip()]
    only = {**vars(args), "amplitude_mm": None, "settle_periods": None}  # not design options
    settings = _setting_values(argparse.Namespace(**only), lists=True)
    jumps = data.tables.get("heights")
    if jumps is None:
        raise UsageError(f"{args.data}: no jump heights: granbayes design proposes jumps")
    candidates = candidate_settings(
        jumps,
        commands=commands,
        phis=phis,
        freqs_hz=settings.get("freq_hz"),
        delays_ms=settings.get("delay_ms"),
    )
    sha = data_hash(experiment, data)
    record = None
    if args.diagnosis is not None:
        record = json.loads((args.diagnosis / "diagnosis.json").read_text())
    if record is not None and not args.parameter and ties_of(record):
        try:
            tie, design = design_from_diagnosis(
                args.diagnosis,
                tie=args.tie,
                candidates=candidates,
                max_jumps=args.max_jumps,
                n_draws=args.draws,
                rng=args.seed,
                data_sha256=sha,
            )
        except (ValueError, FileNotFoundError) as exc:
            raise UsageError(str(exc)) from None
        lines = _design_lines(tie, design, record)
        extra = {
            "tie": {k: (list(v) if k == "laws" else v) for k, v in tie.items()},
            "diagnosis": str(args.diagnosis),
        }
    else:
        design, lines, extra = _parameter_design(args, candidates, sha)
    with staged_folder(args.out, resume=False) as work:
        (work / "design.json").write_text(
            json.dumps(
                {
                    **design.to_json(),
                    **extra,
                    "data_source": str(args.data),
                    "seed": args.seed,
                    "granbayes_version": __version__,
                },
                indent=2,
            )
            + "\n"
        )
        _write_csv(design.plan, work / "plan.csv")
        _write_csv(design.candidates, work / "candidates.csv")
        (work / "design.md").write_text("\n".join(lines) + "\n")
    if not args.quiet:
        print("\n".join(lines))
    return EXIT_OK


def _parameter_design(args: argparse.Namespace, candidates: pd.DataFrame, sha: str):
    """``granbayes design`` for parameters: the design, its words and its provenance."""
    from ._saved import load_fit
    from .design import design_parameters

    where = args.fit if args.fit is not None else args.diagnosis / "posterior_selected.nc"
    if args.fit is None and not where.is_file():
        raise UsageError(
            f"--diagnosis {args.diagnosis}: no tie to settle, and no posterior of the selected "
            "law (posterior_selected.nc) whose parameters could be designed for"
        )
    fit = load_fit(where)  # an InputError names the file
    fitted = fit.datatree.attrs.get("data_sha256")
    if fitted != sha:
        raise UsageError(
            f"{where} is a fit of other data (sha256 {str(fitted)[:12]}... against "
            f"{sha[:12]}...): pass the fitted folder, with the same kinds of measurement"
        )
    names = None
    if args.parameter:
        names = [n.strip() for n in args.parameter.split(",") if n.strip()]
    try:
        design = design_parameters(
            fit,
            parameters=names,
            candidates=candidates,
            goal=args.goal_contraction,
            sd_ratio=args.sd_ratio,
            max_jumps=args.max_jumps,
            n_draws=args.draws,
            rng=args.seed,
        )
    except ValueError as exc:
        no_tie = " (the diagnosis has no tie)" if args.diagnosis is not None else ""
        raise UsageError(f"{where}{no_tie}: {exc}") from None
    source = {"fit": str(where)} if args.fit is not None else {"diagnosis": str(args.diagnosis)}
    return design, _parameter_design_lines(design, str(args.data)), source


def _parameter_design_lines(design, data_source: str) -> list[str]:
    """A parameter design in words (``design.md``)."""
    from ._design_draws import SETTINGS
    from .report import markdown_table

    goal = (
        f"a posterior-to-prior contraction of {design.goal:g}"
        if design.sd_ratio is None
        else f"a posterior SD {design.sd_ratio:g} times the present one"
    )
    targets = design.targets[
        [
            "parameter",
            "phi",
            "unit",
            "scale",
            "median",
            "posterior_sd",
            "contraction",
            "posterior_sd_expected",
            "contraction_expected",
            "information_nats",
            "reached",
        ]
    ]
    lines = [
        f"# The jumps that would identify the parameters of {design.law}",
        "",
        f"Fit of {data_source}; the goal: {goal} for each parameter below.",
        "",
        "## Plan" + ("" if design.reached else " (budget spent: the goal not reached)"),
        "",
        markdown_table(design.plan, missing="-"),
        "",
        f"{design.n_jumps} jumps, {design.information_nats:.2f} nats of expected information "
        "about the parameters jointly. Each parameter now and after them in expectation "
        "(the SD in its scale: log of the value for log-scale priors; a linear-Gaussian "
        "approximation on the posterior draws: an estimate, not a promise):",
        "",
        markdown_table(targets.round(4)),
        "",
        "The best settings by the information one jump gives (`information_nats`; all in "
        "`candidates.csv`):",
        "",
        markdown_table(
            design.candidates[[*SETTINGS, "mean_mm", "sd_mm", "information_nats"]].head(8).round(3),
            missing="-",
        ),
    ]
    lines += ["", *[f"- note: {n}" for n in design.notes]] if design.notes else []
    return lines


def _design_lines(tie: dict, design, record: dict) -> list[str]:
    """The plan in words (``design.md``)."""
    from ._design_draws import SETTINGS
    from .report import markdown_table

    a, b = design.laws
    best = design.candidates[
        [*SETTINGS, *(c for c in design.candidates if c.startswith("mean_mm")), "worst_kl"]
    ]
    rule = design.rule
    lines = [
        f"# The jumps that would settle {a} against {b}",
        "",
        f"Diagnosis of {record.get('data_source', '')}, round {tie['round']}: {a} - {b} = "
        f"{tie['elpd_diff']:.1f} ± {tie['elpd_diff_se']:.1f} nats (paired), short of the "
        f"rule (> {rule['min_gain']:g} nats and > {rule['se_factor']:g} SE).",
        "",
        "## Plan" + ("" if design.settled else " (budget spent: not settled in expectation)"),
        "",
        markdown_table(design.plan, missing="-"),
        "",
        f"{design.n_jumps} jumps. Expected paired ELPD difference after them, under each "
        "hypothesis (which law is true): the separation of the two laws' predictive "
        "distributions of a new jump (Box & Hill 1967, normal approximation) after both "
        "posteriors have been reweighted by the planned jumps, so that a rival that can "
        "move towards them is not credited with the separation it first promises; an "
        "estimate, not a promise (`ess_share`: the smallest share of a posterior's draws "
        "left effective by the reweighting):",
        "",
        markdown_table(design.hypotheses.round(2)),
        "",
        "The best settings by the separation one jump gives under the worse hypothesis "
        "(`worst_kl` [nats]; all in `candidates.csv`):",
        "",
        markdown_table(best.head(8).round(3), missing="-"),
    ]
    lines += ["", *[f"- note: {n}" for n in design.notes]] if design.notes else []
    return lines


# ----------------------------------------------------------------------------------------
# granbayes sbc
# ----------------------------------------------------------------------------------------


def _add_sbc_arguments(parser: argparse.ArgumentParser) -> None:
    _add_inference_arguments(
        parser,
        max_steps=20_000,
        threads_help="numba threads per replicate (default: cores / workers on the local "
        "cluster, 1 on --scheduler)",
    )
    parser.add_argument(
        "--terms",
        default="depth,drag",
        help=f"comma-separated force terms (default depth,drag; available: {', '.join(TERMS)})",
    )
    parser.add_argument(
        "--replicates", type=int, required=True, help="number of SBC replicates (fits)"
    )
    _add_phi_arguments(parser)
    _add_kinds_argument(parser)
    parser.add_argument(
        "--rank-draws",
        type=int,
        default=99,
        help="posterior draws each true value is ranked among (default 99)",
    )
    parser.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="address of a running Dask scheduler, e.g. tcp://10.0.0.5:8786 "
        "(default: a local cluster on this machine)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        help="worker processes of the local cluster (default: one per core)",
    )
    parser.add_argument(
        "--connect-timeout",
        type=float,
        default=10.0,
        metavar="S",
        help="seconds to try reaching --scheduler (default 10)",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue a killed run from OUT.partial: finished replicates are not recomputed",
    )


def run_sbc_command(args: argparse.Namespace) -> int:
    """``granbayes sbc``: simulation-based calibration of fit as a Dask campaign."""
    from ._fitting import FitSettings
    from ._priors import load_priors
    from ._sampler import SamplerSettings
    from .campaign import CampaignError

    _check_inference_arguments(args)
    terms = tuple(t.strip() for t in args.terms.split(",") if t.strip())
    sampler = SamplerSettings(**_sampler_arguments(args))
    try:
        config = FitSettings(
            terms=terms,
            sampler=sampler,
            calibration=args.calibration,
            phi_mode=args.phi_mode,
            sigma_mode=args.sigma,
            bed_phi=args.bed_phi,
        )
    except ValueError as exc:
        raise UsageError(f"--terms {args.terms}: {exc}") from None
    if args.replicates < 1:
        raise UsageError(f"--replicates {args.replicates}: must be >= 1")
    kept = args.walkers * args.ensembles * config.sampler.n_draws
    if not 1 <= args.rank_draws <= kept:
        raise UsageError(
            f"--rank-draws {args.rank_draws}: must be in [1, walkers x ensembles x "
            f"{config.sampler.n_draws} kept draws = {kept}]"
        )
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers}: must be >= 1")
    if args.workers is not None and args.scheduler is not None:
        raise UsageError(
            "--workers sizes the local cluster; with --scheduler the cluster has its own workers"
        )
    if not args.connect_timeout > 0:
        raise UsageError(f"--connect-timeout {args.connect_timeout}: must be > 0")
    experiment = load_experiment(args.data)
    design = _load_measurements(args, experiment)  # run_sbc takes heights alone as a table
    if args.phi_mode == "quadratic" and design.kinds != ("heights",):
        raise UsageError(
            "--phi-mode quadratic: SBC of a quadratic fit takes jump heights alone "
            f"({args.data} has {', '.join(design.kinds)}; add --data heights)"
        )
    priors = load_priors(args.priors) if args.priors else None
    log = (lambda _m: None) if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    try:
        result = _run_sbc_campaign(args, experiment, design, config, priors, log)
    except CampaignError as exc:  # name the options the user typed
        message = str(exc)
        for name, flag in (("scheduler_address ", "--scheduler "), ("resume: ", "--resume: ")):
            message = message.replace(name, flag, 1) if message.startswith(name) else message
        raise UsageError(message) from None
    print((args.out / "summary.md").read_text())
    failed = result.campaign.n_failed
    if failed:
        print(
            f"granbayes: warning: {failed} of {args.replicates} replicates failed; their "
            f"errors are in {args.out / 'tasks.csv'} (rerun with --resume to retry them)",
            file=sys.stderr,
        )
        return EXIT_FAILED_TASK
    return EXIT_OK


def _run_sbc_campaign(args, experiment, design, config, priors, log):
    from ._sbc import run_sbc
    from .campaign import ClusterSettings

    cluster = ClusterSettings(
        scheduler_address=args.scheduler,
        n_workers=args.workers,
        numba_threads=args.threads,
        connect_timeout_s=args.connect_timeout,
    )
    return run_sbc(
        experiment,
        design,
        args.out,
        settings=config,
        n_replicates=args.replicates,
        seed=args.seed,
        priors=priors,
        n_rank_draws=args.rank_draws,
        cluster=cluster,
        resume=args.resume,
        progress=not args.quiet,
        data_source=str(args.data),
        log=log,
    )


# ----------------------------------------------------------------------------------------
# granbayes predict
# ----------------------------------------------------------------------------------------


def _add_predict_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "posterior",
        metavar="POSTERIOR",
        type=Path,
        help="posterior.nc written by granbayes fit (or the fit's output folder)",
    )
    parser.add_argument(
        "--command",
        metavar="NAME[,NAME]",
        required=True,
        help=f"jump command(s), comma-separated: {', '.join(COMMAND_NAMES)}",
    )
    parser.add_argument(
        "--phi",
        metavar="PHI[,PHI]",
        required=True,
        help="volume fraction(s), comma-separated (a per_phi fit: fitted ones only)",
    )
    settings = parser.add_argument_group(
        "command settings (comma-separated lists; default: the fit's experiment settings)"
    )
    for flag, metavar, text in _SETTING_FLAGS:
        settings.add_argument(flag, metavar=f"{metavar}[,{metavar}]", type=str, help=text)
    parser.add_argument(
        "--draws",
        type=int,
        default=1000,
        help="posterior draws to simulate (default 1000; 0: all)",
    )
    parser.add_argument(
        "--ci-prob",
        type=float,
        default=0.9,
        help="probability of the equal-tailed intervals (default 0.9)",
    )
    parser.add_argument(
        "--seed", type=int, default=0, help="seed of the draw selection and noise (default 0)"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument(
        "--out", metavar="OUT.csv", type=Path, help="also write the predictions as CSV"
    )


def _run_predict(args: argparse.Namespace) -> int:
    from ._prediction import predict
    from ._saved import load_fit

    commands = [_check_command(c.strip()) for c in args.command.split(",") if c.strip()]
    phis = [_check_phi(p.strip()) for p in args.phi.split(",") if p.strip()]
    if not commands or not phis:
        raise UsageError("--command and --phi need at least one value each")
    settings = _setting_values(args, lists=True)
    if args.draws < 0:
        raise UsageError(f"--draws {args.draws}: must be >= 0 (0: all draws)")
    if not 0.0 < args.ci_prob < 1.0:
        raise UsageError(f"--ci-prob {args.ci_prob}: must be in (0, 1)")
    if args.out is not None:
        _check_target(args.out, "--out")
    saved = load_fit(args.posterior)
    try:
        result = predict(
            saved,
            commands,
            phis,
            **settings,
            n_draws=args.draws or None,
            ci_prob=args.ci_prob,
            rng=args.seed,
        )
    except ValueError as exc:  # name the options the user typed
        message = str(exc).replace("fit with phi_mode='quadratic'", "fit with --phi-mode quadratic")
        raise UsageError(message) from None
    if args.out is not None:
        _write_csv(result.table, args.out)
    if args.json:
        record = result.to_json() | {
            "posterior": str(saved.source),
            "terms": list(saved.settings.terms),
            "phi_mode": saved.settings.phi_mode,
            "seed": args.seed,
            "granbayes_version": __version__,
        }
        print(json.dumps(record, allow_nan=False))
        return EXIT_OK
    pct = f"{args.ci_prob:.0%}"
    print(
        f"Predicted jump heights [mm] from {saved.source} ({' + '.join(saved.settings.terms)}, "
        f"{saved.settings.phi_mode}): median [{pct} interval] of the simulated height and of a "
        "new jump (plus the fitted scatter)"
    )
    for r in result.table.itertuples():
        setting = (
            f"{r.freq_hz:g} Hz, A = {r.amplitude_mm:g} mm, delay {r.delay_ms:g} ms, "
            f"settle {r.settle_periods:g} T"
        )
        failed = f"; {r.n_failed} of {r.n_draws} failed" if r.n_failed else ""
        print(
            f"  {r.command:<24} phi={r.phi:<6g} {setting}: simulated "
            f"{r.height_sim_mm_median:.1f} [{r.height_sim_mm_lo:.1f}, {r.height_sim_mm_hi:.1f}]"
            f", new jump {r.height_mm_median:.1f} [{r.height_mm_lo:.1f}, "
            f"{r.height_mm_hi:.1f}]{failed}"
        )
    for note in result.notes:
        print(f"granbayes: note: {note}", file=sys.stderr)
    return EXIT_OK


# ----------------------------------------------------------------------------------------
# granbayes report
# ----------------------------------------------------------------------------------------


def _add_report_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "posterior",
        metavar="POSTERIOR",
        type=Path,
        help="posterior.nc written by granbayes fit (or the fit's output folder); a "
        "uniqueness.csv next to it is included",
    )
    parser.add_argument(
        "--out",
        metavar="DIR",
        type=Path,
        required=True,
        help="output folder (replaced only when the report is complete; not the folder "
        "holding POSTERIOR)",
    )
    parser.add_argument(
        "--truth", type=Path, help="truth.toml of synthetic data, overlaid on figures"
    )
    parser.add_argument(
        "--no-diagnostics-plots", action="store_true", help="skip the trace and rank plots"
    )
    parser.add_argument("--quiet", action="store_true", help="do not print the summary")


def _run_report(args: argparse.Namespace) -> int:
    from ._saved import load_fit
    from .report import load_truth, write_fit_report

    source = args.posterior / "posterior.nc" if args.posterior.is_dir() else args.posterior
    if args.out.exists() and not args.out.is_dir():
        raise UsageError(f"--out {args.out}: exists and is not a folder")
    if args.out.resolve() == source.resolve().parent:
        raise UsageError(
            f"--out {args.out}: is the folder holding {source.name}; write the report "
            "elsewhere (the output folder is replaced)"
        )
    saved = load_fit(source)
    truth = load_truth(args.truth) if args.truth else None
    uniqueness_csv = source.parent / "uniqueness.csv"
    uniqueness = pd.read_csv(uniqueness_csv) if uniqueness_csv.is_file() else None
    with staged_folder(args.out, resume=False) as work:
        write_fit_report(
            saved.datatree,
            work,
            truth=truth,
            uniqueness=uniqueness,
            diagnostics_plots=not args.no_diagnostics_plots,
        )
    if not args.quiet:
        print((args.out / "summary.md").read_text())
    return EXIT_OK


# ----------------------------------------------------------------------------------------
# granbayes priors
# ----------------------------------------------------------------------------------------


def _add_priors_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--terms",
        help=f"comma-separated force terms whose parameters to print (default: every "
        f"parameter; available: {', '.join(TERMS)}); the scatter sigma_mm is always printed",
    )


def _run_priors(args: argparse.Namespace) -> int:
    from ._priors import NOISE_PARAMETERS, priors_toml
    from .forces import terms_of

    if args.terms is None:
        names = None
    else:
        try:
            terms = terms_of(t.strip() for t in args.terms.split(",") if t.strip())
        except ValueError as exc:
            raise UsageError(f"--terms {args.terms}: {exc}") from None
        names = [p.name for t in terms for p in TERMS[t].parameters] + list(NOISE_PARAMETERS)
    print(priors_toml(names=names), end="")
    return EXIT_OK


# ----------------------------------------------------------------------------------------
# Registry and entry point
# ----------------------------------------------------------------------------------------

#: The subcommands, in ``--help`` order.
SUBCOMMANDS: list[Subcommand] = [
    Subcommand(
        "simulate",
        "simulate one jump, or a batch table of jumps",
        _add_simulate_arguments,
        _run_simulate,
        description="Simulate one jump (--command, --phi, --param k=... [--param ...]) or "
        "every row of a table (--batch IN.csv --out OUT.csv). Exit code 3 if a jump did "
        "not finish (its status is failed:...); outputs are still written.",
    ),
    Subcommand(
        "fit",
        "Bayesian fit of a force law to an experiment folder",
        _add_fit_arguments,
        run_fit,
        description="Sample the posterior of the force-term parameters (emcee) per volume "
        "fraction, shared by all commands, and write posterior.nc, summary tables and "
        "figures into OUT.",
    ),
    Subcommand(
        "diagnose",
        "model criticism: what the simulation gets wrong and which physics is missing",
        _add_diagnose_arguments,
        run_diagnose,
        description="Fit the baseline law, show its posterior predictive misfit per command "
        "x phi x frequency, try every other force term of the library, keep the ones PSIS-LOO "
        "clearly favours, and write OUT/diagnosis.json with a report and figures.",
    ),
    Subcommand(
        "design",
        "the next jumps that would separate tied laws, or identify a parameter",
        _add_design_arguments,
        _run_design,
        description="For a tie of a diagnosis (laws whose paired ELPD difference is short of "
        "the rule's margin), propose the jumps (command, phi, frequency, delay, trials) that "
        "are expected to separate them, by the Kullback-Leibler separation of the two laws' "
        "posterior predictive distributions, with the ELPD difference expected after them. "
        "For a fit (--fit), or a diagnosis without a tie, or with --parameter: the jumps "
        "expected to narrow the parameters the data leave to their priors (contraction below "
        "0.5, or those named) to a goal, by their expected information (linear-Gaussian "
        "approximation on the posterior draws), with the posterior SD expected after them. "
        "Writes DESIGN/design.json, plan.csv, candidates.csv and design.md.",
    ),
    Subcommand(
        "sbc",
        "simulation-based calibration of fit on an experiment's design (Dask campaign)",
        _add_sbc_arguments,
        run_sbc_command,
        description="Per replicate: draw the force law and scatter per volume fraction from "
        "the priors, simulate the jumps of DIR's design, fit them, and rank each true value "
        "among the posterior draws. With tracked jumps or intrusion tests in DIR (--data), "
        "every kind's noise is drawn from its prior too and the independent oracle simulates "
        "every measurement: the calibration of the joint fit. Replicates run on Dask (a local "
        "cluster, or --scheduler), each result written as it finishes (--resume continues a "
        "killed run). Writes "
        "OUT/ranks.csv, OUT/summary.json, OUT/summary.md and OUT/sbc_ecdf.png.",
    ),
    Subcommand(
        "predict",
        "predictive jump heights at new settings from a fit's posterior",
        _add_predict_arguments,
        _run_predict,
        description="Simulate the jump for posterior draws of a saved fit (posterior.nc) at "
        "the given command(s), volume fraction(s) and settings, and print the median and "
        "equal-tailed interval of the simulated height and of a new jump (plus the fitted "
        "scatter). A per_phi fit predicts at its fitted volume fractions only; a quadratic "
        "fit anywhere. Comma-separated values give every combination.",
    ),
    Subcommand(
        "report",
        "re-render a fit's report from its posterior.nc",
        _add_report_arguments,
        _run_report,
        description="Write the summary, tables and figures of a fit (as granbayes fit "
        "writes them) into OUT from a saved posterior.nc, and the uniqueness.csv next to it "
        "if there is one.",
    ),
    Subcommand(
        "priors",
        "print the default priors as TOML (the format of --priors FILE)",
        _add_priors_arguments,
        _run_priors,
        description="Print the default prior of every parameter (or those of --terms) as "
        "TOML, each with its reason as a comment: a file to edit and pass back with "
        "granbayes fit --priors FILE.",
    ),
    Subcommand(
        "demo",
        "simulate the five jumps and the hard-ground sweep; write figures",
        _add_demo_arguments,
        _run_demo,
    ),
]


def build_parser() -> argparse.ArgumentParser:
    """The ``granbayes`` argument parser with every subcommand of :data:`SUBCOMMANDS`."""
    parser = _Parser(
        prog="granbayes",
        description="Simulate a jumping robot on granular media and infer the ground force.",
        epilog="Exit codes: 0 success, 2 bad input (nothing written), 3 a jump did not "
        f"finish (outputs written), {EXIT_UNCONVERGED} a fit or diagnosis did not converge "
        "(results written; --allow-unconverged exits 0), 5 a campaign task failed "
        "(results written).",
    )
    parser.add_argument("--version", action="version", version=f"granbayes {__version__}")
    sub = parser.add_subparsers(dest="subcommand", metavar="SUBCOMMAND", required=True)
    for cmd in SUBCOMMANDS:
        p = sub.add_parser(cmd.name, help=cmd.help, description=cmd.description or cmd.help)
        cmd.add_arguments(p)
        p.set_defaults(_run=cmd.run)
    return parser


def _one_line(err: BaseException) -> str:
    message = err.args[0] if isinstance(err, KeyError) and err.args else str(err)
    return " ".join(str(message).split())


def main(argv: list[str] | None = None) -> int:
    """Run ``granbayes`` with ``argv`` (default: ``sys.argv[1:]``).

    Parameters
    ----------
    argv : list of str, optional
        Arguments after the program name.

    Returns
    -------
    int
        Exit code (module docstring): 0 success, 2 bad input, 3 a jump did not finish,
        4 a sampler run did not converge, 5 a campaign task failed.
    """
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors
        return exc.code if isinstance(exc.code, int) else EXIT_INPUT
    try:
        return args._run(args)
    except (InputError, UsageError, ValueError, KeyError) as err:
        print(f"granbayes: error: {_one_line(err)}", file=sys.stderr)
        return EXIT_INPUT
    except OSError as err:
        where = f"{err.filename}: " if err.filename else ""
        print(f"granbayes: error: {where}{err.strerror or err}", file=sys.stderr)
        return EXIT_INPUT


if __name__ == "__main__":
    raise SystemExit(main())
