"""Benchmark of the compiled simulator: compile time, cost, accuracy, solve_ivp, memory.

Measured in one run, on one machine:

a. **Compile time.** ``import granbayes; granbayes.simulate("single", 0.612, {"k": 3000.0})``
   in a fresh process with an empty ``NUMBA_CACHE_DIR`` (cold compile), then in a second
   fresh process with the same cache directory (warm cache load).
b. **Mixed workload.** N jumps (default 5000), the five commands equally, force parameters
   drawn uniformly over realistic ranges (seeded). Cost per jump on one thread (median of 5
   timed runs after a warm-up), per command, accuracy against
   ``SolverSettings.converged()`` and the two-thread throughput.
c. **solve_ivp comparison.** A subset of the same jumps with the plain
   ``scipy.integrate.solve_ivp`` implementation of ``granbayes.testing`` and with
   granbayes, timed in the same run.
d. **Memory.** Peak resident memory of a 100,000-jump batch (in a fresh process).

The machine may be shared, so every time is a median over repeats and the implementations
are compared in the same run. The Markdown report is printed and saved with the JSON
results in ``benchmarks/results/``.

Usage::

    python benchmarks/bench_simulator.py            # full run (about a minute on 2 cores)
    python benchmarks/bench_simulator.py --quick    # smoke run
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
import tracemalloc
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np
from _machine import machine_info, machine_markdown  # this folder

import granbayes
from granbayes._experiment import Robot
from granbayes._simulator import SolverSettings, Status, build_rows, simulate_rows
from granbayes.commands import COMMAND_NAMES, CommandProgram, build_command
from granbayes.forces import typical_ranges
from granbayes.testing import simulate_height_scipy

BENCH_DIR = Path(__file__).resolve().parent
RESULTS_DIR = BENCH_DIR / "results"

#: Realistic ranges of the force parameters [SI] (uniform draws).
PARAMETER_RANGES: dict[str, tuple[float, float]] = typical_ranges(
    ("k", "c_d", "kappa", "r_unload", "k2", "b")
)
PHI_RANGE = (0.592, 0.632)
UNITS = {"k": "N/m", "c_d": "kg/m", "kappa": "-", "r_unload": "-", "k2": "N/m^2", "b": "N s/m"}

#: Targets the report checks.
TARGET_MAX_ERROR_MM = 0.05
TARGET_US_PER_JUMP = 100.0
TARGET_SCIPY_RATIO = 300.0
TARGET_MEMORY_MB = 1024.0

#: solve_ivp settings: the headline (accuracy comparable to or better than granbayes'
#: defaults) and the tolerances of granbayes' defaults themselves, for reference.
SCIPY_SETTINGS: dict[str, dict] = {
    "RK45, rtol 1e-6, atol 1e-9": {"method": "RK45", "rtol": 1e-6, "atol": 1e-9},
    "RK45, granbayes tolerances (rtol 1e-5, atol 1e-7 m, 1e-5 m/s)": {
        "method": "RK45",
        "rtol": 1e-5,
        "atol": [1e-7, 1e-7, 1e-5, 1e-5],
    },
}

COMPILE_SNIPPET = textwrap.dedent(
    """
    import json, time
    t0 = time.perf_counter()
    import granbayes
    t1 = time.perf_counter()
    granbayes.simulate("single", 0.612, {"k": 3000.0})
    t2 = time.perf_counter()
    print(json.dumps({"import_s": t1 - t0, "first_call_s": t2 - t1, "total_s": t2 - t0}))
    """
)


# ----------------------------------------------------------------------------------------
# workload
@dataclass(frozen=True)
class Workload:
    """A batch of jumps: integrator rows, command of each row and the drawn values.

    Attributes
    ----------
    rows : ndarray, shape (n, len(ROW_FIELDS))
        Integrator input rows (default robot).
    command_index : ndarray of int, shape (n,)
        Index into :data:`COMMAND_NAMES` (and :func:`programs`) per jump.
    phi : ndarray, shape (n,)
        Volume fractions.
    params : dict of str to ndarray
        Force parameters per jump [SI].
    seed : int
        Seed of the numpy Generator that drew them.
    """

    rows: np.ndarray
    command_index: np.ndarray
    phi: np.ndarray
    params: dict[str, np.ndarray]
    seed: int

    def __len__(self) -> int:
        return len(self.command_index)

    def subset(self, index: np.ndarray) -> Workload:
        """The jumps at ``index`` (integer or boolean array)."""
        return Workload(
            rows=self.rows[index],
            command_index=self.command_index[index],
            phi=self.phi[index],
            params={name: v[index] for name, v in self.params.items()},
            seed=self.seed,
        )


def draw_workload(n: int, seed: int) -> Workload:
    """Draw ``n`` jumps: the five commands in turn, parameters uniform over their ranges.

    Parameters
    ----------
    n : int
        Number of jumps.
    seed : int
        Seed of ``numpy.random.default_rng``.

    Returns
    -------
    Workload
    """
    rng = np.random.default_rng(seed)
    phi = rng.uniform(*PHI_RANGE, size=n)
    params = {name: rng.uniform(lo, hi, size=n) for name, (lo, hi) in PARAMETER_RANGES.items()}
    command_index = np.arange(n, dtype=np.int64) % len(COMMAND_NAMES)
    rows = build_rows(Robot(), phi, params)
    return Workload(rows, command_index, phi, params, seed)


@functools.cache
def programs() -> tuple[CommandProgram, ...]:
    """The five commands with default settings, in :data:`COMMAND_NAMES` order."""
    return tuple(build_command(name) for name in COMMAND_NAMES)


def run(
    workload: Workload, options: SolverSettings | None = None, n_threads: int = 1
) -> granbayes.Heights:
    """Simulate a workload with one program per command."""
    return simulate_rows(
        workload.rows,
        programs(),
        workload.command_index,
        settings=options,
        n_threads=n_threads,
    )


def repeat_timed(
    fun: Callable[[], object], repeats: int, warmup: int = 1, cpu: list[float] | None = None
) -> list[float]:
    """Wall times [s] of ``repeats`` calls of ``fun`` after ``warmup`` untimed calls.

    If ``cpu`` is given, the process CPU times [s] of the calls are appended to it (on one
    thread, a check of the wall times that is insensitive to other processes' load).
    """
    for _ in range(warmup):
        fun()
    times = []
    for _ in range(repeats):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fun()
        times.append(time.perf_counter() - t0)
        if cpu is not None:
            cpu.append(time.process_time() - c0)
    return times


def threads_used(requested: int) -> int:
    """Threads the simulator actually uses for ``n_threads=requested``."""
    return max(1, min(requested, numba.config.NUMBA_NUM_THREADS))


# ----------------------------------------------------------------------------------------
# a. compile time
def bench_compile() -> dict:
    """First-call time in fresh processes: empty numba cache, then the cache it filled."""
    out: dict = {"snippet": 'import granbayes; granbayes.simulate("single", 0.612, {"k": 3000.0})'}
    with tempfile.TemporaryDirectory(prefix="numba-cache-") as cache_dir:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache_dir}
        for label in ("cold", "warm"):
            t0 = time.perf_counter()
            proc = subprocess.run(
                [sys.executable, "-c", COMPILE_SNIPPET],
                env=env,
                capture_output=True,
                text=True,
                check=True,
            )
            wall = time.perf_counter() - t0
            record = json.loads(proc.stdout.strip().splitlines()[-1])
            record["process_wall_s"] = wall
            record["cache_files"] = sum(len(files) for _, _, files in os.walk(cache_dir))
            out[label] = record
    return out


# ----------------------------------------------------------------------------------------
# b. mixed workload
def bench_workload(workload: Workload, repeats: int) -> tuple[dict, np.ndarray, np.ndarray]:
    """Cost, per-command cost, accuracy and two-thread throughput of the workload.

    Returns
    -------
    results : dict
    heights_default, heights_converged : ndarray
        Heights [mm] of the workload with default and converged settings.
    """
    n = len(workload)
    res = run(workload)  # warm-up
    masks = [workload.command_index == c for c in range(len(COMMAND_NAMES))]
    subsets = [workload.subset(mask) for mask in masks]
    # one thread: the whole batch and each command's jumps, in rounds, so that all of them
    # see the same load of the (shared) machine
    one: list[float] = []
    one_cpu: list[float] = []
    command_times: list[list[float]] = [[] for _ in subsets]
    for _ in range(repeats):
        one += repeat_timed(lambda: run(workload), 1, warmup=0, cpu=one_cpu)
        for times, sub in zip(command_times, subsets, strict=True):
            times += repeat_timed(lambda sub=sub: run(sub), 1, warmup=0)
    two_threads = threads_used(2)
    two = repeat_timed(lambda: run(workload, n_threads=2), repeats)
    t0 = time.perf_counter()
    conv = run(workload, SolverSettings.converged(), n_threads=2)
    t_conv = time.perf_counter() - t0
    ok = (res.status == Status.OK) & (conv.status == Status.OK)
    err = np.abs(res.height_mm - conv.height_mm)
    err_ok = err[ok]
    per_command = {}
    for name, mask, times in zip(COMMAND_NAMES, masks, command_times, strict=True):
        e = err[mask & ok]
        per_command[name] = {
            "n": int(mask.sum()),
            "us_per_jump_median": statistics.median(times) / int(mask.sum()) * 1e6,
            "mean_steps": float(res.n_steps[mask].mean()),
            "max_error_mm": float(e.max()) if e.size else float("nan"),
            "p99_error_mm": float(np.percentile(e, 99)) if e.size else float("nan"),
        }
    us = statistics.median(one) / n * 1e6
    results = {
        "n_jumps": n,
        "seed": workload.seed,
        "repeats": repeats,
        "parameter_ranges": PARAMETER_RANGES,
        "phi_range": PHI_RANGE,
        "one_thread": {
            "batch_times_s": one,
            "us_per_jump_median": us,
            "cpu_times_s": one_cpu,
            "cpu_us_per_jump_median": statistics.median(one_cpu) / n * 1e6,
            "jumps_per_s": n / statistics.median(one),
        },
        "two_threads": {
            "threads_used": two_threads,
            "batch_times_s": two,
            "us_per_jump_median": statistics.median(two) / n * 1e6,
            "jumps_per_s": n / statistics.median(two),
            "speedup": statistics.median(one) / statistics.median(two),
        },
        "converged_reference": {
            "options": "SolverSettings.converged()",
            "wall_s_two_threads": t_conv,
            "mean_steps": float(conv.n_steps.mean()),
        },
        "mean_steps": float(res.n_steps.mean()),
        "failed_default": int((res.status != Status.OK).sum()),
        "failed_converged": int((conv.status != Status.OK).sum()),
        "max_error_mm": float(err_ok.max()),
        "p99_error_mm": float(np.percentile(err_ok, 99)),
        "mean_error_mm": float(err_ok.mean()),
        "per_command": per_command,
        "meets_targets": bool(err_ok.max() <= TARGET_MAX_ERROR_MM and us <= TARGET_US_PER_JUMP),
    }
    return results, res.height_mm, conv.height_mm


# ----------------------------------------------------------------------------------------
# c. solve_ivp comparison
def bench_scipy(
    workload: Workload,
    converged_mm: np.ndarray,
    per_command: int,
    repeats_scipy: int,
    repeats: int,
) -> dict:
    """Time solve_ivp and granbayes on the first ``per_command`` jumps of each command."""
    pick = np.concatenate(
        [
            np.flatnonzero(workload.command_index == c)[:per_command]
            for c in range(len(COMMAND_NAMES))
        ]
    )
    sub = workload.subset(pick)
    reference = converged_mm[pick]
    n = len(sub)
    jumps = [
        (
            COMMAND_NAMES[sub.command_index[i]],
            float(sub.phi[i]),
            {name: float(v[i]) for name, v in sub.params.items()},
        )
        for i in range(n)
    ]
    out: dict = {"n_jumps": n, "per_command": per_command, "scipy": {}, "granbayes": {}}
    for label, settings in SCIPY_SETTINGS.items():
        per_jump = np.empty((repeats_scipy, n))
        heights = np.empty(n)
        for r in range(repeats_scipy):
            for i, (command, phi, params) in enumerate(jumps):
                t0 = time.perf_counter()
                heights[i] = simulate_height_scipy(command, phi, params, **settings)
                per_jump[r, i] = time.perf_counter() - t0
        med = np.median(per_jump, axis=0)  # per jump, over repeats
        out["scipy"][label] = {
            "settings": {**settings, "max_step": 0.01},
            "repeats": repeats_scipy,
            "ms_per_jump_median": float(np.median(med)) * 1e3,
            "ms_per_jump_mean": float(np.mean(med)) * 1e3,
            "max_error_mm": float(np.max(np.abs(heights - reference))),
        }
    # granbayes, on one thread: per jump (a batch of copies of that jump, so that the call
    # overhead is amortised), one batch of all the jumps, and one call per jump
    copies = 20
    per_jump = np.empty(n)
    single = np.empty(n)
    for i in range(n):
        jump = sub.subset(np.full(copies, i))
        per_jump[i] = statistics.median(repeat_timed(lambda jump=jump: run(jump), repeats))
        per_jump[i] /= copies
        one = sub.subset(np.array([i]))
        single[i] = statistics.median(repeat_timed(lambda one=one: run(one), repeats))
    batch = repeat_timed(lambda: run(sub), repeats)
    heights = run(sub).height_mm
    out["granbayes"] = {
        "settings": "SolverSettings() defaults, n_threads=1",
        "repeats": repeats,
        "copies_per_jump": copies,
        "us_per_jump_median": float(np.median(per_jump)) * 1e6,
        "us_per_jump_mean": float(np.mean(per_jump)) * 1e6,
        "us_per_jump_batch": statistics.median(batch) / n * 1e6,
        "us_single_call_median": float(np.median(single)) * 1e6,
        "max_error_mm": float(np.max(np.abs(heights - reference))),
    }
    headline = out["scipy"][next(iter(SCIPY_SETTINGS))]
    gb = out["granbayes"]
    out["ratio_median"] = headline["ms_per_jump_median"] * 1e3 / gb["us_per_jump_median"]
    out["ratio_mean_batch"] = headline["ms_per_jump_mean"] * 1e3 / gb["us_per_jump_batch"]
    out["ratio_single_call"] = headline["ms_per_jump_median"] * 1e3 / gb["us_single_call_median"]
    out["meets_target"] = bool(out["ratio_median"] >= TARGET_SCIPY_RATIO)
    return out


# ----------------------------------------------------------------------------------------
# d. memory (in a fresh process, so that the peak is this batch's)
def _max_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def memory_child(n: int, seed: int, n_threads: int) -> dict:
    """Peak memory of drawing and simulating ``n`` jumps in one batch (this process).

    The timed pass runs without tracemalloc: its hooks serialise the integrator's threads.
    A second pass under tracemalloc reports the peak of the traced (numpy) allocations.
    """
    run(draw_workload(10, seed), n_threads=n_threads)  # load the compiled code, start threads
    rss0 = _max_rss_mb()
    t0 = time.perf_counter()
    workload = draw_workload(n, seed)
    t1 = time.perf_counter()
    res = run(workload, n_threads=n_threads)
    t2 = time.perf_counter()
    rss1 = _max_rss_mb()
    del workload, res
    tracemalloc.start()
    res = run(draw_workload(n, seed), n_threads=n_threads)
    traced_peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return {
        "n_jumps": n,
        "threads_used": threads_used(n_threads),
        "draw_s": t1 - t0,
        "simulate_s": t2 - t1,
        "us_per_jump": (t2 - t1) / n * 1e6,
        "max_rss_before_mb": rss0,
        "max_rss_after_mb": rss1,
        "max_rss_increase_mb": rss1 - rss0,
        "tracemalloc_peak_mb": traced_peak,
        "failed": int((res.status != Status.OK).sum()),
    }


def bench_memory(n: int, seed: int, n_threads: int = 2) -> dict:
    """Run :func:`memory_child` in a fresh process and return its results."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--memory-child", str(n)]
    cmd += ["--seed", str(seed), "--threads", str(n_threads)]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=True)
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["meets_target"] = bool(out["max_rss_increase_mb"] < TARGET_MEMORY_MB)
    return out


# ----------------------------------------------------------------------------------------
# report
def _ok(flag: bool) -> str:
    return "yes" if flag else "**NO**"


def render_markdown(results: dict) -> str:
    """The Markdown report of a benchmark run."""
    lines: list[str] = []
    add = lines.append
    cfg = results["config"]
    add("# Simulator benchmark")
    add("")
    add(
        f"Mode: {cfg['mode']}; {cfg['n_jumps']} jumps (seed {cfg['seed']}); timings are "
        f"medians over {cfg['repeats']} runs after a warm-up. Load average (1 min) at start / "
        f"end: {cfg['load_start']:.2f} / {results['load_end']:.2f}."
    )
    add("")
    if "compile" in results:
        c = results["compile"]
        add("## a. First-call compile time")
        add("")
        add(f"`{c['snippet']}` in a fresh process, `NUMBA_CACHE_DIR` set to a new empty folder.")
        add("")
        add("| run | import [s] | first call [s] | import + call [s] | process wall [s] |")
        add("|---|---:|---:|---:|---:|")
        for label, text in (("cold", "cold (empty cache)"), ("warm", "warm (cache load)")):
            r = c[label]
            add(
                f"| {text} | {r['import_s']:.2f} | {r['first_call_s']:.2f} | "
                f"{r['total_s']:.2f} | {r['process_wall_s']:.2f} |"
            )
        add("")
    w = results["workload"]
    ranges = ", ".join(
        f"{name} {lo:g}-{hi:g} {UNITS[name]}" for name, (lo, hi) in w["parameter_ranges"].items()
    )
    add("## b. Mixed workload")
    add("")
    add(
        f"{w['n_jumps']} jumps, the five commands equally, default robot; uniform draws "
        f"(numpy Generator, seed {w['seed']}): {ranges}, phi {w['phi_range'][0]}-"
        f"{w['phi_range'][1]}. One `simulate_rows` batch with one program per command; "
        "errors against the same batch with `SolverSettings.converged()`. On one thread the "
        "whole batch and the per-command batches are timed in alternating rounds."
    )
    add("")
    add("| measure | value | target | met |")
    add("|---|---:|---:|---|")
    us = w["one_thread"]["us_per_jump_median"]
    add(
        f"| cost, 1 thread | {us:.1f} us/jump | <= {TARGET_US_PER_JUMP:g} | "
        f"{_ok(us <= TARGET_US_PER_JUMP)} |"
    )
    cpu_us = w["one_thread"]["cpu_us_per_jump_median"]
    add(f"| cost, 1 thread, process CPU time (load check) | {cpu_us:.1f} us/jump | | |")
    add(f"| throughput, 1 thread | {w['one_thread']['jumps_per_s']:,.0f} jumps/s | | |")
    t2 = w["two_threads"]
    add(
        f"| throughput, {t2['threads_used']} threads | {t2['jumps_per_s']:,.0f} jumps/s "
        f"({t2['speedup']:.2f}x) | | |"
    )
    add(
        f"| max abs error | {w['max_error_mm']:.4f} mm | <= {TARGET_MAX_ERROR_MM:g} | "
        f"{_ok(w['max_error_mm'] <= TARGET_MAX_ERROR_MM)} |"
    )
    add(f"| 99th percentile abs error | {w['p99_error_mm']:.4f} mm | | |")
    add(f"| mean abs error | {w['mean_error_mm']:.5f} mm | | |")
    add(f"| mean integrator steps | {w['mean_steps']:.0f} | | |")
    add(
        f"| failed jumps (default / converged) | {w['failed_default']} / "
        f"{w['failed_converged']} | 0 | {_ok(w['failed_default'] + w['failed_converged'] == 0)} |"
    )
    ref = w["converged_reference"]
    add(
        f"| converged reference ({t2['threads_used']} threads) | {ref['wall_s_two_threads']:.1f} "
        f"s, {ref['mean_steps']:.0f} steps/jump | | |"
    )
    add("")
    add("| command | jumps | us/jump (1 thread) | mean steps | max error [mm] | p99 error [mm] |")
    add("|---|---:|---:|---:|---:|---:|")
    for name, r in w["per_command"].items():
        add(
            f"| {name} | {r['n']} | {r['us_per_jump_median']:.1f} | {r['mean_steps']:.0f} | "
            f"{r['max_error_mm']:.4f} | {r['p99_error_mm']:.4f} |"
        )
    add("")
    s = results["scipy"]
    add("## c. Comparison with solve_ivp")
    add("")
    add(
        f"The first {s['per_command']} jumps of each command of the workload ({s['n_jumps']} "
        "jumps), timed one by one with the plain `scipy.integrate.solve_ivp` implementation "
        "(`granbayes.testing`: Python right-hand side, terminal events for the regime "
        "changes, `max_step` 0.01 s as in granbayes) and with granbayes, in the same run. "
        "Errors against `SolverSettings.converged()`."
    )
    add("")
    add("| implementation | settings | median per jump | mean per jump | max error [mm] |")
    add("|---|---|---:|---:|---:|")
    for label, r in s["scipy"].items():
        add(
            f"| solve_ivp | {label} | {r['ms_per_jump_median']:.1f} ms | "
            f"{r['ms_per_jump_mean']:.1f} ms | {r['max_error_mm']:.2e} |"
        )
    g = s["granbayes"]
    add(
        f"| granbayes, per jump (batch of {g['copies_per_jump']} copies) | defaults, 1 thread | "
        f"{g['us_per_jump_median']:.1f} us | {g['us_per_jump_mean']:.1f} us | "
        f"{g['max_error_mm']:.2e} |"
    )
    batch_us = g["us_per_jump_batch"]
    add(f"| granbayes, one batch of all | defaults, 1 thread | | {batch_us:.1f} us | |")
    add(
        f"| granbayes, one `simulate_rows` call per jump | defaults, 1 thread | "
        f"{g['us_single_call_median']:.1f} us | | |"
    )
    add("")
    add(
        f"Speed-up over solve_ivp ({next(iter(SCIPY_SETTINGS))}): **{s['ratio_median']:,.0f}x** "
        f"(ratio of per-jump medians; target >= {TARGET_SCIPY_RATIO:g}x: "
        f"{_ok(s['meets_target'])}); {s['ratio_mean_batch']:,.0f}x on the mean against one "
        f"batch; {s['ratio_single_call']:,.0f}x against one call per jump, Python call overhead "
        "included."
    )
    add("")
    m = results["memory"]
    add("## d. Memory")
    add("")
    add(
        f"{m['n_jumps']:,} jumps drawn and simulated in one batch ({m['threads_used']} threads) "
        "in a fresh process; increase of the peak resident set size (`ru_maxrss`) over the "
        "process after loading the compiled code."
    )
    add("")
    add("| measure | value | target | met |")
    add("|---|---:|---:|---|")
    add(
        f"| peak RSS increase | {m['max_rss_increase_mb']:.1f} MB | < {TARGET_MEMORY_MB:g} MB |"
        f" {_ok(m['meets_target'])} |"
    )
    traced = m["tracemalloc_peak_mb"]
    add(f"| tracemalloc peak (numpy arrays; separate, untimed pass) | {traced:.1f} MB | | |")
    add(f"| peak RSS of the process | {m['max_rss_after_mb']:.1f} MB | | |")
    add(f"| wall time (simulate) | {m['simulate_s']:.2f} s ({m['us_per_jump']:.1f} us/jump) | | |")
    add(f"| failed jumps | {m['failed']} | 0 | {_ok(m['failed'] == 0)} |")
    add("")
    lines.extend(machine_markdown(results["machine"]))
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------
def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command-line options (``argv`` as for ``argparse``; ``None``: ``sys.argv``)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small smoke run (about 20 s)")
    parser.add_argument("--n-jumps", type=int, help="jumps in the mixed workload (5000)")
    parser.add_argument("--seed", type=int, default=20240611, help="workload seed")
    parser.add_argument("--skip-compile", action="store_true", help="skip part a")
    parser.add_argument(
        "--out",
        type=Path,
        help="JSON output (default benchmarks/results/simulator.json, or simulator-quick.json)",
    )
    parser.add_argument("--memory-child", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--threads", type=int, default=2, help=argparse.SUPPRESS)
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print the Markdown report and save the results."""
    args = parse_args(argv)
    if args.memory_child is not None:
        print(json.dumps(memory_child(args.memory_child, args.seed, args.threads)))
        return 0
    quick = args.quick
    n = args.n_jumps or (500 if quick else 5000)
    repeats = 3 if quick else 5
    config = {
        "mode": "quick" if quick else "full",
        "n_jumps": n,
        "seed": args.seed,
        "repeats": repeats,
        "load_start": os.getloadavg()[0],
    }
    results: dict = {"config": config}
    t_start = time.perf_counter()
    if not args.skip_compile:
        print("a. compile time ...", file=sys.stderr, flush=True)
        results["compile"] = bench_compile()
    print("b. mixed workload ...", file=sys.stderr, flush=True)
    workload = draw_workload(n, args.seed)
    results["workload"], _, converged = bench_workload(workload, repeats)
    print("c. solve_ivp comparison ...", file=sys.stderr, flush=True)
    results["scipy"] = bench_scipy(
        workload,
        converged,
        per_command=2 if quick else 10,
        repeats_scipy=1 if quick else 3,
        repeats=repeats,
    )
    print("d. memory ...", file=sys.stderr, flush=True)
    results["memory"] = bench_memory(10_000 if quick else 100_000, args.seed)
    results["load_end"] = os.getloadavg()[0]
    results["machine"] = machine_info()
    results["total_wall_s"] = time.perf_counter() - t_start
    report = render_markdown(results)
    print(report)
    out = args.out or RESULTS_DIR / ("simulator-quick.json" if quick else "simulator.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")
    out.with_suffix(".md").write_text(report)
    print(f"results: {out} (report: {out.with_suffix('.md')})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
