"""Benchmark: ``granbayes diagnose`` on the SYNTHETIC reference data set.

Target (issue "model criticism"): <= 10 minutes wall on the 2-core machine (aim: 5).
Runs the loop as the CLI does (baseline, candidates, forward selection, report) and
records the wall time, the fits it needed and what it found against the documented truth
(``granbayes/data/reference/TRUTH.md``: depth + drag + compaction). Writes
``benchmarks/results/diagnose.json`` and ``.md``.

Usage: ``python benchmarks/bench_diagnose.py [--seed N]``
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from granbayes import load_experiment, load_jumps, simulate
from granbayes.criticism import diagnose
from granbayes.report import write_diagnosis_report
from granbayes.synthetic import REFERENCE_DATA

HERE = Path(__file__).resolve().parent
DATA = REFERENCE_DATA


def main() -> None:
    """Run the benchmark and print a Markdown report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    simulate("single", 0.612, {"k": 3000.0})  # compile / load the cache outside the timing
    experiment = load_experiment(DATA)
    table = load_jumps(DATA, experiment)
    t0 = time.perf_counter()
    d = diagnose(experiment, table, seed=args.seed, data_source="granbayes/data/reference")
    t_loop = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        write_diagnosis_report(d.to_json(), d.selected.datatree, Path(tmp))
        report_md = (Path(tmp) / "report.md").read_text()
    wall = time.perf_counter() - t0
    rec = d.to_json()
    result = {
        "date": datetime.date.today().isoformat(),
        "wall_s": wall,
        "loop_s": t_loop,
        "n_fits": len(d.fits),
        "verdict": rec["verdict"],
        "added": rec["selected"]["added"],
        "elpd_gain": rec["selected"]["elpd_gain"],
        "elpd_gain_se": rec["selected"]["elpd_gain_se"],
        "rmse_before_mm": rec["selected"]["rmse_before_mm"],
        "rmse_after_mm": rec["selected"]["rmse_after_mm"],
        "truth": ["drag", "compaction"],
        "seed": args.seed,
        "machine": (
            f"{platform.platform()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"
        ),
    }
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "diagnose.json").write_text(json.dumps(result, indent=2) + "\n")
    lines = [
        f"### `granbayes diagnose` on the synthetic reference data, {result['date']}",
        "",
        f"- wall time: **{wall:.0f} s** (loop {t_loop:.0f} s, {result['n_fits']} fits; "
        "target <= 600 s, aim 300 s)",
        f"- found: {', '.join(result['added']) or 'nothing'} (truth: drag + compaction on "
        "top of depth)",
        f"- machine: {result['machine']}",
        "",
        report_md,
    ]
    (HERE / "results" / "diagnose.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
