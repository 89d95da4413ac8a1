"""Benchmark of tracked jumps: positions and velocities at video frames against heights.

A tracked jump (``granbayes.simulate_frames_rows``) is simulated once, like a height-only
jump (``granbayes.simulate_rows``), and its positions and velocities at the frame times
(the four columns of ``granbayes._simulator.FRAME_COLUMNS``) come from the dense output of
the accepted steps (no extra steps, except that a jump whose frames go on
after its height is final is simulated on to its last frame). Measured in one run, on one
machine:

a. **Cost.** The mixed workload of ``bench_simulator.py`` (N jumps, default 5000, the five
   commands equally, realistic random laws, same seed). Each jump is tracked with 500
   equally spaced frames over its own duration: from t = 0 to the touchdown that ends it
   (or to the end of the height window if it never flies), i.e. about 700 to 2000 frames
   per second. Height-only and tracked batches are timed in alternating, paired rounds on
   one thread (the whole workload and each command's jumps); the headline is the median
   over rounds of the per-round ratio tracked / height-only, of the public batched calls
   (Python checks included) and of the compiled entry points alone. Target: <= 2.
b. **Height-only cost against a baseline kernel** (``--baseline-rev REV``): the compiled
   kernel of a git revision, loaded from ``git show REV:granbayes/_kernel.py`` into a
   temporary module, and the current one, timed on the same workload in alternating
   rounds: the frames must not slow height-only jumps. Heights are compared bit for bit.
c. **Accuracy.** Frames (positions and velocities) at the default settings against
   ``SolverSettings.converged()`` on a subset of the workload, and the error as the
   tolerance tightens (closed form on, and
   off so that every frame comes from the quintic Hermite interpolant of Dormand-Prince
   steps), against a very tight reference (rtol 1e-12).

The machine may be shared: every ratio is taken within a round and the median over rounds
is quoted, with process CPU times as a check that is insensitive to other processes' load.
The Markdown report is printed and saved with the JSON results in
``benchmarks/results/frames.{json,md}``.

Usage::

    python benchmarks/bench_frames.py                          # full run (a few minutes)
    python benchmarks/bench_frames.py --baseline-rev 978134b   # plus the baseline kernel
    python benchmarks/bench_frames.py --quick                  # smoke run
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numba
import numpy as np
from _machine import machine_info, machine_markdown  # this folder
from bench_simulator import Workload, draw_workload, programs

from granbayes import _kernel
from granbayes._simulator import (
    SolverSettings,
    Status,
    simulate_frames_rows,
    simulate_rows,
)
from granbayes.commands import COMMAND_NAMES

BENCH_DIR = Path(__file__).resolve().parent
RESULTS_DIR = BENCH_DIR / "results"
REPO = BENCH_DIR.parent

#: Frames per tracked jump.
N_FRAMES = 500
#: Target: cost of a tracked jump / cost of the same jump untracked.
TARGET_RATIO = 2.0
#: Label of the mixed workload with irregularly spaced frames.
IRREGULAR = "mixed, irregular frames"
#: Grid on which the jump's end (touchdown) is found [s].
END_GRID_S = 1e-3


# ----------------------------------------------------------------------------------------
# the tracked workload
def jump_durations(workload: Workload, options: SolverSettings) -> np.ndarray:
    """Each jump's duration [s]: t = 0 to the touchdown that ends it, or to the window's end.

    Found on a 1 ms grid over the height window after the command (one tracked pass): the
    first fall of the foot through the surface after a flight of 1 mm (linear interpolation
    between grid points), else the window's end.
    """
    progs = programs()
    t_end = np.array([p.t_end for p in progs])[workload.command_index]
    grid = np.arange(0.0, options.window_after + END_GRID_S / 2, END_GRID_S)
    n = len(workload)
    times = (t_end[:, None] + grid[None, :]).ravel()
    offsets = np.arange(n + 1) * grid.size
    res = simulate_frames_rows(
        workload.rows, progs, workload.command_index, times, offsets, settings=options
    )
    foot = res.frames[:, :, 0]
    flown = np.maximum.accumulate(foot, axis=1) >= _kernel.H_FLIGHT * 1e3
    down = flown & (foot < 0.0)
    ends = t_end + options.window_after
    for i in np.flatnonzero(down.any(axis=1)):
        j = int(np.argmax(down[i]))
        a, b = foot[i, j - 1], foot[i, j]
        ends[i] = t_end[i] + grid[j - 1] + END_GRID_S * a / (a - b)
    return ends


def frame_table(
    durations: np.ndarray, n_frames: int, irregular: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """``n_frames`` frames over [0, duration] per jump: times and offsets.

    Equally spaced (a camera), or, if ``irregular``, at sorted uniform random times (seeded):
    every spacing differs, so the closed form's factors exp(lam d) are computed per frame,
    as a frame-by-frame evaluation of the closed form would.
    """
    if irregular:
        rng = np.random.default_rng(1)
        unit = np.sort(rng.uniform(0.0, 1.0, (durations.size, n_frames)), axis=1)
    else:
        unit = np.broadcast_to(np.linspace(0.0, 1.0, n_frames), (durations.size, n_frames))
    times = np.ascontiguousarray((unit * durations[:, None]).ravel())
    return times, np.arange(durations.size + 1, dtype=np.int64) * n_frames


# ----------------------------------------------------------------------------------------
# a. cost
def _tables() -> tuple[np.ndarray, np.ndarray]:
    tables = [p.as_table() for p in programs()]
    seg = np.ascontiguousarray(np.stack([t[0] for t in tables]))
    meta = np.ascontiguousarray(np.stack([t[1] for t in tables]))
    return seg, meta


def _timed(fun: Callable[[], object]) -> tuple[float, float]:
    """Wall and process CPU time [s] of one call."""
    c0 = time.process_time()
    t0 = time.perf_counter()
    fun()
    return time.perf_counter() - t0, time.process_time() - c0


def _pair_runs(
    height: Callable[[], object], tracked: Callable[[], object], rounds: int
) -> dict[str, list[float]]:
    """Alternating rounds (the order swapped every round) of the two calls."""
    height()
    tracked()
    out: dict[str, list[float]] = {"h_wall": [], "t_wall": [], "h_cpu": [], "t_cpu": []}
    for r in range(rounds):
        for label, fun in (("h", height), ("t", tracked))[:: 1 if r % 2 == 0 else -1]:
            wall, cpu = _timed(fun)
            out[f"{label}_wall"].append(wall)
            out[f"{label}_cpu"].append(cpu)
    return out


def _summary(times: dict[str, list[float]], n: int) -> dict:
    ratio = [t / h for h, t in zip(times["h_wall"], times["t_wall"], strict=True)]
    ratio_cpu = [t / h for h, t in zip(times["h_cpu"], times["t_cpu"], strict=True)]
    return {
        "n_jumps": n,
        "height_us_per_jump": statistics.median(times["h_wall"]) / n * 1e6,
        "tracked_us_per_jump": statistics.median(times["t_wall"]) / n * 1e6,
        "height_cpu_us_per_jump": statistics.median(times["h_cpu"]) / n * 1e6,
        "tracked_cpu_us_per_jump": statistics.median(times["t_cpu"]) / n * 1e6,
        "ratio_median": statistics.median(ratio),
        "ratio_cpu_median": statistics.median(ratio_cpu),
        "ratios": ratio,
        "times_s": times,
    }


def _kernel_calls(
    sub: Workload,
    times: np.ndarray,
    offsets: np.ndarray,
    seg: np.ndarray,
    meta: np.ndarray,
    opts: np.ndarray,
) -> tuple[Callable[[], None], Callable[[], None]]:
    """The compiled height-only and tracked entry points on a workload, as calls."""
    n = len(sub)
    heights = np.empty(n)
    status = np.empty(n, dtype=np.int8)
    steps = np.empty(n, dtype=np.int64)
    frames = np.empty((times.size, _kernel.FRAME_SIZE))

    def height() -> None:
        _kernel.simulate_batch(sub.rows, sub.command_index, seg, meta, opts,
                               heights, status, steps)  # fmt: skip

    def tracked() -> None:
        _kernel.simulate_frames_batch(sub.rows, sub.command_index, seg, meta, opts, times,
                                      offsets, 1e3, heights, status, steps,
                                      frames)  # fmt: skip

    return height, tracked


def bench_cost(workload: Workload, durations: np.ndarray, rounds: int) -> dict:
    """Paired cost of height-only and tracked batches: the workload and each command."""
    progs = programs()
    seg, meta = _tables()
    opts = SolverSettings().as_array()
    out: dict = {"api": {}, "kernel": {}}
    everything = np.ones(len(workload), dtype=bool)
    groups = {"mixed": everything}
    groups.update({name: workload.command_index == c for c, name in enumerate(COMMAND_NAMES)})
    groups[IRREGULAR] = everything
    for name, mask in groups.items():
        sub = workload.subset(np.flatnonzero(mask))
        n = len(sub)
        times, offsets = frame_table(durations[mask], N_FRAMES, irregular=name == IRREGULAR)

        def api_height(sub: Workload = sub) -> object:
            return simulate_rows(sub.rows, progs, sub.command_index, n_threads=1)

        def api_tracked(
            sub: Workload = sub, times: np.ndarray = times, offsets: np.ndarray = offsets
        ) -> object:
            return simulate_frames_rows(
                sub.rows, progs, sub.command_index, times, offsets, n_threads=1
            )

        kernel_height, kernel_tracked = _kernel_calls(sub, times, offsets, seg, meta, opts)

        previous = numba.get_num_threads()
        numba.set_num_threads(1)
        try:
            out["api"][name] = _summary(_pair_runs(api_height, api_tracked, rounds), n)
            out["kernel"][name] = _summary(_pair_runs(kernel_height, kernel_tracked, rounds), n)
        finally:
            numba.set_num_threads(previous)
        plain = api_height()
        tracked = api_tracked()
        fps = N_FRAMES / durations[mask]
        out["api"][name].update(
            {
                "heights_bit_identical": bool(
                    np.array_equal(plain.height_mm, tracked.height_mm, equal_nan=True)
                    and np.array_equal(plain.status, tracked.status)
                ),
                "failed": int((tracked.status != Status.OK).sum()),
                "mean_steps_height": float(plain.n_steps.mean()),
                "mean_steps_tracked": float(tracked.n_steps.mean()),
                "duration_s_median": float(np.median(durations[mask])),
                "fps_median": float(np.median(fps)),
                "fps_range": [float(fps.min()), float(fps.max())],
            }
        )
    return out


# ----------------------------------------------------------------------------------------
# b. height-only cost against a baseline kernel
def load_kernel(rev: str) -> object:
    """The compiled kernel of git revision ``rev`` as a module of its own."""
    source = subprocess.run(
        ["git", "show", f"{rev}:granbayes/_kernel.py"],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    source = source.replace("from .forces import", "from granbayes.forces import")
    folder = Path(tempfile.mkdtemp(prefix="granbayes-kernel-"))
    path = folder / "_kernel_baseline.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("_kernel_baseline", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def bench_baseline(workload: Workload, rev: str, rounds: int) -> dict:
    """Height-only batches of the baseline kernel and the current one, in paired rounds."""
    base = load_kernel(rev)
    seg, meta = _tables()
    opts = SolverSettings().as_array()
    n = len(workload)
    results = {}

    def run(kernel: object) -> None:
        h = np.empty(n)
        st = np.empty(n, dtype=np.int8)
        ns = np.empty(n, dtype=np.int64)
        kernel.simulate_batch(workload.rows, workload.command_index, seg, meta, opts, h, st, ns)
        results[kernel.__name__] = h

    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        times = _pair_runs(lambda: run(base), lambda: run(_kernel), rounds)
    finally:
        numba.set_num_threads(previous)
    summary = _summary(times, n)
    return {
        "baseline_rev": rev,
        "n_jumps": n,
        "baseline_us_per_jump": summary["height_us_per_jump"],
        "current_us_per_jump": summary["tracked_us_per_jump"],
        "baseline_cpu_us_per_jump": summary["height_cpu_us_per_jump"],
        "current_cpu_us_per_jump": summary["tracked_cpu_us_per_jump"],
        "ratio_median": summary["ratio_median"],
        "ratio_cpu_median": summary["ratio_cpu_median"],
        "ratios": summary["ratios"],
        "heights_bit_identical": bool(
            np.array_equal(results["_kernel_baseline"], results[_kernel.__name__], equal_nan=True)
        ),
    }


# ----------------------------------------------------------------------------------------
# c. accuracy
def _frames(
    sub: Workload, times: np.ndarray, offsets: np.ndarray, options: SolverSettings
) -> np.ndarray:
    return simulate_frames_rows(
        sub.rows, programs(), sub.command_index, times, offsets, settings=options
    ).frames_flat


def _errors(got: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: the larger error of the two positions [mm] and of the two velocities [mm/s]."""
    err = np.abs(got - ref)
    return err[:, :2].max(axis=1), err[:, 2:].max(axis=1)


def bench_accuracy(
    workload: Workload, durations: np.ndarray, per_command: int, per_command_sweep: int
) -> dict:
    """Frames at the defaults against converged settings; error against the tolerance.

    Errors of the positions [mm] and of the velocities [mm/s], over every frame.
    """
    out: dict = {"per_command": {}, "sweep": {}}
    pick = np.concatenate(
        [np.flatnonzero(workload.command_index == c)[:per_command] for c in range(5)]
    )
    sub = workload.subset(pick)
    times, offsets = frame_table(durations[pick], N_FRAMES)
    default = _frames(sub, times, offsets, SolverSettings())
    converged = _frames(sub, times, offsets, SolverSettings.converged())
    err, err_v = _errors(default, converged)
    jump = np.repeat(np.arange(len(sub)), N_FRAMES)
    for c, name in enumerate(COMMAND_NAMES):
        mask = sub.command_index[jump] == c
        e, ev = err[mask], err_v[mask]
        out["per_command"][name] = {
            "n_jumps": int((sub.command_index == c).sum()),
            "max_error_mm": float(e.max()),
            "p99_error_mm": float(np.percentile(e, 99)),
            "median_error_mm": float(np.median(e)),
            "max_error_mm_s": float(ev.max()),
            "p99_error_mm_s": float(np.percentile(ev, 99)),
            "median_error_mm_s": float(np.median(ev)),
            "max_speed_mm_s": float(np.abs(converged[mask, 2:]).max()),
        }
    out["max_error_mm"] = float(err.max())
    out["p99_error_mm"] = float(np.percentile(err, 99))
    out["max_error_mm_s"] = float(err_v.max())
    out["p99_error_mm_s"] = float(np.percentile(err_v, 99))
    # error against the tolerance, against a very tight reference
    pick = np.concatenate(
        [np.flatnonzero(workload.command_index == c)[:per_command_sweep] for c in range(5)]
    )
    sub = workload.subset(pick)
    times, offsets = frame_table(durations[pick], N_FRAMES)
    tight = SolverSettings(rtol=1e-12, atol_position=1e-14, atol_velocity=1e-12)
    reference = _frames(sub, times, offsets, tight)
    for closed in (True, False):
        rows = []
        for rtol in (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9):
            options = SolverSettings(
                rtol=rtol, atol_position=1e-2 * rtol, atol_velocity=rtol, closed_form=closed
            )
            e, ev = _errors(_frames(sub, times, offsets, options), reference)
            rows.append(
                {"rtol": rtol, "max_error_mm": float(e.max()), "max_error_mm_s": float(ev.max())}
            )
        out["sweep"]["closed_form" if closed else "dormand_prince_only"] = rows
    out["n_jumps_sweep"] = len(sub)
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
    add("# Tracked-jump benchmark")
    add("")
    add(
        f"Mode: {cfg['mode']}; {cfg['n_jumps']} jumps (the mixed workload of "
        f"`bench_simulator.py`, seed {cfg['seed']}), {N_FRAMES} frames per tracked jump over "
        f"its own duration; {cfg['rounds']} paired rounds, one thread. Load average (1 min) "
        f"at start / end: {cfg['load_start']:.2f} / {results['load_end']:.2f}."
    )
    add("")
    add("## a. Cost of a tracked jump against the same jump untracked")
    add("")
    add(
        "Per round the height-only batch (`simulate_rows`) and the tracked batch "
        "(`simulate_frames_rows`, 500 frames per jump from t = 0 to the touchdown that ends "
        "the jump, or to the window's end) are timed one after the other (the order swapped "
        "every round); the ratio is taken within the round and the median over rounds is "
        "quoted. *API*: the public calls (the frames' checks in Python included); "
        "*kernel*: the compiled entry points alone. CPU: process CPU time (a check insensitive "
        "to other processes' load)."
    )
    add("")
    add(
        "| jumps | frames/s (median, range) | height-only [us/jump] | tracked [us/jump] | "
        "ratio (API) | ratio (API, CPU) | ratio (kernel) | steps height / tracked | "
        "heights bit-identical | target <= 2 |"
    )
    add("|---|---:|---:|---:|---:|---:|---:|---:|---|---|")
    for name, a in results["cost"]["api"].items():
        k = results["cost"]["kernel"][name]
        lo, hi = a["fps_range"]
        add(
            f"| {name} ({a['n_jumps']}) | {a['fps_median']:.0f} ({lo:.0f}-{hi:.0f}) | "
            f"{a['height_us_per_jump']:.1f} | {a['tracked_us_per_jump']:.1f} | "
            f"**{a['ratio_median']:.2f}** | {a['ratio_cpu_median']:.2f} | "
            f"{k['ratio_median']:.2f} | {a['mean_steps_height']:.0f} / "
            f"{a['mean_steps_tracked']:.0f} | {_ok(a['heights_bit_identical'])} | "
            f"{'-' if name == IRREGULAR else _ok(a['ratio_median'] <= TARGET_RATIO)} |"
        )
    add("")
    add(
        "A tracked jump takes a few more steps than the height-only one: the latter ends as "
        "soon as its height is final (a free flight that can no longer rise), the tracked one "
        "flies on to its last frame, the touchdown. The last row has the frames at sorted "
        "random times instead of equally spaced: every spacing differs, so in the closed-form "
        "steps the factors exp(lam d) and the actuator's rotation are computed per frame (the "
        "cost of evaluating the closed form frame by frame); with equally spaced frames they "
        "are computed once per regime and the frames are carried from one to the next."
    )
    add("")
    if "baseline" in results:
        b = results["baseline"]
        add("## b. Height-only jumps against the baseline kernel")
        add("")
        add(
            f"The kernel of revision `{b['baseline_rev']}` (before the frames) and the current "
            f"one, `simulate_batch` on the whole workload ({b['n_jumps']} jumps), paired "
            "rounds, one thread."
        )
        add("")
        add("| measure | value |")
        add("|---|---:|")
        add(f"| baseline [us/jump] | {b['baseline_us_per_jump']:.1f} |")
        add(f"| current [us/jump] | {b['current_us_per_jump']:.1f} |")
        add(f"| ratio current / baseline (median of rounds) | **{b['ratio_median']:.3f}** |")
        add(f"| same, process CPU time | {b['ratio_cpu_median']:.3f} |")
        ratios = b["ratios"]
        add(f"| range of the per-round ratios | {min(ratios):.3f}-{max(ratios):.3f} |")
        add(f"| heights bit-identical | {_ok(b['heights_bit_identical'])} |")
        add("")
    acc = results["accuracy"]
    add("## c. Accuracy of the frames")
    add("")
    add(
        "Positions and velocities (foot and rod) at the frames of section a with the default "
        "settings against `SolverSettings.converged()`, over every frame (the larger error "
        "of foot and rod)."
    )
    add("")
    add(
        "| command | jumps | max error [mm] | p99 [mm] | median [mm] | max error [mm/s] | "
        "p99 [mm/s] | median [mm/s] | largest speed [mm/s] |"
    )
    add("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, r in acc["per_command"].items():
        add(
            f"| {name} | {r['n_jumps']} | {r['max_error_mm']:.4f} | {r['p99_error_mm']:.4f} | "
            f"{r['median_error_mm']:.5f} | {r['max_error_mm_s']:.2f} | "
            f"{r['p99_error_mm_s']:.3f} | {r['median_error_mm_s']:.4f} | "
            f"{r['max_speed_mm_s']:.0f} |"
        )
    add("")
    add(
        f"Error against the tolerance ({acc['n_jumps_sweep']} jumps, every frame, against "
        "rtol 1e-12; atol = 1e-2 rtol m and rtol m/s). *Closed form*: the default "
        "integrator (exact closed-form steps in the linear regimes); *Dormand-Prince only*: "
        "`closed_form=False`, every frame from the quintic Hermite interpolant of a "
        "Dormand-Prince step."
    )
    add("")
    add(
        "| rtol | closed form [mm] | closed form [mm/s] | Dormand-Prince only [mm] | "
        "Dormand-Prince only [mm/s] |"
    )
    add("|---:|---:|---:|---:|---:|")
    for a, b in zip(acc["sweep"]["closed_form"], acc["sweep"]["dormand_prince_only"], strict=True):
        add(
            f"| {a['rtol']:.0e} | {a['max_error_mm']:.2e} | {a['max_error_mm_s']:.2e} | "
            f"{b['max_error_mm']:.2e} | {b['max_error_mm_s']:.2e} |"
        )
    add("")
    lines.extend(machine_markdown(results["machine"]))
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------
def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command-line options (``argv`` as for ``argparse``; ``None``: ``sys.argv``)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small smoke run")
    parser.add_argument("--n-jumps", type=int, help="jumps in the mixed workload (5000)")
    parser.add_argument("--seed", type=int, default=20240611, help="workload seed")
    parser.add_argument("--rounds", type=int, help="paired rounds (15)")
    parser.add_argument(
        "--baseline-rev", help="git revision whose kernel height-only jumps are compared with"
    )
    parser.add_argument(
        "--out", type=Path, help="JSON output (default benchmarks/results/frames.json)"
    )
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print the Markdown report and save the results."""
    args = parse_args(argv)
    quick = args.quick
    n = args.n_jumps or (500 if quick else 5000)
    rounds = args.rounds or (5 if quick else 15)
    config = {
        "mode": "quick" if quick else "full",
        "n_jumps": n,
        "seed": args.seed,
        "rounds": rounds,
        "n_frames": N_FRAMES,
        "load_start": os.getloadavg()[0],
    }
    results: dict = {"config": config}
    workload = draw_workload(n, args.seed)
    print("durations ...", file=sys.stderr, flush=True)
    durations = jump_durations(workload, SolverSettings())
    print("a. cost ...", file=sys.stderr, flush=True)
    results["cost"] = bench_cost(workload, durations, rounds)
    if args.baseline_rev:
        print("b. baseline kernel ...", file=sys.stderr, flush=True)
        results["baseline"] = bench_baseline(workload, args.baseline_rev, rounds)
    print("c. accuracy ...", file=sys.stderr, flush=True)
    results["accuracy"] = bench_accuracy(
        workload, durations, per_command=20 if quick else 200, per_command_sweep=4 if quick else 20
    )
    results["load_end"] = os.getloadavg()[0]
    results["machine"] = machine_info()
    markdown = render_markdown(results)
    print(markdown)
    out = args.out or RESULTS_DIR / ("frames-quick.json" if quick else "frames.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1) + "\n")
    out.with_suffix(".md").write_text(markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
