"""Shared plumbing of the analysis scripts: arguments, data, fits, figures and summaries.

Every analysis script in this folder is ``python analyses/<name>.py [DIR] --out OUT
[--seed N] [--fast]``: it reads an experiment folder (default: the SYNTHETIC reference data
set), writes its figures (PNG for screens, PDF for papers), ``summary.md`` and
``summary.json`` to ``OUT`` and prints the summary. ``OUT`` is replaced only when the
analysis succeeds (it is built in ``OUT.partial``), so a failed run never destroys earlier
results. ``--fast`` shortens chains and coarsens grids (for tests and quick looks); the
numbers it prints are then rough.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

import granbayes
from granbayes import REFERENCE_DATA as _REFERENCE_DATA
from granbayes import (
    Experiment,
    FitResult,
    FitSettings,
    InputError,
    SamplerSettings,
    data_hash,
    fit,
    load_experiment,
    load_jumps,
)
from granbayes.figures import source_label
from granbayes.forces import terms_of
from granbayes.report import environment, staged_folder
from granbayes.report import markdown_table as _markdown_table
from granbayes.stats import CI_PROB

#: The shipped SYNTHETIC reference data set (package data; data/generate_reference.py, seed
#: 20261121).
REFERENCE_DATA = _REFERENCE_DATA


@dataclass
class Context:
    """What every analysis gets: the data, where to write, and how hard to work.

    Attributes
    ----------
    name : str
        Analysis name (the script's stem).
    data : Path
        Experiment folder.
    out : Path
        Work folder (``OUT.partial``; becomes ``OUT`` on success).
    seed : int
        Master seed of everything random in the analysis.
    fast : bool
        Short chains and coarse grids.
    experiment : Experiment
    table : pandas.DataFrame
        Validated jumps.
    label : str
        ``"SYNTHETIC data (...)"`` when the rows say so, else ``""``.
    args : argparse.Namespace
    """

    name: str
    data: Path
    out: Path
    seed: int
    fast: bool
    experiment: Experiment
    table: pd.DataFrame
    label: str
    args: argparse.Namespace
    written: list[str] = field(default_factory=list)

    def rng(self, offset: int = 0) -> np.random.Generator:
        """A generator seeded from the master seed (``offset`` separates streams)."""
        return np.random.default_rng([self.seed, offset])

    def title(self, text: str) -> str:
        """A figure title with the data label (synthetic data are always marked)."""
        where = self.label or f"data: {self.data.name}"
        return f"{text}\n{where}"

    @property
    def phis(self) -> np.ndarray:
        """Volume fractions present in the data, ascending."""
        return np.unique(self.table["phi"].to_numpy(float))

    @property
    def phi_c(self) -> float:
        """Critical packing of the experiment."""
        return float(self.experiment.phi_c)

    def save_figure(self, fig: Figure, stem: str) -> None:
        """Write ``stem.png`` (150 dpi) and ``stem.pdf`` (vector, for papers)."""
        for ext, kw in (("png", {"dpi": 150}), ("pdf", {})):
            fig.savefig(self.out / f"{stem}.{ext}", **kw)
        self.written += [f"{stem}.png", f"{stem}.pdf"]

    def save_table(self, table: pd.DataFrame, stem: str) -> None:
        """Write ``stem.csv``."""
        table.to_csv(self.out / f"{stem}.csv", index=False)
        self.written.append(f"{stem}.csv")


def parser(doc: str | None) -> argparse.ArgumentParser:
    """The arguments every analysis takes (description: the script's docstring)."""
    text = (doc or "").strip()
    p = argparse.ArgumentParser(
        description=text.splitlines()[0] if text else None,
        epilog="\n".join(text.splitlines()[1:]).strip() or None,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "data",
        metavar="DIR",
        type=Path,
        nargs="?",
        default=REFERENCE_DATA,
        help="experiment folder (default: the SYNTHETIC reference data set)",
    )
    p.add_argument("--out", metavar="OUT", type=Path, required=True, help="output folder")
    p.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    p.add_argument(
        "--fast", action="store_true", help="short chains and coarse grids (rough numbers)"
    )
    p.add_argument(
        "--threads",
        type=int,
        metavar="N",
        help="numba threads of the simulator (default: all cores; use 1 when several "
        "analyses run side by side, threads competing for cores slow every fit 3-5x)",
    )
    return p


def main(
    name: str,
    doc: str | None,
    analysis: Callable[[Context], tuple[str, dict]],
    argv: Sequence[str] | None = None,
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None,
) -> int:
    """Parse arguments, load the data, run ``analysis`` in a staged folder, write summaries.

    ``analysis(ctx)`` writes its figures and tables into ``ctx.out`` and returns the
    Markdown body of its summary and a JSON-ready dict of its key numbers.

    Returns
    -------
    int
        Exit code: 0 success, 2 bad input.
    """
    p = parser(doc)
    if add_arguments is not None:
        add_arguments(p)
    args = p.parse_args(argv)
    if args.threads is not None:
        if args.threads < 1:
            p.error("--threads must be >= 1")
        import numba

        numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    try:
        experiment = load_experiment(args.data)
        table = load_jumps(args.data, experiment)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:  # an error inside leaves OUT untouched (OUT.partial is left for inspection)
        with staged_folder(out, resume=False) as work:
            ctx = Context(
                name=name,
                data=Path(args.data),
                out=work,
                seed=int(args.seed),
                fast=bool(args.fast),
                experiment=experiment,
                table=table,
                label=source_label(table["source"]) if "source" in table else "",
                args=args,
            )
            body, numbers = analysis(ctx)
            seconds = time.perf_counter() - t0
            heading = (doc or name).strip().splitlines()[0].rstrip(".")
            provenance = {
                "analysis": name,
                "data": str(ctx.data),
                "data_sha256": data_hash(experiment, table),
                "data_label": ctx.label or "measured (no synthetic marker in the source column)",
                "seed": ctx.seed,
                "fast": ctx.fast,
                "interval": f"{CI_PROB:.0%} equal-tailed",
                "granbayes": granbayes.__version__,
                **environment(),  # package versions and the machine
                "runtime_s": round(seconds, 1),
            }
            lines = [f"# {heading}", ""]
            if ctx.label:
                lines += [f"**{ctx.label}** — not measured.", ""]
            lines += [body.strip(), ""]
            lines += [
                "---",
                f"Data `{ctx.data}` (sha256 {provenance['data_sha256'][:12]}…), seed {ctx.seed}"
                + (", **fast mode (short chains, coarse grids)**" if ctx.fast else "")
                + f"; intervals are {CI_PROB:.0%} equal-tailed; {seconds:.0f} s.",
                "Files: " + ", ".join(f"`{w}`" for w in ctx.written),
                "",
            ]
            (work / "summary.md").write_text("\n".join(lines))
            (work / "summary.json").write_text(
                json.dumps({**provenance, "results": _jsonable(numbers)}, indent=2) + "\n"
            )
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print("\n".join(lines))
    print(f"wrote {out}/")
    return 0


def _jsonable(value: object) -> object:
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.bool_ | bool):
        return bool(value)
    if isinstance(value, np.integer | int):
        return int(value)
    if isinstance(value, np.floating | float):
        return float(value) if math.isfinite(value) else None
    return value


# ----------------------------------------------------------------------------------------
def sampler_settings(fast: bool) -> SamplerSettings:
    """The converged default of ``granbayes fit``, or short capped chains in fast mode."""
    if fast:
        return SamplerSettings(n_ensembles=2, max_steps=400, min_ess=100, n_draws=40)
    return SamplerSettings()


def run_fit(
    ctx: Context,
    table: pd.DataFrame | granbayes.Measurements,
    terms: Sequence[str],
    *,
    phi_mode: str = "per_phi",
    seed_offset: int = 0,
) -> FitResult:
    """A granbayes fit of ``terms`` with the analysis's chain settings.

    ``table`` is jumps, or measurements of several kinds.
    """
    config = FitSettings(terms=tuple(terms), phi_mode=phi_mode, sampler=sampler_settings(ctx.fast))
    result = fit(
        ctx.experiment,
        table.reset_index(drop=True) if isinstance(table, pd.DataFrame) else table,
        config,
        seed=ctx.seed + seed_offset,
        data_source=str(ctx.data),
    )
    for w in result.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return result


def markdown_table(df: pd.DataFrame, floatfmt: str = ".4g") -> str:
    """A GitHub Markdown table; non-finite numbers are left blank."""
    return _markdown_table(df, floatfmt, missing="")


def parse_terms(text: str) -> tuple[str, ...]:
    """The force terms of a ``--terms`` value (``"depth,drag"``); InputError if unknown."""
    try:
        return terms_of([t.strip() for t in str(text).split(",") if t.strip()])
    except (KeyError, ValueError) as exc:
        raise InputError(f"--terms {text!r}: {exc}") from None
