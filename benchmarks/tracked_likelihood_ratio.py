"""Is the tracked-jump likelihood calibrated on data the fitting code did not make?

The fits of the SYNTHETIC added-mass set put the truth outside more 90% intervals than
chance allows (``analyses/kappa_identification.py``: 5 of 12 intervals of kappa; at
phi = 0.592 the tracked jumps move k and kappa about three posterior standard deviations
from the truth, at any integrator tolerance: ``benchmarks/tracked_tolerance.py``), and the
joint SBC leans overconfident. This study asks the tracked-jump likelihood alone, without
the sampler, the priors or the jump heights: it draws the tracked jumps of the set's design
afresh from the independent oracle (``granbayes.testing.simulate_trajectory_scipy``: the
truth's force law, a clock offset per jump ~ Normal(0, 1.5 frames), AR(1) frame noise of
sd 0.25 mm and lag-1 correlation 0.5 per coordinate, as ``data/generate_lab_reference.py``
draws them), and maximises the library's log-likelihood of the frames
(``TrajectoryBlock.log_lik``: the clock offset integrated out, the noise parameters at
their true values) over the force law's (k, c_d, kappa), from the truth, by Nelder-Mead.
The rise ``2 (max log L - log L(truth))`` is chi-square with 3 degrees of freedom when
the likelihood is right (asymptotically: the frames pin the law down to a fraction of a
per cent). Reported per volume fraction: its mean (3 expected) and how often it exceeds
the chi-square's 50%, 90% and 99% points, with exact 95% intervals, and the rise of the
data set's own frames among the draws' (is the set's noise draw unusual?); a likelihood that
is overconfident (a bias the model does not know, an error of the offset's integral)
shows as a mean above 3 and exceedances above their levels.

With ``--free-noise`` the noise parameters are maximised over too (the rise then has 6
degrees of freedom): does estimating the noise make the likelihood overconfident?

Writes ``benchmarks/results/tracked_likelihood_ratio.md`` (``..._noise.md``).

Usage: ``python benchmarks/tracked_likelihood_ratio.py [--draws 200] [--seed 0]
[--phis 0.592,0.612,0.632] [--free-noise]``
"""

from __future__ import annotations

import argparse
import math
import time
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import minimize
from scipy.stats import beta, chi2

import granbayes as gb
from granbayes import load_experiment
from granbayes._likelihood._blocks import ObservationSettings, Simulated
from granbayes._likelihood._trajectories import TrajectoryBlock
from granbayes.kinds import load_measurements
from granbayes.report import markdown_table
from granbayes.testing import simulate_trajectory_scipy

DATA = gb.REFERENCE_DATA.parent / "added_mass"
OUT = Path(__file__).resolve().parent / "results" / "tracked_likelihood_ratio.md"
FREE = ("k", "c_d", "kappa")
LEVELS = (0.5, 0.9, 0.99)
#: The simulated frame's columns in the order the likelihood reads them.
FRAME_COLUMNS = ("x_foot_mm", "x_rod_mm", "v_foot_mm_s", "v_rod_mm_s")


def _clopper_pearson(k: int, n: int) -> tuple[float, float]:
    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return lo, hi


class Setting:
    """One volume fraction's tracked jumps: the design, the truth and the likelihood."""

    def __init__(self, table: pd.DataFrame, phi: float, truth: dict, noise: dict, experiment):
        self.block = TrajectoryBlock(table.reset_index(drop=True), ObservationSettings())
        coords = self.block.coordinates({}, np.array([phi]))
        self.phi, self.experiment = phi, experiment
        self.law = {k: float(v) for k, v in truth.items() if k != "sigma_mm"}
        tau_ms = -1.0 / math.log(noise["frame_rho"])  # 1 ms frames: rho = exp(-dt / tau)
        values = {
            "frame_sd_foot_mm": noise["frame_sd_mm"],
            "frame_sd_rod_mm": noise["frame_sd_mm"],
            "frame_tau_ms": tau_ms,
        }
        self.u = np.array([[c.prior.to_u(np.array([values[c.parameter]]))[0] for c in coords]])
        self.grids = self.block.jump_request().frame_times_s
        t = self.block.table
        self.jumps = list(dict.fromkeys(t["jump"]))  # the block's jump order
        self.times = [t.loc[t["jump"] == j, "t_s"].to_numpy(float) for j in self.jumps]

    def log_lik(self, law: dict, block: TrajectoryBlock, u: np.ndarray | None = None) -> float:
        """The library's log-likelihood of the frames of ``block`` under ``law``.

        ``u``: the noise's sampling coordinates (default: the truth's).
        """
        sims = []
        for program, grid in zip(self.block._programs, self.grids, strict=True):
            jump = gb.simulate_frames(program, self.phi, law, grid, experiment=self.experiment)
            sims.append(
                jump.data[["x_foot_mm", "x_rod_mm", "v_foot_mm_s", "v_rod_mm_s"]].to_numpy()
            )
        frames = np.concatenate(sims)[None, :, :]
        if not np.all(np.isfinite(frames)):
            return -np.inf
        n = block.n_units
        sim = Simulated(np.zeros((1, n)), np.ones((1, n), bool), frames)
        return float(np.sum(block.log_lik(self.u if u is None else u, None, sim)))

    def draw(self, rng: np.random.Generator, noise: dict) -> pd.DataFrame:
        """The tracked jumps drawn afresh from the oracle: offset, then AR(1) noise."""
        t = self.block.table.copy()
        half_window = self.block.offset_windows_s()
        rho, sd = noise["frame_rho"], noise["frame_sd_mm"]
        for j, times, program in zip(self.jumps, self.times, self.block._programs, strict=True):
            dt = float(np.median(np.diff(times)))
            while True:  # inside the likelihood's offset window (a 3.4-sigma draw otherwise)
                offset = noise["clock_sd_frames"] * dt * rng.standard_normal()
                if abs(offset) < half_window[j]:
                    break
            oracle = simulate_trajectory_scipy(
                program, self.phi, self.law, times + offset, self.experiment
            )
            rows = t["jump"] == j
            for column, clean in (("x_foot_mm", oracle.x_foot_mm), ("x_rod_mm", oracle.x_rod_mm)):
                e = np.empty(len(times))
                e[0] = sd * rng.standard_normal()
                for i in range(1, len(times)):
                    e[i] = rho * e[i - 1] + sd * math.sqrt(1.0 - rho * rho) * rng.standard_normal()
                t.loc[rows, column] = np.asarray(clean) + e
        return t


def rise(setting: Setting, frames_y: pd.DataFrame, free_noise: bool = False) -> tuple[float, dict]:
    """``2 (max log L - log L(truth))`` over (k, c_d, kappa), and the maximum's law.

    With ``free_noise`` the noise parameters (their sampling coordinates, log values) are
    maximised over too.
    """
    truth = np.array([setting.law[n] for n in FREE])
    block = setting.block.with_data(frames_y)
    start = np.concatenate([np.ones(len(FREE)), setting.u[0] if free_noise else []])

    def negative(x: np.ndarray) -> float:
        law = dict(setting.law, **dict(zip(FREE, truth * x[: len(FREE)], strict=True)))
        u = x[None, len(FREE) :] if free_noise else None
        value = setting.log_lik(law, block, u)
        return -value if np.isfinite(value) else 1e12

    at_truth = -negative(start)
    best = minimize(
        negative,
        start,
        method="Nelder-Mead",
        options={"xatol": 1e-6, "fatol": 1e-4, "maxfev": 1000 * len(start)},
    )
    top = max(-best.fun, at_truth)
    return 2.0 * (top - at_truth), dict(zip(FREE, truth * best.x[: len(FREE)], strict=True))


def main() -> None:
    """Run the draws and write the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--phis", default="0.592,0.612,0.632")
    parser.add_argument(
        "--free-noise",
        action="store_true",
        help="maximise over the noise parameters too (results: ..._noise.md)",
    )
    args = parser.parse_args()
    experiment = load_experiment(DATA)
    table = load_measurements(DATA, experiment, use=["trajectories"]).tables["trajectories"]
    spec = tomllib.loads((DATA / "truth.toml").read_text())
    noise = {k: spec[k] for k in ("frame_sd_mm", "frame_rho", "clock_sd_frames")}
    rows, detail = [], []
    start = time.perf_counter()
    free = args.free_noise
    dof = len(FREE) + (3 if free else 0)  # the noise: two sds and a correlation time
    for p, phi in enumerate(float(x) for x in args.phis.split(",")):
        truth = spec["phi"][f"{phi:g}"]
        setting = Setting(table[np.isclose(table["phi"], phi)], phi, truth, noise, experiment)
        rng = np.random.default_rng([args.seed, p])
        own, own_law = rise(setting, setting.block.table, free)  # the data set's own frames
        detail.append([f"{phi:g}", "data set", own, *(own_law[n] for n in FREE)])
        rises = []
        for d in range(args.draws):
            value, law = rise(setting, setting.draw(rng, noise), free)
            rises.append(value)
            detail.append([f"{phi:g}", d, value, *(law[n] for n in FREE)])
            print(f"phi {phi:g} draw {d}: rise {value:.2f}", flush=True)
        rises = np.array(rises)
        row = [f"{phi:g}", len(setting.jumps), args.draws, f"{rises.mean():.2f}"]
        row.append(f"{own:.2f} ({np.mean(rises >= own):.3f}; {chi2.sf(own, dof):.3f})")
        for level in LEVELS:
            k = int(np.sum(rises > chi2.ppf(level, dof)))
            lo, hi = _clopper_pearson(k, args.draws)
            row.append(f"{k}/{args.draws} [{lo:.2f}, {hi:.2f}] ({1 - level:.2f})")
        rows.append(row)
    columns = [
        "phi",
        "tracked jumps",
        "draws",
        f"mean rise ({dof})",
        f"the data set's rise (fraction of draws above; chi2_{dof} tail)",
    ] + [f"rise > chi2_{dof} {level:.0%} point" for level in LEVELS]
    over = (
        "(k, c_d, kappa) and the noise (two sds, a correlation time)"
        if free
        else ("(k, c_d, kappa), the noise at its truth")
    )
    text = [
        "# Is the tracked-jump likelihood calibrated on oracle data?",
        "",
        "**SYNTHETIC data**: the tracked jumps of `granbayes/data/added_mass`'s design drawn "
        "afresh from the independent oracle (truth, clock offsets and AR(1) frame noise of "
        "`truth.toml`), seed "
        f"{args.seed}. The rise `2 (max log L - log L(truth))` over {over}: chi-square "
        f"with {dof} degrees of freedom if the likelihood is right "
        "(the expected exceedance in brackets after each exact 95% interval). The data "
        "set's own frames get the same rise, placed among the draws' and on the chi-square. "
        "Written by "
        "`benchmarks/tracked_likelihood_ratio.py`.",
        "",
        markdown_table(pd.DataFrame(rows, columns=columns)),
        "",
        f"{time.perf_counter() - start:.0f} s.",
        "",
        "## Every draw",
        "",
        markdown_table(
            pd.DataFrame(detail, columns=["phi", "draw", "rise", *(f"max-L {n}" for n in FREE)]),
            floatfmt=".5g",
        ),
        "",
    ]
    out = OUT.with_name(OUT.stem + "_noise.md") if free else OUT
    out.write_text("\n".join(text))
    print("\n".join(text[:12]))


if __name__ == "__main__":
    main()
