"""Generate the SYNTHETIC lab data sets with tracked jumps and intrusion curves (seeded).

Two experiment folders, package data of granbayes beside ``granbayes/data/reference/``,
each made by the independent scipy oracle (``granbayes.testing.synthetic_lab_data``, never
the compiled kernel) and written by ``granbayes.testing.write_lab_experiment``:

* ``granbayes/data/reference_tracked/``: the documented reference truth
  (``granbayes/data/reference/truth.toml``: depth + drag + compaction, per volume
  fraction, with its trial-to-trial scatter ``sigma_mm(phi)``) on the same nominal robot
  (``granbayes/data/reference/experiment.toml``), measured the way a lab with a
  high-speed camera and an intrusion rig would: jump heights on a smaller design than the
  reference's, the first single jump of every volume fraction filmed, intrusion tests
  at three speeds per volume fraction. Small enough that ``granbayes fit`` on it with its
  true terms converges in about 11 minutes on a shared 2-core machine (filming every cell
  took 31; measured, see its README).
* ``granbayes/data/added_mass/``: a truth with an added-mass cone (``kappa = 1.5``) and
  drag on top of the reference's depth law, same robot, same design except that the
  single and the stutter jumps are filmed: a data set on which the question "is kappa
  identified?" has an answer to find (``analyses/kappa_identification.py``).

Every row of every table says ``synthetic: data/generate_lab_reference.py seed=<seed>``
in its ``source`` column, ``experiment.toml`` starts with a SYNTHETIC comment naming the
generator and seed, and each folder's ``README.md`` states the truth and the design. The
truth is also stored in ``truth.toml`` (the format of the reference's, read by
``granbayes fit --truth``) and ``lab_truth.json`` (the oracle's record); inference code
never reads either.

Run ``python data/generate_lab_reference.py`` to regenerate both folders bit for bit
(``--only reference_tracked`` or ``--only added_mass`` for one of them).

Randomness. Each folder has its own seed. The oracle's lab draws its clock offsets, frame
noise and force noise from its own streams (``numpy.random.SeedSequence(seed).spawn(6)``).
The reference's scatter differs per volume fraction, which the lab's single ``sigma_mm``
cannot express, so for ``reference_tracked`` the lab makes noise-free heights and this
script adds ``Normal(0, sigma_mm(phi))`` in table order from the seventh child
``SeedSequence(seed).spawn(7)[6]`` (independent of the lab's six). ``added_mass`` uses the
lab's own scatter (one ``sigma_mm``).
"""

from __future__ import annotations

import argparse
import dataclasses
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from granbayes import load_experiment
from granbayes.commands import build_command
from granbayes.testing import LabDesign, synthetic_lab_data, write_lab_experiment

HERE = Path(__file__).resolve().parent
DATA = HERE.parent / "granbayes" / "data"
#: The documented reference data set whose truth and robot ``reference_tracked`` reuses.
REFERENCE = DATA / "reference"
#: The generator named in every ``source`` value.
LABEL = "data/generate_lab_reference.py"

SEED_TRACKED = 20261127
SEED_ADDED_MASS = 20261128

#: Volume fractions of both sets: the loosest, critical and densest of the reference's.
PHIS = (0.592, 0.612, 0.632)
COMMANDS = ("single", "preload", "stutter", "delayed_stutter", "delayed_stutter_preload")

#: What both labs measure and how well: 3 volume fractions x 5 commands x 1 frequency x 3
#: trials (45 jumps); the first trial of every cell filmed at 1000 frames/s from 10 ms
#: before the command to 80 ms after its end (only the cells of a data set's
#: ``tracked_commands`` are kept), with AR(1) frame noise (0.25 mm, lag-1
#: correlation 0.5) and a clock offset of standard deviation 1.5 frames; intrusion tests
#: at 1, 500 and 1000 mm/s to 40 mm depth every 0.5 mm with 0.3 N force noise.
BASE_DESIGN = LabDesign(
    phis=PHIS,
    commands=COMMANDS,
    freqs_hz=(10.0,),
    trials=3,
    sigma_mm=0.0,  # per data set below
    tracked_trials=1,
    fps=1000.0,
    frame_sd_mm=0.25,
    frame_rho=0.5,
    clock_sd_frames=1.5,
    track_from_s=-0.010,
    track_after_end_s=0.080,
    intrusion_speeds_mm_s=(1.0, 500.0, 1000.0),
    intrusion_repeats=1,
    depth_step_mm=0.5,
    depth_max_mm=40.0,
    force_sd_N=0.3,
)


def reference_truth() -> dict[float, dict[str, float]]:
    """The reference truth per volume fraction (``granbayes/data/reference/truth.toml``)."""
    doc = tomllib.loads((REFERENCE / "truth.toml").read_text())
    return {float(phi): dict(values) for phi, values in doc["phi"].items()}


def added_mass_law(phi: float) -> dict[str, float]:
    """True law of ``added_mass`` at ``phi`` [SI]: the reference's ``k(phi)``, ``c_d = 10``
    kg/m and ``kappa = 1.5`` at every volume fraction (no compaction), ``r_unload = 20``."""
    x = phi - 0.612
    return {"k": 4000.0 + 1.5e5 * x + 2.0e6 * x * x, "c_d": 10.0, "kappa": 1.5, "r_unload": 20.0}


@dataclass(frozen=True)
class DataSet:
    """One folder: its truth, terms, scatter, seed and words for its README."""

    name: str
    seed: int
    terms: tuple[str, ...]
    law: Callable[[float], Mapping[str, float]]
    sigma_mm: Callable[[float], float]
    lab_sigma_mm: float  # the lab's own scatter (0: added here, per phi)
    tracked_commands: tuple[str, ...]  # the commands whose trial 1 is filmed
    what: str
    size: str  # how long a fit of it takes (measured)


def data_sets() -> dict[str, DataSet]:
    """The two data sets."""
    ref = reference_truth()
    missing = [p for p in PHIS if p not in ref]
    if missing:
        raise KeyError(f"the reference truth has no volume fraction {missing}")
    return {
        "reference_tracked": DataSet(
            name="reference_tracked",
            seed=SEED_TRACKED,
            terms=("depth", "drag", "compaction"),
            law=lambda phi: {k: v for k, v in ref[phi].items() if k != "sigma_mm"},
            sigma_mm=lambda phi: ref[phi]["sigma_mm"],
            lab_sigma_mm=0.0,
            tracked_commands=("single",),
            what=(
                "The documented reference truth (`granbayes/data/reference/truth.toml`, "
                "TRUTH.md there: depth + drag + compaction) on the reference's nominal "
                "robot, measured by a lab with a high-speed camera and an intrusion rig, "
                "on a smaller design than the reference's (3 of its 5 volume fractions, "
                "10 Hz instead of 8 and 12 Hz, 3 trials instead of 5: 45 jumps, not 250)."
            ),
            size=(
                "Small enough to fit in minutes: `granbayes fit "
                "granbayes/data/reference_tracked --out OUT --terms depth,drag,compaction "
                "--seed 1` converged (every run; 150-300 steps of 4 ensembles of 32 "
                "walkers, from the Laplace start of fits with tracked jumps: three climbs "
                "per ensemble run side by side, and one from the intrusion curves' own "
                "mode) in 60.5 s wall time on a 2-core machine (2026-11-27, median of 3 "
                "runs paired with the heights alone, `--data heights`: 15.4 s, ratio "
                "3.9x); with one climb per ensemble and one point per simulator call it "
                "had taken 108-116 s (heights alone 30-33 s) on another machine, and from "
                "the earlier search start 1700-2500 steps and 11.1 min. Filming trial 1 of "
                "every cell instead "
                "(15 jumps, 4365 frames) took 30.6 min from that start (2500-2700 steps), "
                "so only the single jumps are filmed here."
            ),
        ),
        "added_mass": DataSet(
            name="added_mass",
            seed=SEED_ADDED_MASS,
            terms=("depth", "drag", "added_mass"),
            law=added_mass_law,
            sigma_mm=lambda phi: 3.0,
            lab_sigma_mm=3.0,
            tracked_commands=("single", "stutter"),
            what=(
                "A truth with an added-mass cone (kappa = 1.5) and drag on top of the "
                "reference's depth law, on the reference's nominal robot: the data set of "
                "`analyses/kappa_identification.py` (is kappa identified by jump heights "
                "alone, with tracked jumps, with intrusion curves?)."
            ),
            size=(
                "Small enough for three fits in half an hour: the fits of "
                "`analyses/kappa_identification.py` (depth + drag + added_mass, seed 0) all "
                "converged, in 0.3-0.6 min (heights), 3-6.5 min (+ tracked jumps) and 9.5-12.5 "
                "min (+ intrusion curves) wall time over three runs on a 2-core machine "
                "shared with other work (`docs/analyses/kappa_identification/timings.csv`: "
                "the last run). The single and "
                "stutter jumps are filmed (the stutter lands on the bed mid-command: a second "
                "added-mass episode at speed); filming every cell would about double the cost "
                "of each evaluation of the tracked jumps' likelihood."
            ),
        ),
    }


def generate(ds: DataSet, out: Path) -> dict[str, int]:
    """Simulate ``ds`` with the oracle and write its folder to ``out``.

    Returns
    -------
    dict
        Row counts per table and the largest clock offset [frames].
    """
    design = LabDesign(**{**vars(BASE_DESIGN), "sigma_mm": ds.lab_sigma_mm})
    experiment = load_experiment(REFERENCE)
    data = synthetic_lab_data(
        ds.law, seed=ds.seed, design=design, experiment=experiment, label=LABEL
    )
    # the camera films trial 1 of the cells of ds.tracked_commands only (the lab draws the
    # frame noise per filmed jump in jump order whatever is kept: still fixed by the seed)
    frames = data.trajectories
    kept = frames[frames["command"].isin(ds.tracked_commands)].reset_index(drop=True)
    data = dataclasses.replace(data, trajectories=kept)
    if ds.lab_sigma_mm == 0.0:  # the reference's scatter per volume fraction
        rng = np.random.default_rng(np.random.SeedSequence(ds.seed).spawn(7)[6])
        sd = data.jumps["phi"].map(ds.sigma_mm).to_numpy(float)
        noise = sd * rng.standard_normal(len(data.jumps))
        data.jumps["height_mm"] = np.round(data.jumps["true_height_mm"] + noise, 3)
    out.mkdir(parents=True, exist_ok=True)
    write_lab_experiment(out, data, uncertainties=False, truth_file=True)
    offsets = data.trajectories.groupby("jump").apply(
        lambda f: float((f["t_s"] - f["true_t_s"]).iloc[0]), include_groups=False
    )
    max_offset = float(np.max(np.abs(offsets))) * design.fps
    _write_truth(ds, out, design)
    _write_readme(ds, out, design, data, max_offset)
    return {
        "jumps": len(data.jumps),
        "tracked jumps": int(data.trajectories["jump"].nunique()),
        "frames": len(data.trajectories),
        "intrusion tests": int(data.intrusions["test"].nunique()),
        "intrusion samples": len(data.intrusions),
        "max |clock offset| [frames]": round(max_offset, 2),
    }


def _header(ds: DataSet) -> str:
    return (
        f"SYNTHETIC data: generated by {LABEL} with seed {ds.seed} (the scipy oracle of "
        "granbayes.testing.synthetic_lab_data); not measured."
    )


def _write_truth(ds: DataSet, out: Path, design: LabDesign) -> None:
    lines = [
        f"# {_header(ds)}",
        "# true force law per phi (SI) and the lab's noise; inference code never reads this file",
        f"terms = {list(ds.terms)!r}".replace("'", '"'),
        f"seed = {ds.seed}",
        f"frame_sd_mm = {design.frame_sd_mm!r}",
        f"frame_rho = {design.frame_rho!r}",
        f"clock_sd_frames = {design.clock_sd_frames!r}",
        f"force_sd_N = {design.force_sd_N!r}",
    ]
    for phi in design.phis:
        lines += ["", f'[phi."{phi}"]']
        lines += [f"{k} = {float(v)!r}" for k, v in ds.law(phi).items()]
        lines.append(f"sigma_mm = {float(ds.sigma_mm(phi))!r}")
    (out / "truth.toml").write_text("\n".join(lines) + "\n")


def _fmt_law(law: Mapping[str, float]) -> str:
    return ", ".join(f"{k} = {v:.4g}" for k, v in law.items())


def _design_rows(design: LabDesign, data, max_offset: float) -> list[tuple[str, str]]:
    """The README's design table: (measurement, design) per kind."""
    frames = data.trajectories.groupby("jump").size()
    filmed = sorted(set(data.trajectories["command"]), key=design.commands.index)
    span = f"{frames.min()}" if frames.min() == frames.max() else f"{frames.min()}-{frames.max()}"
    lengths = {
        c: build_command(c, data.experiment.replace(freq_hz=design.freqs_hz[0]).command).t_end
        for c in filmed
    }
    freqs = ", ".join(f"{f:g}" for f in design.freqs_hz)
    speeds = ", ".join(f"{v:g}" for v in design.intrusion_speeds_mm_s)
    heights = (
        f"phi {', '.join(map(str, design.phis))} (phi_c = 0.612) x commands "
        f"{', '.join(design.commands)} x {freqs} Hz x {design.trials} trials = "
        f"{len(data.jumps)} jumps; Gaussian scatter as above, independent trials"
    )
    tracked = (
        f"trial 1 of the {' and '.join(filmed)} cells at every phi ({len(frames)} jumps, "
        f"{len(data.trajectories)} frames; the other commands are not filmed): foot "
        f"height and rod displacement at {design.fps:g} frames/s from "
        f"{design.track_from_s * 1e3:g} ms to {design.track_after_end_s * 1e3:g} ms after "
        f"the command's end ({span} frames per jump; the command "
        "lasts " + ", ".join(f"{c} {t * 1e3:g} ms" for c, t in lengths.items()) + "); "
        f"AR(1) frame noise per coordinate, marginal sd {design.frame_sd_mm} mm, lag-1 "
        f"correlation {design.frame_rho}; a clock offset per jump ~ Normal(0, "
        f"{design.clock_sd_frames} frames) (largest among the filmed jumps: "
        f"{max_offset:.2f} frames)"
    )
    intrusions = (
        f"{len(design.intrusion_speeds_mm_s)} speeds ({speeds} mm/s) x "
        f"{design.intrusion_repeats} test per phi, each into a fresh bed, depth 0 to "
        f"{design.depth_max_mm:g} mm every {design.depth_step_mm:g} mm "
        f"({len(data.intrusions)} samples); Gaussian force noise sd {design.force_sd_N} N"
    )
    return [
        ("jump heights (`jumps.csv`)", heights),
        ("tracked jumps (`trajectories.csv`)", tracked),
        ("intrusion tests (`intrusions.csv`)", intrusions),
    ]


def _write_readme(ds: DataSet, out: Path, design: LabDesign, data, max_offset: float) -> None:
    law_rows = "\n".join(
        f"| {phi} | {_fmt_law(ds.law(phi))} | {ds.sigma_mm(phi):.3g} |" for phi in design.phis
    )
    design_rows = "\n".join(f"| {a} | {b} |" for a, b in _design_rows(design, data, max_offset))
    text = f"""# {ds.name}: {_header(ds)}

{ds.what}

{ds.size}

Regenerate with `python {LABEL}` (bit for bit; `--only {ds.name}` for this folder alone).
Every row of `jumps.csv`, `trajectories.csv` and `intrusions.csv` says
`synthetic: {LABEL} seed={ds.seed}` in its `source` column. The truth is in
`truth.toml` (the format of `granbayes/data/reference/truth.toml`, for
`granbayes fit --truth`) and `lab_truth.json` (the oracle's record: true robot, beds and
law); inference code never reads either.

## The true force law (SI)

Terms: {", ".join(f"`{t}`" for t in ds.terms)}; the bed's unloading `r_unload = 20`. The
robot is the nominal one of `granbayes/data/reference/experiment.toml` (the default robot
of physics-model.md, exactly: no calibration error); every bed's phi is exact.

| phi | law | heights' scatter sigma [mm] |
|---|---|---|
{law_rows}

## Design

| measurement | design |
|---|---|
{design_rows}

Columns: `jumps.csv`: phi [-], command, trial, height_mm [mm], freq_hz [Hz], jump (id
shared with `trajectories.csv`), bed, source. `trajectories.csv`: jump, phi, command,
trial, freq_hz, t_s [s, lab clock], x_foot_mm, x_rod_mm [mm], bed, source.
`intrusions.csv`: test, phi, speed_mm_s [mm/s], depth_mm [mm], force_N [N], bed, source.
"""
    (out / "README.md").write_text(text)


def main() -> None:
    """Write the folders asked for."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sets = data_sets()
    parser.add_argument("--only", choices=sorted(sets), action="append")
    parser.add_argument(
        "--out", type=Path, default=DATA, help="parent folder (default granbayes/data)"
    )
    args = parser.parse_args()
    for name in args.only or list(sets):
        counts = generate(sets[name], args.out / name)
        print(f"wrote {args.out / name}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))


if __name__ == "__main__":
    main()
