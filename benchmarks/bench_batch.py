"""Benchmark of ``granbayes simulate --batch``: the command line against the kernel.

Measured in one run, on one machine, on N mixed jumps (default 100,000; seeded
``numpy.random.default_rng``): the five commands equally, ``phi`` and every force parameter
uniform over their realistic ranges (``granbayes.forces.typical_ranges``), and per-row
command settings (``freq_hz`` 8/10/12 Hz or empty, ``amplitude_mm``, ``delay_ms``,
``settle_periods``), written as a batch CSV with full-precision numbers (as
``DataFrame.to_csv`` writes them). Cost per jump, one numba thread:

a. **CLI process.** ``granbayes simulate --batch IN --out OUT --threads 1`` as a
   subprocess (wall time; import, numba cache load, read, validate, simulate, write), and
   the same on a one-row table (the fixed start-up cost of a process).
b. **CLI in-process.** ``granbayes._cli.main([...])`` with the same arguments (wall and CPU
   time), and where its time goes: reading the file, validating the cells, the simulation
   (the kernel, and the table and grouping code around it) and writing the output.
c. **The API.** ``granbayes.simulate`` on the same jumps, one call per command program
   (command and settings), in-process; and ``simulate_rows`` with all of them in one call.

The ratios (a)/(c) and (b)/(c) are of medians over rounds; each round runs a, b and c once,
in rotating order. Every time is taken as wall time and as CPU time (the process's, or the
child process's for (a)): all of it runs on one thread, so on an idle machine the two agree,
and on a shared one the CPU time is the measure that other processes do not inflate (the
load average is recorded). The CLI's heights are checked against (c), bit for bit. The
Markdown report is printed and saved with the JSON results in ``benchmarks/results/``
(``batch.json``, ``batch.md``).

Usage::

    python benchmarks/bench_batch.py              # full run (100,000 jumps, 7 rounds)
    python benchmarks/bench_batch.py --quick      # smoke run (10,000 jumps, 3 rounds)
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from _machine import machine_info, machine_markdown  # this folder

import granbayes
import granbayes._cli
import granbayes._measurements
import granbayes._simulator
import granbayes._tables
from granbayes._experiment import Experiment
from granbayes._simulator import build_rows, simulate, simulate_rows
from granbayes.commands import COMMAND_NAMES
from granbayes.forces import typical_ranges

BENCH_DIR = Path(__file__).resolve().parent
RESULTS_DIR = BENCH_DIR / "results"

#: Volume fractions [-] (uniform draws).
PHI_RANGE = (0.592, 0.632)
#: Per-row command settings: the values drawn uniformly per row ("" = not given: default).
SETTING_VALUES: dict[str, tuple[float | None, ...]] = {
    "freq_hz": (8.0, 10.0, 12.0, None),
    "amplitude_mm": (15.0, 20.0),
    "delay_ms": (25.0, 50.0),
    "settle_periods": (2.0, 3.0),
}
#: The issue's target: the CLI within this factor of ``granbayes.simulate`` per jump.
TARGET_RATIO = 1.2


# ----------------------------------------------------------------------------------------
# workload
def draw_table(n: int, seed: int) -> pd.DataFrame:
    """``n`` mixed jumps: commands, parameters and settings drawn uniformly.

    Parameters
    ----------
    n : int
        Number of jumps (rows).
    seed : int
        Seed of ``numpy.random.default_rng``.

    Returns
    -------
    pandas.DataFrame
        ``command``, ``phi``, every force parameter [SI] and the settings of
        :data:`SETTING_VALUES` (NaN: not given).
    """
    rng = np.random.default_rng(seed)
    table = {
        "command": np.asarray(COMMAND_NAMES, dtype=object)[rng.integers(0, 5, n)],
        "phi": rng.uniform(*PHI_RANGE, size=n),
    }
    for name, (low, high) in typical_ranges().items():
        table[name] = rng.uniform(low, high, size=n)
    for name, values in SETTING_VALUES.items():
        choices = np.array([np.nan if v is None else v for v in values])
        table[name] = choices[rng.integers(0, len(choices), n)]
    return pd.DataFrame(table)


def api_groups(table: pd.DataFrame) -> list[tuple[str, dict[str, float], np.ndarray]]:
    """The jumps of ``table`` per command program: command, settings and row indices."""
    defaults = Experiment().command
    settings = {name: table[name].fillna(float(getattr(defaults, name))) for name in SETTING_VALUES}
    keys = pd.DataFrame({"command": table["command"], **settings})
    groups = keys.groupby(list(keys.columns), sort=False).indices
    return [
        (key[0], dict(zip(SETTING_VALUES, map(float, key[1:]), strict=True)), rows)
        for key, rows in groups.items()
    ]


def run_api(
    table: pd.DataFrame, groups: list[tuple[str, dict[str, float], np.ndarray]]
) -> np.ndarray:
    """(c) ``granbayes.simulate`` per command program, one thread; heights [mm] per row."""
    heights = np.empty(len(table))
    params = {name: table[name].to_numpy() for name in typical_ranges()}
    phi = table["phi"].to_numpy()
    for command, settings, rows in groups:
        experiment = Experiment().replace(**settings)
        result = simulate(
            command,
            phi[rows],
            {name: values[rows] for name, values in params.items()},
            experiment=experiment,
            n_threads=1,
        )
        heights[rows] = result.height_mm
    return heights


def api_rows(
    table: pd.DataFrame, groups: list[tuple[str, dict[str, float], np.ndarray]]
) -> tuple[np.ndarray, list, np.ndarray]:
    """Integrator rows, programs and program index of every jump (for ``simulate_rows``)."""
    from granbayes.commands import CommandSettings, build_command

    params = {name: table[name].to_numpy() for name in typical_ranges()}
    rows = build_rows(Experiment().robot, table["phi"].to_numpy(), params)
    programs = [build_command(c, CommandSettings(**s)) for c, s, _ in groups]
    index = np.empty(len(table), dtype=np.int64)
    for number, (_, _, members) in enumerate(groups):
        index[members] = number
    return rows, programs, index


# ----------------------------------------------------------------------------------------
# timing helpers
def timed(fun: Callable[[], object]) -> tuple[float, float, object]:
    """Wall and process CPU time [s] of one call, and its result."""
    c0, t0 = time.process_time(), time.perf_counter()
    result = fun()
    return time.perf_counter() - t0, time.process_time() - c0, result


@contextlib.contextmanager
def phase_clock(phases: dict[str, float]) -> Iterator[None]:
    """Time the phases of the in-process CLI by wrapping the functions it calls.

    ``read`` (``_read_csv``), ``load`` (read + validate: ``_load_batch``), ``table``
    (``simulate_table``), ``kernel`` (``simulate_rows``, inside it), ``format`` (the
    results' text) and ``text`` (``_CsvTable.to_text``); CPU seconds, summed per call.
    """
    targets = [
        (granbayes._measurements, "_read_csv", "read"),
        (granbayes._cli, "_load_batch", "load"),
        (granbayes._cli, "simulate_table", "table"),
        (granbayes._simulator, "simulate_rows", "kernel"),
        (granbayes._cli, "_csv_numbers", "format"),
        (granbayes._tables._CsvTable, "to_text", "text"),
    ]
    saved = []
    for owner, name, phase in targets:
        original = getattr(owner, name)
        saved.append((owner, name, original))

        def wrapper(*args, _original=original, _phase=phase, **kwargs):
            t0 = time.process_time()
            try:
                return _original(*args, **kwargs)
            finally:
                phases[_phase] = phases.get(_phase, 0.0) + time.process_time() - t0

        setattr(owner, name, wrapper)
    try:
        yield
    finally:
        for owner, name, original in saved:
            setattr(owner, name, original)


def granbayes_program() -> list[str]:
    """The installed ``granbayes`` console script (or ``python -m granbayes._cli``)."""
    script = Path(sys.executable).with_name("granbayes")
    if script.is_file():
        return [str(script)]
    found = shutil.which("granbayes")
    return [found] if found else [sys.executable, "-m", "granbayes._cli"]


def _children_cpu() -> float:
    """CPU time [s] (user + system) of the finished child processes so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_process(argv: Sequence[str]) -> tuple[float, float]:
    """(a) Wall and CPU time [s] of one ``granbayes`` process."""
    c0, t0 = _children_cpu(), time.perf_counter()
    done = subprocess.run(
        [*granbayes_program(), *argv], capture_output=True, text=True, check=False
    )
    wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
    if done.returncode != 0:
        raise RuntimeError(f"granbayes {' '.join(argv)} failed: {done.stderr}")
    return wall, cpu


def run_in_process(argv: list[str]) -> tuple[float, float]:
    """(b) Wall and CPU time [s] of ``granbayes._cli.main(argv)`` (stderr silenced)."""
    with contextlib.redirect_stderr(io.StringIO()):
        wall, cpu, code = timed(lambda: granbayes._cli.main(argv))
    if code != 0:
        raise RuntimeError(f"granbayes._cli.main({argv}) exited {code}")
    return wall, cpu


# ----------------------------------------------------------------------------------------
# the benchmark
def bench(n: int, seed: int, rounds: int, folder: Path) -> dict:
    """Rounds of a, b and c (rotating order) on ``n`` jumps; medians and breakdown."""
    table = draw_table(n, seed)
    batch = folder / "batch.csv"
    t0 = time.perf_counter()
    table.to_csv(batch, index=False)
    write_s = time.perf_counter() - t0
    one_row = folder / "one.csv"
    table.iloc[:1].to_csv(one_row, index=False)
    out = folder / "out.csv"
    argv = ["simulate", "--batch", str(batch), "--out", str(out), "--threads", "1"]
    argv_one = ["simulate", "--batch", str(one_row), "--out", str(folder / "one-out.csv")]
    argv_one += ["--threads", "1"]
    groups = api_groups(table)
    rows, programs, index = api_rows(table, groups)

    # warm-up: numba cache load / compilation, pandas' and the CLI's first calls
    reference = run_api(table, groups)
    run_in_process(argv)
    run_process(argv_one)

    keys = ("a", "a_start", "b", "c", "c_rows")
    times: dict[str, list[float]] = {k + suffix: [] for k in keys for suffix in ("", "_cpu")}
    phases: list[dict[str, float]] = []
    loads = []

    def record(key: str, wall_cpu: tuple[float, float]) -> None:
        times[key].append(wall_cpu[0])
        times[key + "_cpu"].append(wall_cpu[1])

    for r in range(rounds):
        order = ["a", "b", "c"][r % 3 :] + ["a", "b", "c"][: r % 3]
        print(f"round {r + 1}/{rounds}: {' '.join(order)}", file=sys.stderr, flush=True)
        loads.append(os.getloadavg()[0])
        for step in order:
            if step == "a":
                record("a", run_process(argv))
            elif step == "b":
                record("b", run_in_process(argv))
            else:
                record("c", timed(lambda: run_api(table, groups))[:2])
        record("a_start", run_process(argv_one))
        record("c_rows", timed(lambda: simulate_rows(rows, programs, index, n_threads=1))[:2])
        spent: dict[str, float] = {}
        with phase_clock(spent):
            spent["total"] = run_in_process(argv)[1]
        phases.append(spent)

    result = pd.read_csv(out)
    same = np.array_equal(result["height_mm"].to_numpy(), reference, equal_nan=True)
    per_jump = {key: [t / n * 1e6 for t in values] for key, values in times.items()}
    median = {key: statistics.median(values) for key, values in per_jump.items()}
    rounds_parts = []
    for spent in phases:  # per round: the phases, and what is left of the total
        parts = {
            "read the file (CSV to cells)": spent["read"],
            "validate (cells to numbers, checks)": spent["load"] - spent["read"],
            "simulate: kernel (simulate_rows)": spent["kernel"],
            "simulate: table and grouping": spent["table"] - spent["kernel"],
            "write: format heights and statuses": spent["format"],
            "write: CSV text (to_text)": spent["text"],
        }
        parts["write: file, and the rest of the CLI"] = spent["total"] - sum(parts.values())
        rounds_parts.append(parts)
    parts = {
        key: statistics.median(p[key] for p in rounds_parts) / n * 1e6 for key in rounds_parts[0]
    }
    total_us = statistics.median(spent["total"] for spent in phases) / n * 1e6
    ratios = {}
    for clock in ("", "_cpu"):
        c = median["c" + clock]
        ratios["a_c" + clock] = median["a" + clock] / c
        ratios["a_minus_start_c" + clock] = (median["a" + clock] - median["a_start" + clock]) / c
        ratios["b_c" + clock] = median["b" + clock] / c
        ratios["c_rows_c" + clock] = median["c_rows" + clock] / c
    return {
        "n_jumps": n,
        "n_programs": len(groups),
        "load_per_round": loads,
        "input_mb": batch.stat().st_size / 1e6,
        "input_write_s": write_s,
        "heights_equal_api_bitwise": bool(same),
        "failed_jumps": int((result["status"] != "ok").sum()),
        "us_per_jump": per_jump,
        "median_us_per_jump": median,
        "ratios": ratios,
        "breakdown_us_per_jump": parts,
        "breakdown_total_us_per_jump": total_us,
    }


# ----------------------------------------------------------------------------------------
# report
def _ok(flag: bool) -> str:
    return "yes" if flag else "**NO**"


def render_markdown(results: dict) -> str:
    """The Markdown report of a benchmark run."""
    cfg, r, mi = results["config"], results["batch"], results["machine"]
    m = r["median_us_per_jump"]
    rounds = cfg["rounds"]
    lines = [
        "# Batch CLI benchmark",
        "",
        f"Mode: {cfg['mode']}; {r['n_jumps']:,} jumps (seed {cfg['seed']}), "
        f"{r['n_programs']} command programs, input {r['input_mb']:.1f} MB; medians over "
        f"{rounds} interleaved rounds, one numba thread. Load average (1 min) at start / "
        f"end: {cfg['load_start']:.2f} / {results['load_end']:.2f} on {mi['cpu_count']} "
        "cores.",
        "",
        "Jumps: the five commands (uniform), `phi` and all seven force parameters uniform "
        "over their realistic ranges, `freq_hz` 8/10/12 Hz or empty (default), "
        "`amplitude_mm`, `delay_ms` and `settle_periods` two values each; numbers written "
        "with full precision (`DataFrame.to_csv`).",
        "",
        "| measure | wall us/jump | / (c) | CPU us/jump | / (c) |",
        "|---|---:|---:|---:|---:|",
    ]
    rows = [
        ("(a) `granbayes simulate --batch` process", "a", "a_c"),
        ("(a) start-up of a process (one-row table), per jump of the batch", "a_start", None),
        ("(a) minus start-up", None, "a_minus_start_c"),
        ("(b) `granbayes._cli.main`, in-process", "b", "b_c"),
        ("(c) `granbayes.simulate` per command program, in-process", "c", None),
        ("(c) `simulate_rows`, all programs in one call", "c_rows", "c_rows_c"),
    ]
    ratio = r["ratios"]
    for label, key, ratio_key in rows:
        cells = []
        for clock in ("", "_cpu"):
            value = m[key + clock] if key else m["a" + clock] - m["a_start" + clock]
            shown = (
                f"{ratio[ratio_key + clock]:.2f}" if ratio_key else ("1.00" if key == "c" else "")
            )
            cells += [f"{value:.1f}", shown]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    b_ok, a_ok = ratio["b_c_cpu"] <= TARGET_RATIO, ratio["a_c_cpu"] <= TARGET_RATIO
    lines += [
        "",
        f"Target (issue): the CLI within {TARGET_RATIO}x of `granbayes.simulate` per jump. "
        f"In-process (b)/(c) = {ratio['b_c_cpu']:.2f} CPU, {ratio['b_c']:.2f} wall: "
        f"{_ok(b_ok)} (on CPU time); process (a)/(c) = {ratio['a_c_cpu']:.2f} CPU, "
        f"{ratio['a_c']:.2f} wall: {_ok(a_ok)}, of which the start-up of a process "
        f"(imports, numba cache load) is {m['a_start_cpu'] / m['c_cpu']:.2f}; without it "
        f"{ratio['a_minus_start_c_cpu']:.2f}. The CLI's heights equal (c)'s bit for bit: "
        f"{_ok(r['heights_equal_api_bitwise'])}; failed jumps: {r['failed_jumps']}. Load "
        f"average (1 min) at the start of each round: "
        f"{', '.join(f'{x:.1f}' for x in r['load_per_round'])}.",
        "",
        "## Where the in-process CLI's time goes",
        "",
        "One instrumented `main` call per round (wrapped functions; CPU time); each phase is "
        "its median over the rounds, so the phases need not add up to the median total.",
        "",
        "| phase | us/jump | share |",
        "|---|---:|---:|",
    ]
    total = r["breakdown_total_us_per_jump"]
    for phase, value in r["breakdown_us_per_jump"].items():
        lines.append(f"| {phase} | {value:.2f} | {value / total:.1%} |")
    kernel = r["breakdown_us_per_jump"]["simulate: kernel (simulate_rows)"]
    lines += [
        f"| total | {total:.2f} | |",
        "",
        f"Within these runs, everything but the kernel costs {total - kernel:.2f} us/jump: the "
        f"CLI takes {total / kernel:.2f}x the time of the kernel it runs (a ratio that does "
        "not depend on comparing separate runs).",
        "",
    ]
    lines += ["## Every round", "", "| round | " + " | ".join(r["us_per_jump"]) + " |"]
    lines.append("|---|" + "---:|" * len(r["us_per_jump"]))
    for i in range(rounds):
        cells = " | ".join(f"{values[i]:.1f}" for values in r["us_per_jump"].values())
        lines.append(f"| {i + 1} | {cells} |")
    lines += ["", *machine_markdown(mi)]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------
def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command-line options (``argv`` as for ``argparse``; ``None``: ``sys.argv``)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10,000 jumps, 3 rounds")
    parser.add_argument("--n-jumps", type=int, help="jumps (default 100,000)")
    parser.add_argument("--rounds", type=int, help="interleaved rounds (default 7)")
    parser.add_argument("--seed", type=int, default=20261126, help="workload seed")
    parser.add_argument(
        "--out",
        type=Path,
        help="JSON output (default benchmarks/results/batch.json, or batch-quick.json)",
    )
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print the Markdown report and save the results."""
    args = parse_args(argv)
    quick = args.quick
    n = args.n_jumps or (10_000 if quick else 100_000)
    rounds = args.rounds or (3 if quick else 7)
    config = {
        "mode": "quick" if quick else "full",
        "n_jumps": n,
        "rounds": rounds,
        "seed": args.seed,
        "load_start": os.getloadavg()[0],
    }
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench-batch-") as folder:
        batch = bench(n, args.seed, rounds, Path(folder))
    results = {
        "config": config,
        "batch": batch,
        "load_end": os.getloadavg()[0],
        "machine": machine_info(("numpy", "pandas", "numba")),
        "total_wall_s": time.perf_counter() - t_start,
    }
    report = render_markdown(results)
    print(report)
    out = args.out or RESULTS_DIR / ("batch-quick.json" if quick else "batch.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")
    out.with_suffix(".md").write_text(report)
    print(f"results: {out} (report: {out.with_suffix('.md')})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
