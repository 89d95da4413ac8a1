"""Benchmark: ``granbayes diagnose`` on the SYNTHETIC reference data (or another data set).

Targets (speed issue): <= 120 s wall on the 2-core machine on the reference data with the
same verdict, and <= 2x that on data holding an effect outside the library
(``--data outside_library``: ``data/outside_library``, made by
``data/generate_outside_library.py``). Runs the loop as the CLI does (baseline,
screening, candidates, forward selection, report) and records the wall time, the fits it
needed, the candidates screened out and the verdict against the documented truth.
``--no-screen`` fits every candidate in full (the lever's baseline). ``--without TERMS``
takes terms out of the candidates: with the true term of the data taken out, the library
no longer holds the physics, and the right verdict is ``misfit_remains`` (or a law that
truly leaves no misfit), never a nearby term named as the cause. Writes
``benchmarks/results/diagnose[_<data>][_without_<terms>][_noscreen].json`` and ``.md``.

Usage: ``python benchmarks/bench_diagnose.py [--seed N] [--data reference|outside_library]
[--without TERM[,TERM]] [--no-screen]``
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from granbayes import load_experiment, load_jumps, simulate
from granbayes._criticism import DiagnoseSettings, diagnose
from granbayes._synthetic import REFERENCE_DATA
from granbayes.forces import TERMS
from granbayes.report import write_diagnosis_report

HERE = Path(__file__).resolve().parent
DATA = {
    "reference": (REFERENCE_DATA, "drag + compaction on top of depth (TRUTH.md)"),
    "outside_library": (
        HERE.parent / "data" / "outside_library",
        "depth + drag and a bed stiffened after the hold of the delayed commands (outside "
        "the library: the right verdict is misfit_remains)",
    ),
}


def main() -> None:
    """Run the benchmark and print a Markdown report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--data", choices=sorted(DATA), default="reference")
    parser.add_argument("--no-screen", action="store_true", help="fit every candidate")
    parser.add_argument("--without", default="", help="terms taken out of the candidates")
    args = parser.parse_args()
    folder, truth = DATA[args.data]
    without = tuple(t.strip() for t in args.without.split(",") if t.strip())
    simulate("single", 0.612, {"k": 3000.0})  # compile / load the cache outside the timing
    experiment = load_experiment(folder)
    table = load_jumps(folder, experiment)
    config = dataclasses.replace(DiagnoseSettings(), screen=not args.no_screen)
    if without:
        unknown = sorted(set(without) - set(TERMS))
        if unknown:
            parser.error(f"--without: unknown terms {unknown}")
        keep = tuple(t for t in TERMS if t not in without)
        config = dataclasses.replace(config, candidates=keep)
        truth += f"; the candidates lack {', '.join(without)}"
    t0 = time.perf_counter()
    d = diagnose(experiment, table, config, seed=args.seed, data_source=str(folder))
    t_loop = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        write_diagnosis_report(d.to_json(), d.selected.datatree, Path(tmp))
        report_md = (Path(tmp) / "report.md").read_text()
    wall = time.perf_counter() - t0
    rec = d.to_json()
    screened = [c for c in d.candidates if c.screened_out]
    result = {
        "date": datetime.date.today().isoformat(),
        "data": args.data,
        "n_jumps": len(table),
        "screen": config.screen,
        "wall_s": wall,
        "loop_s": t_loop,
        "n_fits": len(d.fits),
        "n_candidates": len(d.candidates),
        "n_screened_out": len(screened),
        "timing_s": {k: round(v, 1) for k, v in d.timing_s.items()},
        "verdict": rec["verdict"],
        "added": rec["selected"]["added"],
        "indistinguishable": rec["selected"]["indistinguishable"],
        "n_residual_misfit": len(rec["residual_misfit"]),
        "candidates_withheld": list(without),
        "all_converged": rec["all_converged"],
        "elpd_gain": rec["selected"]["elpd_gain"],
        "elpd_gain_se": rec["selected"]["elpd_gain_se"],
        "rmse_before_mm": rec["selected"]["rmse_before_mm"],
        "rmse_after_mm": rec["selected"]["rmse_after_mm"],
        "truth": truth,
        "seed": args.seed,
        "numba_threads": int(os.environ.get("NUMBA_NUM_THREADS", os.cpu_count() or 1)),
        "machine": (
            f"{platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"
        ),
    }
    stem = "diagnose" + ("" if args.data == "reference" else f"_{args.data}")
    stem += f"_without_{'_'.join(without)}" if without else ""
    stem += "" if config.screen else "_noscreen"
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / f"{stem}.json").write_text(json.dumps(result, indent=2) + "\n")
    lines = [
        f"### `granbayes diagnose` on {args.data} ({len(table)} SYNTHETIC jumps), {result['date']}",
        "",
        f"- wall time: **{wall:.0f} s** (loop {t_loop:.0f} s; {result['n_fits']} fits, "
        f"{len(screened)} of {len(d.candidates)} candidates screened out; screening "
        f"{'on' if config.screen else 'off'}; target <= 120 s on the reference data)",
        "- where the loop's time went [s]: "
        + ", ".join(f"{k.replace('_', ' ')} {v:.0f}" for k, v in d.timing_s.items()),
        f"- verdict: {rec['verdict']}; added: {', '.join(result['added']) or 'nothing'} "
        f"(truth: {truth}); all fits converged: {rec['all_converged']}",
        f"- machine: {result['machine']}",
        "",
        report_md,
    ]
    (HERE / "results" / f"{stem}.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
