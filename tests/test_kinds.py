"""Kinds of measurement beyond jump heights: loading, the likelihood blocks, one joint fit.

The data are SYNTHETIC, from the independent scipy oracle (``granbayes.testing``'s lab),
never from the kernel under test. The statistical checks are seeded; their tolerances are
stated where they are made.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from granbayes._cli import EXIT_INPUT, EXIT_OK, main
from granbayes._datatree import read_datatree
from granbayes._experiment import Experiment, load_experiment
from granbayes._likelihood import ObservationSettings, Simulated, TrajectoryBlock
from granbayes.kinds import KINDS, kind_names, load_measurements
from granbayes.testing import SMALL_LAB, LabDesign, synthetic_lab_data, write_lab_experiment

TRUTH = {"k": 3000.0, "c_d": 20.0}

#: The small SYNTHETIC lab (generator granbayes.testing.synthetic_lab_data, seed 11).
SMALL = SMALL_LAB


@pytest.fixture(scope="module")
def lab_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The SMALL lab's experiment folder (every kind)."""
    data = synthetic_lab_data(TRUTH, seed=11, design=SMALL)
    return write_lab_experiment(tmp_path_factory.mktemp("lab") / "exp", data)


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# ----------------------------------------------------------------------------------------
def test_registry_has_the_three_kinds() -> None:
    assert kind_names()[:3] == ("heights", "trajectories", "intrusions")
    assert KINDS["trajectories"].unit_dim == "trajectory"
    assert KINDS["intrusions"].unit_dim == "test"


def test_the_built_in_kinds_figures_name_functions_of_the_figures_module() -> None:
    """Each built-in kind names its figures (``FigureName``, so that importing the registry
    does not import matplotlib): every name is a function of ``granbayes.figures``, and
    the name survives pickling (Dask ships kinds to its workers)."""
    import pickle
    import subprocess
    import sys

    import granbayes.figures as figures
    from granbayes.kinds._kind import FigureName

    for name in ("heights", "trajectories", "intrusions"):
        assert KINDS[name].figures, name
        for stem, draw in KINDS[name].figures.items():
            assert isinstance(draw, FigureName), (name, stem)
            assert callable(getattr(figures, draw.name, None)), (name, stem, draw.name)
            assert pickle.loads(pickle.dumps(draw)) == draw
    code = "import sys, granbayes.kinds; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.stdout.strip() == "False", out.stderr


def test_load_measurements_reads_every_file_and_selects(lab_folder: Path) -> None:
    exp = Experiment()
    every = load_measurements(lab_folder, exp)
    assert every.kinds == ("heights", "trajectories", "intrusions")
    n_jumps = len(SMALL.phis) * len(SMALL.commands) * SMALL.trials * len(SMALL.freqs_hz)
    n_tracked = len(SMALL.phis) * len(SMALL.commands) * len(SMALL.freqs_hz)
    n_tests = len(SMALL.phis) * len(SMALL.intrusion_speeds_mm_s)
    assert every.n_units == n_jumps + n_tracked + n_tests
    only = load_measurements(lab_folder, exp, ["trajectories"])
    assert only.kinds == ("trajectories",)
    assert only.n_units == n_tracked


@pytest.mark.parametrize(
    ("file", "edit", "row", "column", "fragment"),
    [
        ("trajectories.csv", "t_back", 3, "t_s", "increase strictly"),
        ("trajectories.csv", "command_changes", 3, "command", "changes"),
        ("trajectories.csv", "no_position", None, "x_foot_mm", "no position column"),
        ("intrusions.csv", "negative_depth", 4, "depth_mm", "depth_mm"),
        ("intrusions.csv", "two_speeds", 4, "speed_mm_s", "changes"),
    ],
)
def test_bad_measurement_file_is_refused_with_file_row_column(
    lab_folder: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    file: str,
    edit: str,
    row: int | None,
    column: str,
    fragment: str,
) -> None:
    """Exit 2, one line naming the file, the row (data rows from 1) and the column;
    nothing written."""
    folder = tmp_path / "exp"
    folder.mkdir()
    for f in lab_folder.iterdir():
        if f.is_file():
            (folder / f.name).write_bytes(f.read_bytes())
    table = pd.read_csv(folder / file)
    i = row - 1 if row is not None else 0  # rows are numbered from 1 after the header
    if edit == "t_back":
        table.loc[i, "t_s"] = table.loc[i - 1, "t_s"]
    elif edit == "command_changes":
        first = table.loc[i, "command"]
        table.loc[i, "command"] = "stutter" if first != "stutter" else "single"
    elif edit == "no_position":
        table = table.drop(columns=[c for c in ("x_foot_mm", "x_rod_mm") if c in table])
    elif edit == "negative_depth":
        table.loc[i, "depth_mm"] = -1.0
    elif edit == "two_speeds":
        table.loc[i, "speed_mm_s"] = table.loc[i, "speed_mm_s"] + 1.0
    table.to_csv(folder / file, index=False)
    out = tmp_path / "OUT"
    code, stdout, err = run(
        capsys, "fit", str(folder), "--out", str(out), "--max-steps", "100", "--quiet"
    )
    assert code == EXIT_INPUT
    assert stdout == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert file in lines[0] and column in lines[0] and fragment in lines[0], lines[0]
    if row is not None:
        assert f"row {row}" in lines[0], lines[0]
    assert not out.exists() and not out.with_name("OUT.partial").exists()


def test_unknown_or_missing_kind_is_a_usage_error(
    lab_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = run(
        capsys, "fit", str(lab_folder), "--out", str(tmp_path / "o"), "--data", "videos"
    )
    assert code == EXIT_INPUT and "unknown kind of data videos" in err


# ----------------------------------------------------------------------------------------
def _block_of_one_jump(t: np.ndarray, x: np.ndarray, step_ms: float = 0.5) -> TrajectoryBlock:
    """A block of one tracked jump (foot only), its noise shared by all volume fractions."""
    table = pd.DataFrame(
        {
            "jump": "a",
            "phi": 0.612,
            "command": "single",
            "t_s": t,
            "x_foot_mm": x,
            "freq_hz": 10.0,
            "amplitude_mm": 20.0,
            "delay_ms": 0.0,
            "settle_periods": 0.0,
        }
    )
    settings = ObservationSettings(sigma_mode="global", max_offset_frames=2, offset_step_ms=step_ms)
    block = TrajectoryBlock(table, settings)
    block.coordinates({}, np.array([0.612]))
    return block


def test_clock_offset_marginal_is_exact_for_a_linear_motion() -> None:
    """For positions linear in time the linearised offset integral is exact: the block's
    likelihood equals brute-force quadrature over the offset (4,001 points) to 1e-6. With
    ``max_offset_frames = 2`` and 1 ms frames the grid has 2 sub-steps of 0.5 ms and the
    offset's prior is uniform over +/- 2.25 frame intervals."""
    dt = 1e-3
    t = np.arange(30) * dt
    speed_mm_s = 150.0
    rng = np.random.default_rng(3)
    true_offset = 0.7 * dt
    y = speed_mm_s * (t + true_offset) + 0.05 * rng.standard_normal(t.size)
    block = _block_of_one_jump(t, y)
    grid = np.concatenate(block.jump_request().frame_times_s)
    frames = np.zeros((1, grid.size, 4))
    frames[0, :, 0] = speed_mm_s * grid
    frames[0, :, 2] = speed_mm_s
    sim = Simulated(np.zeros((1, 1)), np.ones((1, 1), bool), frames)
    sd_mm, tau_ms = 0.05, 0.4
    value = {"frame_sd_foot_mm": sd_mm, "frame_tau_ms": tau_ms}
    u = np.array([[c.prior.to_u(np.array([value[c.parameter]]))[0] for c in block._coords]])
    got = float(block.log_lik(u, None, sim)[0, 0])
    # brute force: OU likelihood of y - v (t + delta) averaged over delta ~ U(+/- 2.25 dt)
    assert block.substeps == 2
    rho = math.exp(-dt / (tau_ms * 1e-3))
    deltas = np.linspace(-2.25 * dt, 2.25 * dt, 4001)
    lls = []
    for d in deltas:
        r = y - speed_mm_s * (t + d)
        w = np.empty_like(r)
        w[0] = r[0] / sd_mm
        w[1:] = (r[1:] - rho * r[:-1]) / (sd_mm * math.sqrt(1 - rho * rho))
        logdet = math.log(sd_mm) + (r.size - 1) * math.log(sd_mm * math.sqrt(1 - rho * rho))
        lls.append(-0.5 * np.sum(w * w) - logdet - 0.5 * r.size * math.log(2 * math.pi))
    lls = np.array(lls)
    peak = lls.max()
    # trapezoid rule of the mean over the offset's uniform prior
    mean = np.trapezoid(np.exp(lls - peak), deltas) / (deltas[-1] - deltas[0])
    assert got == pytest.approx(peak + math.log(mean), abs=1e-6)


# ----------------------------------------------------------------------------------------
@pytest.mark.long
def test_joint_fit_cli_keeps_every_kind_on_its_own_dims(
    lab_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``granbayes fit`` on heights, tracked jumps and intrusion curves together: one
    DataTree with each kind's observed data, log-likelihood and replicates on its own
    dimensions, the observation models' parameters in the posterior, each kind's cells
    and figures in the report, and the fit read back by ``load_fit`` (a capped smoke
    run; recovery is ``test_joint_fit_recovers_the_truth``)."""
    out = tmp_path / "OUT"
    code, _, err = run(
        capsys,
        "fit",
        str(lab_folder),
        "--out",
        str(out),
        "--terms",
        "depth,drag",
        "--max-steps",
        "100",
        "--ensembles",
        "2",
        "--start",  # the search's ball: no climbs (the start is not what this checks)
        "search",
        "--allow-unconverged",
        "--quiet",
        "--seed",
        "2",
    )
    assert code == EXIT_OK, err
    dt = read_datatree(out / "posterior.nc")
    ll = dt["log_likelihood"].to_dataset()
    assert set(ll.data_vars) == {"height_mm", "tracked_jump", "intrusion"}
    assert ll["tracked_jump"].dims[-1] == "trajectory" and ll.sizes["trajectory"] == 2
    assert ll["intrusion"].dims[-1] == "test" and ll.sizes["test"] == 4
    # the units' kinds (the strata of diagnose's paired SEs) in the pointwise order
    from granbayes.stats import unit_kinds

    names = {"heights": "height_mm", "trajectories": "tracked_jump", "intrusions": "intrusion"}
    units = load_measurements(lab_folder, load_experiment(lab_folder)).units
    assert [names[k] for k in units["kind"]] == unit_kinds(dt).tolist()
    obs = dt["observed_data"].to_dataset()
    for name in ("height_mm", "x_foot_mm", "x_rod_mm", "force_N"):
        assert name in obs, name
    pp = dt["posterior_predictive"].to_dataset()
    assert pp["x_foot_mm"].dims == ("predictive_draw", "frame")
    assert pp["force_N"].dims == ("chain", "draw", "reading")
    assert np.all(np.isfinite(pp["x_foot_mm"].values))
    post = dt["posterior"].to_dataset()
    for name in ("sigma_mm", "frame_sd_foot_mm", "frame_sd_rod_mm", "frame_tau_ms", "force_sd_N"):
        assert name in post, name
    for name in ("trajectories.png", "intrusions.png", "cells_trajectories.csv"):
        assert (out / name).is_file(), name
    summary = (out / "summary.md").read_text()
    assert "Where the law misses: trajectories" in summary
    from granbayes import load_fit

    again = load_fit(out)
    data = again.measurements() if callable(getattr(again, "measurements", None)) else None
    if data is not None:
        assert data.kinds == ("heights", "trajectories", "intrusions")


@pytest.mark.slow  # a second joint fit (~19 s): with the slow suite
def test_fit_data_option_selects_kinds(
    lab_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--data intrusions``: a fit of the force-depth curves alone (no simulation of a
    jump), whose log-likelihood is over tests only."""
    out = tmp_path / "OUT"
    code, _, err = run(
        capsys,
        "fit",
        str(lab_folder),
        "--out",
        str(out),
        "--data",
        "intrusions",
        "--terms",
        "depth,drag",
        "--max-steps",
        "100",
        "--ensembles",
        "2",
        "--allow-unconverged",
        "--quiet",
    )
    assert code == EXIT_OK, err
    dt = read_datatree(out / "posterior.nc")
    assert set(dt["log_likelihood"].data_vars) == {"intrusion"}
    assert "sigma_mm" not in dt["posterior"] and "force_sd_N" in dt["posterior"]


def _offset_error(step_ms: float) -> float:
    """Linearised marginal minus exact quadrature [nats] for one simulated tracked jump.

    A single jump at 500 frames/s with 0.2 mm white frame noise (seed 5) and a clock
    offset of 0.37 frames; the exact likelihood simulates the positions at each of 20,001
    offsets across the prior (no linearisation; the quadrature's own error is < 1e-4
    nats: 80,001 points give the same value to 4 decimals).
    """
    from granbayes._simulator import simulate_frames

    dt = 2e-3
    t = np.arange(-0.01, 0.15, dt)
    law = {"k": 3000.0, "c_d": 20.0}
    rng = np.random.default_rng(5)
    exact = simulate_frames("single", 0.612, law, t + 0.37 * dt).data["x_foot_mm"].to_numpy()
    y = exact + 0.2 * rng.standard_normal(t.size)
    block = _block_of_one_jump(t, y, step_ms)
    grid = np.concatenate(block.jump_request().frame_times_s)
    cols = ["x_foot_mm", "x_rod_mm", "v_foot_mm_s", "v_rod_mm_s"]
    frames = simulate_frames("single", 0.612, law, grid).data[cols].to_numpy()[None]
    sim = Simulated(np.zeros((1, 1)), np.ones((1, 1), bool), frames)
    sd_mm, tau_ms = 0.2, 1e-3  # white noise: successive frames' correlation exp(-2000)
    value = {"frame_sd_foot_mm": sd_mm, "frame_tau_ms": tau_ms}
    u = np.array([[c.prior.to_u(np.array([value[c.parameter]]))[0] for c in block._coords]])
    got = float(block.log_lik(u, None, sim)[0, 0])
    half = 2 * dt + 0.5 * dt / block.substeps
    deltas = np.linspace(-half, half, 20001)
    times = (t[None, :] + deltas[:, None]).ravel()
    x = simulate_frames("single", 0.612, law, times).data["x_foot_mm"].to_numpy()
    r = y[None, :] - x.reshape(deltas.size, t.size)
    norm = t.size * math.log(sd_mm * math.sqrt(2 * math.pi))
    lls = -0.5 * np.sum((r / sd_mm) ** 2, axis=1) - norm
    peak = lls.max()
    return got - (peak + math.log(np.trapezoid(np.exp(lls - peak), deltas) / (2 * half)))


def test_clock_offset_marginal_converges_to_the_exact_one() -> None:
    """The default grid (0.25 ms) is within 0.02 nats of the exact marginal likelihood
    (measured 0.006), and the error falls at least 8-fold when the step falls 4-fold
    (second order: a linearisation error ``a h^2 / 2``; measured 0.144 -> 0.006 nats from
    1 ms to 0.25 ms, 0.52 nats with the whole 2 ms frame interval as the step)."""
    default = ObservationSettings().offset_step_ms
    assert default == 0.25
    assert abs(_offset_error(default)) < 0.02
    assert abs(_offset_error(1.0)) > 8 * abs(_offset_error(0.25))


# ----------------------------------------------------------------------------------------
#: A hidden viscous force (b = 2 N s/m on top of depth and drag) that changes a jump's
#: height by 0.7 mm (against 3 mm scatter, 3 trials per cell) but its trajectory by up to
#: 1.3 mm (against 0.2 mm frame noise, ~250 frames per tracked jump).
HIDDEN_VISCOUS = LabDesign(
    phis=(0.612,),
    commands=("single", "preload"),
    trials=3,
    sigma_mm=3.0,
    tracked_trials=1,
    fps=1000.0,
    frame_sd_mm=0.2,
    frame_rho=0.3,
    clock_sd_frames=1.0,
    track_from_s=-0.01,
    track_after_end_s=0.08,
    intrusion_speeds_mm_s=(),
)


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="measured 2026-11-27 (first completed run, 12 min): with 2 tracked jumps the "
    "trajectories do not show viscous b = 2 N s/m by the rule either: depth + drag absorbs "
    "it through k and c_d (3020 N/m, 23.1 kg/m against 3000, 20; frame noise 0.21 mm, "
    "recovered), no misfit cell, viscous's screening gain +3.3 nats < 4 (+3.1 fitted, "
    "b = 1.6); the design lacks power, not the likelihood",
)
def test_hidden_effect_heights_barely_show_is_found_in_the_trajectories(tmp_path: Path) -> None:
    """SYNTHETIC oracle data (seed 21) with a hidden viscous force: ``diagnose`` on the
    jump heights alone does not name it (the effect is a quarter of the heights' scatter);
    on heights and tracked jumps it should find the misfit in the trajectories and name
    ``viscous``. Candidates are limited to viscous, stiffening and added mass. It does not
    (the xfail's reason): one filmed trial per command is too little; a design that films
    every trial (3x the frames: about 9 nats expected from the 3.1 measured) is the next
    test to run."""
    from granbayes._criticism import DiagnoseSettings, diagnose

    truth = {"k": 3000.0, "c_d": 20.0, "b": 2.0}
    data = synthetic_lab_data(truth, seed=21, design=HIDDEN_VISCOUS)
    folder = write_lab_experiment(tmp_path / "exp", data)
    exp = load_experiment(folder)
    config = DiagnoseSettings(
        baseline=("depth", "drag"), candidates=("viscous", "stiffening", "added_mass")
    )
    heights = diagnose(exp, load_measurements(folder, exp, ["heights"]), config, seed=3)
    assert "viscous" not in heights.added
    both = diagnose(
        exp, load_measurements(folder, exp, ["heights", "trajectories"]), config, seed=3
    )
    assert both.record.n_misfit_cells > 0
    assert any(c.kind == "trajectories" and c.significant for c in both.record.misfit)
    assert both.added[:1] == ["viscous"]


@pytest.mark.slow
def test_hidden_viscous_is_found_when_every_trial_is_filmed(tmp_path: Path) -> None:
    """The design of the test above with every trial filmed (6 tracked jumps, not 2): the
    design a lab that films every jump has, chosen after the one-filmed-trial design fell
    short (3.1 nats measured there, about 9 expected from three times the frames).
    Measured on its first run (2026-11-27, 409 s on 2 cores): viscous named with an ELPD
    gain of +30.8 +- 13.1 nats, 2 misfit cells; stiffening close behind (+25.8 +- 10.3,
    not distinguished from viscous: +5.0 +- 3.4, which the diagnosis reports). Rerun
    2026-11-28 with the SE stratified by kind (74 s on a quiet 2-core machine): viscous
    named, +33.2 +- 9.7 nats; stiffening screened out (+25.5 < 26.8)."""
    from granbayes._criticism import DiagnoseSettings, diagnose

    design = dataclasses.replace(HIDDEN_VISCOUS, tracked_trials=3)
    data = synthetic_lab_data({"k": 3000.0, "c_d": 20.0, "b": 2.0}, seed=21, design=design)
    folder = write_lab_experiment(tmp_path / "exp", data)
    exp = load_experiment(folder)
    config = DiagnoseSettings(
        baseline=("depth", "drag"), candidates=("viscous", "stiffening", "added_mass")
    )
    both = diagnose(
        exp, load_measurements(folder, exp, ["heights", "trajectories"]), config, seed=3
    )
    assert both.record.n_misfit_cells > 0
    assert both.added[:1] == ["viscous"]
