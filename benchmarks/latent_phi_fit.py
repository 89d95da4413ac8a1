"""Study: a bed's phi known only to its measurement, integrated out or taken as measured.

SYNTHETIC lab data (the oracle of ``granbayes.testing``; never the kernel under test):
5 volume fractions x 5 commands x 4 trials at 10 Hz (100 jumps, scatter 1 mm) and 2
intrusion tests per volume fraction and speed (1 and 200 mm/s, to 40 mm every 0.5 mm,
force noise 0.3 N), **each jump and each test on its own bed** whose true phi is
``Normal(written phi, 0.002)`` (``phi_jitter="jump"``: the thesis's protocol, a bed
prepared before every jump), robot exact. Truth: ``log k = log 4000 + 38 x + 300 x^2``
(``x = phi - 0.612``: k doubles over 0.02, like the reference truth's) and drag ``c_d =
10``; the quadratic law of ``--phi-mode quadratic`` contains it.

For each seed (of everything the lab draws) the same data are fitted twice, pair by pair in
one process (terms ``depth,drag``, ``phi_mode="quadratic"``, ``sigma_mode="global"``, the
default sampler): ``bed_phi="integrate"`` (each unit's bed integrated out, 9 nodes) and
``bed_phi="measured"``. Records the wall time, steps and convergence, and per volume
fraction ``k``'s and ``c_d``'s posterior against the truth (z = (mean - truth) / sd, and
whether the 90% equal-tailed interval covers it), the scatter and the force noise against
theirs. Writes ``benchmarks/results/latent_phi_fit.json`` and ``.md``; progress lines as it
goes, and ``--resume`` skips the fits already in the JSON (a stopped study keeps its rows).

Usage: ``python benchmarks/latent_phi_fit.py [--seeds 4] [--resume]``
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

import numpy as np
import pandas as pd

import granbayes as gb
from granbayes._fitting import FitSettings, fit
from granbayes.commands import COMMAND_NAMES
from granbayes.report import markdown_table
from granbayes.testing import LabDesign, synthetic_lab_data, write_lab_experiment

HERE = Path(__file__).resolve().parent
OUT = HERE / "results" / "latent_phi_fit"
PHIS = (0.592, 0.602, 0.612, 0.622, 0.632)
PHI_SD = 0.002
SIGMA_MM = 1.0
FORCE_SD_N = 0.3
LOG_K = (float(np.log(4000.0)), 38.0, 300.0)
C_D = 10.0
DESIGN = LabDesign(
    phis=PHIS,
    commands=COMMAND_NAMES,
    freqs_hz=(10.0,),
    trials=4,
    sigma_mm=SIGMA_MM,
    tracked_trials=0,
    intrusion_speeds_mm_s=(1.0, 200.0),
    intrusion_repeats=2,
    force_sd_N=FORCE_SD_N,
    phi_sd=PHI_SD,
    phi_jitter="jump",
)


def truth(phi: float) -> dict[str, float]:
    """The true law [SI] at ``phi``."""
    x = phi - 0.612
    return {"k": float(np.exp(LOG_K[0] + LOG_K[1] * x + LOG_K[2] * x * x)), "c_d": C_D}


def one_fit(exp, data, bed_phi: str, seed: int) -> dict:
    """Fit and summarise against the truth."""
    config = FitSettings(
        terms=("depth", "drag"),
        phi_mode="quadratic",
        sigma_mode="global",
        bed_phi=bed_phi,
        n_prior_draws=0,
    )
    t0 = time.perf_counter()
    res = fit(exp, data, config, seed=seed)
    wall = time.perf_counter() - t0
    post = res.datatree["posterior"]
    phis = post["phi"].values
    row = {
        "bed_phi": bed_phi,
        "seed": seed,
        "wall_s": round(wall, 1),
        "converged": bool(res.converged),
        "steps": [int(p.run.n_steps) for p in res.parts],
    }
    for name in ("k", "c_d"):
        v = post[name].stack(s=("chain", "draw")).transpose("phi", "s").values
        true = np.array([truth(p)[name] for p in phis])
        lo, hi = np.quantile(v, [0.05, 0.95], axis=1)
        row[f"{name}_z"] = ((v.mean(axis=1) - true) / v.std(axis=1)).round(2).tolist()
        row[f"{name}_covered90"] = ((lo <= true) & (true <= hi)).tolist()
    for name in ("sigma_mm", "force_sd_N"):
        row[name] = round(float(post[name].mean()), 3)
    return row


def main(argv: list[str] | None = None) -> int:
    """Run the pairs and write the results."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--resume", action="store_true", help="keep the fits already done")
    args = parser.parse_args(argv)
    OUT.parent.mkdir(exist_ok=True)
    path = OUT.with_suffix(".json")
    rows = json.loads(path.read_text())["fits"] if args.resume and path.exists() else []
    done = {(r["seed"], r["bed_phi"]) for r in rows}
    for seed in range(args.seeds):
        lab = synthetic_lab_data(truth, seed=seed, design=DESIGN)
        with tempfile.TemporaryDirectory() as tmp:
            folder = write_lab_experiment(Path(tmp) / "lab", lab)
            exp = gb.load_experiment(folder)
            data = gb.load_measurements(folder, exp)
            for bed_phi in ("integrate", "measured"):
                if (seed, bed_phi) in done:
                    continue
                rows.append(one_fit(exp, data, bed_phi, seed))
                print(json.dumps(rows[-1]), flush=True)
                _write(rows)
    _write(rows)
    return 0


def _write(rows: list[dict]) -> None:
    """The JSON and the Markdown summary of the fits so far."""
    rows = sorted(rows, key=lambda r: (r["seed"], r["bed_phi"]))
    result = {
        "date": datetime.date.today().isoformat(),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "data": "SYNTHETIC: granbayes.testing.synthetic_lab_data, seeds 0..N-1 (DESIGN)",
        "fits": rows,
    }
    OUT.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    table = [
        {
            "seed": r["seed"],
            "bed phi": r["bed_phi"],
            "wall [s]": r["wall_s"],
            "steps": r["steps"][0],
            "converged": r["converged"],
            "z of k per phi": " ".join(f"{z:+.1f}" for z in r["k_z"]),
            "z of c_d per phi": " ".join(f"{z:+.1f}" for z in r["c_d_z"]),
            "sigma_mm (truth 1)": r["sigma_mm"],
            "force_sd_N (truth 0.3)": r["force_sd_N"],
        }
        for r in rows
    ]
    summary = []
    for way in ("integrate", "measured"):
        mine = [r for r in rows if r["bed_phi"] == way]
        if not mine:
            continue
        cover = [c for r in mine for n in ("k", "c_d") for c in r[f"{n}_covered90"]]
        walls = [r["wall_s"] for r in mine]
        summary.append(
            f"- `{way}`: {len(mine)} fits, 90% intervals of k and c_d cover the truth at "
            f"{sum(cover)}/{len(cover)} (fit, phi) pairs; median wall {np.median(walls):.0f} s."
        )
    pairs = {r["seed"]: r for r in rows if r["bed_phi"] == "measured"}
    ratios = [
        r["wall_s"] / pairs[r["seed"]]["wall_s"]
        for r in rows
        if r["bed_phi"] == "integrate" and r["seed"] in pairs
    ]
    if ratios:
        summary.append(
            f"- wall-time ratio integrate / measured, paired: median {np.median(ratios):.2f} "
            f"({', '.join(f'{x:.2f}' for x in ratios)})."
        )
    lines = [
        "# A bed's phi integrated out or taken as measured (SYNTHETIC lab data)",
        "",
        f"{result['date']}, {result['machine']}; data: {result['data']}. Design and truth: "
        "`benchmarks/latent_phi_fit.py` (100 jumps, 20 intrusion tests, every jump and test "
        f"on its own bed, phi_sd {PHI_SD}; log k quadratic in phi, c_d {C_D}). Fits: depth + "
        "drag, quadratic in phi, one scatter and one force noise for all volume fractions.",
        "",
        *summary,
        "",
        markdown_table(pd.DataFrame(table)),
    ]
    OUT.with_suffix(".md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    raise SystemExit(main())
