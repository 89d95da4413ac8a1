"""The SYNTHETIC lab (granbayes.testing.synthetic_lab_data): experiments as a lab has them.

Every number in the tables comes from the scipy oracle plus seeded noise. The tests check
the seeding (same seed, same tables; each component from its own stream), the columns and
units of docs/data-format.md, the noise statistics against their standard errors, the
truth behind the tables (robot off its nominal values, the granularity of the phi
scatter, the oracle's values at the true frame times), and the experiment folder (read by
the package's loaders, marked SYNTHETIC).

Noise statistics: with n independent draws the sample standard deviation has a relative
standard error of about 1 / sqrt(2 n); for an AR(1) series with lag-1 correlation rho it
is sqrt((1 + rho^2) / (2 n (1 - rho^2))), and the lag-1 sample correlation has an SE of
about sqrt((1 - rho^2) / n). The tests allow 4 standard errors.
"""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pandas as pd
import pytest

from granbayes import load_experiment, load_jumps
from granbayes._experiment import Experiment
from granbayes.testing import (
    LabDesign,
    RateStiffening,
    simulate_height_scipy,
    simulate_trajectory_scipy,
    synthetic_lab_data,
    write_lab_experiment,
)
from granbayes.testing._lab import _ar1

LAW = {"k": 3000.0, "c_d": 20.0}


def law_of_phi(phi: float) -> dict[str, float]:
    return {"k": 3000.0 + 1e5 * (phi - 0.612), "c_d": 20.0}


DESIGN = LabDesign(
    phis=(0.602, 0.622),
    commands=("single", "preload"),
    trials=30,
    sigma_mm=1.5,
    tracked_trials=1,
    fps=1000.0,
    frame_sd_mm=0.3,
    frame_rho=0.6,
    clock_sd_frames=2.0,
    track_from_s=-0.02,
    track_after_end_s=0.1,
    intrusion_speeds_mm_s=(0.0, 300.0),
    intrusion_repeats=2,
    depth_step_mm=0.5,
    depth_max_mm=40.0,
    force_sd_N=0.4,
)


@pytest.fixture(scope="module")
def lab():
    return synthetic_lab_data(law_of_phi, seed=11, design=DESIGN)


def test_the_same_seed_gives_the_same_tables(lab) -> None:
    """Same seed and design: equal tables; another seed: other noise, same truth."""
    again = synthetic_lab_data(law_of_phi, seed=11, design=DESIGN)
    for name in ("jumps", "trajectories", "intrusions", "beds"):
        pd.testing.assert_frame_equal(getattr(lab, name), getattr(again, name))
    other = synthetic_lab_data(law_of_phi, seed=12, design=DESIGN)
    assert not np.allclose(other.jumps["height_mm"], lab.jumps["height_mm"])
    np.testing.assert_array_equal(other.jumps["true_height_mm"], lab.jumps["true_height_mm"])


def test_each_component_draws_from_its_own_stream() -> None:
    """Dropping the filmed jumps and the intrusion tests leaves the heights' draws as they
    were: the tables of one design do not depend on what else is measured."""
    full = synthetic_lab_data(LAW, seed=5, design=LabDesign(phis=(0.612,), commands=("single",)))
    heights_only = synthetic_lab_data(
        LAW,
        seed=5,
        design=LabDesign(
            phis=(0.612,), commands=("single",), tracked_trials=0, intrusion_speeds_mm_s=()
        ),
    )
    pd.testing.assert_frame_equal(full.jumps, heights_only.jumps)
    assert heights_only.trajectories.empty and heights_only.intrusions.empty


def test_columns_and_units_are_those_of_data_format(lab) -> None:
    jumps, traj, intr = lab.jumps, lab.trajectories, lab.intrusions
    assert list(jumps.columns[:5]) == ["phi", "command", "height_mm", "trial", "freq_hz"]
    assert {"jump", "bed", "source", "true_height_mm"} <= set(jumps.columns)
    assert list(traj.columns[:8]) == [
        "jump",
        "phi",
        "command",
        "trial",
        "freq_hz",
        "t_s",
        "x_foot_mm",
        "x_rod_mm",
    ]
    assert list(intr.columns[:5]) == ["test", "phi", "speed_mm_s", "depth_mm", "force_N"]
    assert len(jumps) == 2 * 2 * 30 and jumps["jump"].is_unique
    assert set(traj["jump"]) == set(jumps.loc[jumps["trial"] == 1, "jump"])
    for _, frames in traj.groupby("jump"):
        assert np.all(np.diff(frames["t_s"]) > 0.0)  # strictly increasing
        assert np.allclose(np.diff(frames["t_s"]), 1e-3)  # 1000 frames per second
        assert frames[["phi", "command", "trial", "bed"]].nunique().max() == 1
        assert frames["t_s"].iloc[0] == pytest.approx(-0.02)
    for _, samples in intr.groupby("test"):
        assert samples[["phi", "speed_mm_s", "bed"]].nunique().max() == 1
        np.testing.assert_allclose(samples["depth_mm"], np.arange(81) * 0.5)
    assert intr["test"].nunique() == 2 * 2 * 2
    # the heights are millimetres, as the oracle's: a default robot jumps tens of mm
    assert 10.0 < jumps["true_height_mm"].median() < 200.0
    source = "synthetic: granbayes.testing.synthetic_lab_data seed=11"
    assert lab.source == source
    for table in (jumps, traj, intr):
        assert set(table["source"]) == {source}


def test_the_truth_is_the_oracles(lab) -> None:
    """Noise-free values: the heights are the oracle's at the bed's true phi; a filmed
    jump's frames are the oracle's at the true (command-clock) frame times, and its height
    row is the same simulation's."""
    row = lab.jumps.iloc[0]
    true_phi = lab.beds.set_index("bed").loc[row["bed"], "true_phi"]
    assert row["true_height_mm"] == simulate_height_scipy(
        row["command"], true_phi, law_of_phi(true_phi)
    )
    frames = lab.trajectories[lab.trajectories["jump"] == row["jump"]]
    traj = simulate_trajectory_scipy(
        row["command"], true_phi, law_of_phi(true_phi), frames["true_t_s"].to_numpy()
    )
    np.testing.assert_array_equal(frames["true_x_foot_mm"], traj.x_foot_mm)
    np.testing.assert_array_equal(frames["true_x_rod_mm"], traj.x_rod_mm)
    assert traj.height_mm == row["true_height_mm"]
    cell = lab.jumps[(lab.jumps["phi"] == row["phi"]) & (lab.jumps["command"] == row["command"])]
    assert cell["true_height_mm"].nunique() == 1  # one bed per phi level: one simulation


def test_height_noise_statistics(lab) -> None:
    """Residuals (written minus true; rounding to 1 um adds < 3e-4 mm sd): mean 0 within 4
    SE (sigma / sqrt(n)), sd within 4 SE (sigma / sqrt(2 n))."""
    res = lab.jumps["height_mm"] - lab.jumps["true_height_mm"]
    n, sigma = len(res), DESIGN.sigma_mm
    assert abs(res.mean()) < 4.0 * sigma / math.sqrt(n)
    assert abs(res.std() - sigma) < 4.0 * sigma / math.sqrt(2 * n)


def test_frame_noise_statistics(lab) -> None:
    """Per coordinate, pooled over the filmed jumps: marginal sd and lag-1 correlation of
    the AR(1) frame noise within 4 SE; the clock offset is one per jump (t_s - true_t_s
    constant within a jump) and a few frames."""
    traj = lab.trajectories
    sd, rho = DESIGN.frame_sd_mm, DESIGN.frame_rho
    for coordinate in ("x_foot_mm", "x_rod_mm"):
        noise = [
            (frames[coordinate] - frames[f"true_{coordinate}"]).to_numpy()
            for _, frames in traj.groupby("jump")
        ]
        pooled = np.concatenate(noise)
        n = pooled.size
        se_sd = sd * math.sqrt((1 + rho**2) / (2 * n * (1 - rho**2)))
        assert abs(pooled.std() - sd) < 4.0 * se_sd, coordinate
        lag1 = sum(float(np.sum(e[1:] * e[:-1])) for e in noise) / sum(
            float(np.sum(e[:-1] ** 2)) for e in noise
        )
        assert abs(lag1 - rho) < 4.0 * math.sqrt((1 - rho**2) / n), (coordinate, lag1)
    offsets = traj["t_s"] - traj["true_t_s"]
    per_jump = offsets.groupby(traj["jump"])
    assert (per_jump.max() - per_jump.min()).max() < 1e-9
    frames = per_jump.first() * DESIGN.fps
    assert frames.abs().max() < 6.0 * DESIGN.clock_sd_frames and frames.abs().max() > 0.0


def test_ar1_generator_statistics() -> None:
    """The AR(1) series itself, on 200,000 draws: sd and lag-1 correlation within 4 SE."""
    rng = np.random.default_rng(0)
    n, sd, rho = 200_000, 0.25, 0.8
    e = _ar1(rng, n, sd, rho)
    se_sd = sd * math.sqrt((1 + rho**2) / (2 * n * (1 - rho**2)))
    assert abs(e.std() - sd) < 4.0 * se_sd
    lag1 = np.corrcoef(e[1:], e[:-1])[0, 1]
    assert abs(lag1 - rho) < 4.0 * math.sqrt((1 - rho**2) / n)
    lag2 = np.corrcoef(e[2:], e[:-2])[0, 1]
    assert abs(lag2 - rho**2) < 0.01
    assert _ar1(rng, 0, sd, rho).shape == (0,)


def test_force_noise_statistics(lab) -> None:
    res = lab.intrusions["force_N"] - lab.intrusions["true_force_N"]
    n, sd = len(res), DESIGN.force_sd_N
    assert abs(res.mean()) < 4.0 * sd / math.sqrt(n)
    assert abs(res.std() - sd) < 4.0 * sd / math.sqrt(2 * n)


def test_robot_off_its_nominal_values_and_beds_off_their_phi() -> None:
    """Calibration sds draw a true robot (the TOML keeps the nominal one); given true
    values are used as they are; phi scatters per level or per jump, as asked."""
    design = LabDesign(
        phis=(0.602, 0.622),
        commands=("single",),
        trials=3,
        tracked_trials=1,
        track_after_end_s=0.0,
        intrusion_speeds_mm_s=(100.0,),
        depth_max_mm=5.0,
        robot_sd={"k_spring": 150.0, "m_motor": 0.01, "amplitude_mm": 0.5},
        robot_true={"m_foot": 0.12},
        phi_sd=0.003,
    )
    data = synthetic_lab_data(law_of_phi, seed=3, design=design)
    nominal, true = data.experiment, data.true_experiment
    assert nominal == Experiment()
    assert true.robot.m_foot == 0.12
    for key in ("k_spring", "m_motor"):
        assert getattr(true.robot, key) != getattr(nominal.robot, key)
    assert abs(true.robot.k_spring - 5760.0) < 6 * 150.0
    assert true.command.amplitude_mm != 20.0
    assert data.uncertainty == {"k_spring": 150.0, "m_motor": 0.01, "amplitude_mm": 0.5}
    # one bed per level: every table at a level shares it
    assert len(data.beds) == 2 and np.all(data.beds["true_phi"] != data.beds["phi"])
    for table in (data.jumps, data.trajectories, data.intrusions):
        assert (table.groupby("phi")["bed"].nunique() == 1).all()
    assert data.jumps.groupby("phi")["true_height_mm"].nunique().max() == 1
    # one bed per jump and per test; a filmed jump's frames are on its own bed
    per_jump = synthetic_lab_data(
        law_of_phi, seed=3, design=LabDesign(**{**vars(design), "phi_jitter": "jump"})
    )
    assert len(per_jump.beds) == len(per_jump.jumps) + per_jump.intrusions["test"].nunique()
    assert per_jump.jumps["true_height_mm"].nunique() == len(per_jump.jumps)
    filmed = per_jump.jumps.set_index("jump").loc[per_jump.trajectories["jump"], "bed"]
    np.testing.assert_array_equal(filmed.to_numpy(), per_jump.trajectories["bed"].to_numpy())
    scatter = per_jump.beds["true_phi"] - per_jump.beds["phi"]
    assert scatter.std() == pytest.approx(0.003, rel=0.6)  # 8 beds: SE of the sd ~25%
    with pytest.raises(KeyError, match="unknown robot key"):
        LabDesign(robot_sd={"k": 1.0})


def test_effects_reach_every_table() -> None:
    design = LabDesign(
        phis=(0.612,),
        commands=("single",),
        trials=1,
        track_after_end_s=0.0,
        intrusion_speeds_mm_s=(200.0,),
        depth_max_mm=5.0,
        sigma_mm=0.0,
        frame_sd_mm=0.0,
        force_sd_N=0.0,
        clock_sd_frames=0.0,
    )
    plain = synthetic_lab_data(LAW, seed=1, design=design)
    hidden = synthetic_lab_data(LAW, seed=1, design=design, effects=(RateStiffening(0.5),))
    assert hidden.effects == (RateStiffening(0.5),)
    assert (hidden.jumps["height_mm"] > plain.jumps["height_mm"] + 1.0).all()
    assert not np.allclose(hidden.trajectories["x_foot_mm"], plain.trajectories["x_foot_mm"])
    deep = hidden.intrusions["depth_mm"] > 0.0
    assert (hidden.intrusions["force_N"][deep] > plain.intrusions["force_N"][deep]).all()


def test_a_map_callable_gives_the_same_data() -> None:
    """The simulations may run anywhere: a map-like executor changes nothing."""
    design = LabDesign(
        phis=(0.612,), commands=("single", "preload"), trials=2, track_after_end_s=0.05
    )
    calls = []

    def counting_map(fn, tasks):
        tasks = list(tasks)
        calls.append(len(tasks))
        return map(fn, tasks)

    serial = synthetic_lab_data(LAW, seed=2, design=design)
    mapped = synthetic_lab_data(LAW, seed=2, design=design, executor=counting_map)
    assert calls == [4]  # per cell: one filmed jump, one height shared by the other trial
    for name in ("jumps", "trajectories", "intrusions"):
        pd.testing.assert_frame_equal(getattr(serial, name), getattr(mapped, name))


@pytest.mark.slow
def test_a_dask_client_gives_the_same_data() -> None:
    from dask.distributed import Client, LocalCluster

    design = LabDesign(
        phis=(0.612,), commands=("single", "preload"), trials=2, track_after_end_s=0.05
    )
    serial = synthetic_lab_data(LAW, seed=2, design=design)
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True) as cluster,
        Client(cluster) as client,
    ):
        distributed = synthetic_lab_data(LAW, seed=2, design=design, executor=client)
    for name in ("jumps", "trajectories", "intrusions"):
        pd.testing.assert_frame_equal(getattr(serial, name), getattr(distributed, name))


def test_the_folder_is_an_experiment(lab, tmp_path) -> None:
    """Without uncertainties the folder loads as it is (nominal robot, the jumps); the
    CSV files hold the tables without their true_* columns."""
    folder = write_lab_experiment(tmp_path / "exp", lab)
    text = (folder / "experiment.toml").read_text()
    assert text.startswith("# SYNTHETIC data (granbayes.testing.synthetic_lab_data, seed=11)")
    assert load_experiment(folder).robot == Experiment().robot
    jumps = load_jumps(folder)
    np.testing.assert_array_equal(jumps["height_mm"], lab.jumps["height_mm"])
    assert set(jumps["source"]) == {lab.source}
    for name, table in (("trajectories.csv", lab.trajectories), ("intrusions.csv", lab.intrusions)):
        written = pd.read_csv(folder / name)
        assert not any(c.startswith("true_") for c in written.columns)
        expected = table.drop(columns=[c for c in table.columns if c.startswith("true_")])
        pd.testing.assert_frame_equal(written, expected, check_dtype=False)
    assert (folder / "lab_truth.json").exists()


def test_uncertainties_are_written_to_the_toml(lab, tmp_path) -> None:
    """[robot.uncertainty] and [bed] phi_sd as data-format.md shows them; the robot
    section keeps the nominal values, and the loader reads the uncertainties back. Tables
    of an earlier experiment written to the same folder do not stay behind."""
    design = LabDesign(
        phis=(0.612,),
        commands=("single",),
        trials=2,
        tracked_trials=0,
        intrusion_speeds_mm_s=(),
        robot_sd={"k_spring": 150.0, "amplitude_mm": 0.5},
        phi_sd=0.002,
    )
    data = synthetic_lab_data(LAW, seed=4, design=design)
    write_lab_experiment(tmp_path / "exp", lab)
    folder = write_lab_experiment(tmp_path / "exp", data)
    toml = tomllib.loads((folder / "experiment.toml").read_text())
    assert toml["robot"]["uncertainty"] == {"k_spring": 150.0, "amplitude_mm": 0.5}
    assert toml["robot"]["k_spring"] == 5760.0 and toml["command"]["amplitude_mm"] == 20.0
    assert toml["bed"] == {"phi_c": 0.612, "phi_sd": 0.002}
    assert len(load_jumps(folder)) == 2
    assert not (folder / "trajectories.csv").exists() and not (folder / "intrusions.csv").exists()
    exp = load_experiment(folder)  # read and kept; the robot keeps its nominal values
    assert exp.robot == Experiment().robot
    assert exp.uncertainty == {"k_spring": 150.0, "amplitude_mm": 0.5}
    assert exp.phi_sd == 0.002 and exp.uncertain
    plain = write_lab_experiment(tmp_path / "plain", data, uncertainties=False, truth_file=False)
    assert load_experiment(plain).robot == Experiment().robot
    assert not (plain / "lab_truth.json").exists()
