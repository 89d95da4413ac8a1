"""Tests of simulation-based calibration (``granbayes._sbc``, ``granbayes sbc``) on Dask.

All data here are SYNTHETIC. The design is tiny (2 volume fractions x 2 commands x 1
trial) and the fits are capped (8 walkers, 100 steps, ranks among 19 draws), so one
replicate costs about a second: these tests check the machinery (real scheduler and
workers, kill and resume, seeds, refusals), not calibration itself; a calibration study
needs converged fits and >= 100 replicates (``benchmarks/sbc_reference.py``).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from distributed import Client
from scipy.stats import norm

from granbayes import (
    Experiment,
    default_priors,
    load_experiment,
    load_jumps,
    load_measurements,
)
from granbayes._cli import EXIT_INPUT, EXIT_OK, main
from granbayes._fitting import FitSettings, part_models
from granbayes._sampler import SamplerSettings
from granbayes._sbc import draw_beds, draw_measurements, replicate_ranks, run_sbc
from granbayes.campaign import ClusterSettings, spawn_seeds
from granbayes.stats import summarize_ranks
from granbayes.testing import (
    LabDesign,
    intrusion_force_scipy,
    replicate_measurements,
    simulate_height_scipy,
    simulate_trajectory_scipy,
    synthetic_jumps,
    synthetic_lab_data,
    write_lab_experiment,
)
from granbayes.testing._replicate import _ou

BIN = Path(sys.executable).parent
#: Capped fits for machinery tests (not converged; not a calibration study).
FAST = ["--walkers", "8", "--max-steps", "100", "--rank-draws", "19", "--quiet"]
#: The machinery tests start the walkers from the search's ball: the Laplace start's climb was
#: half of a capped replicate's time, and it is the campaign these tests check.
MACHINERY = [*FAST, "--start", "search"]
FAST_CONFIG = FitSettings(
    terms=("depth", "drag"),
    sampler=SamplerSettings(n_walkers=8, check_every=100, max_steps=100, n_draws=125),
)
PARAMETERS = ("k", "c_d", "sigma_mm")


@pytest.fixture(scope="module")
def design(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny experiment folder: its jumps define the design (heights are not used)."""
    folder = tmp_path_factory.mktemp("design")
    (folder / "experiment.toml").write_text("# SYNTHETIC test design\n[bed]\nphi_c = 0.612\n")
    (folder / "jumps.csv").write_text(
        "phi,command,freq_hz,trial,height_mm\n"
        "0.602,single,10,1,30.0\n0.602,preload,10,1,40.0\n"
        "0.622,single,10,1,35.0\n0.622,preload,10,1,45.0\n"
    )
    return folder


def check_outputs(out: Path, n_replicates: int) -> pd.DataFrame:
    """The SBC outputs are complete: one rank per replicate, phi and parameter."""
    ranks = pd.read_csv(out / "ranks.csv")
    assert len(ranks) == n_replicates * 2 * len(PARAMETERS)
    assert not ranks.duplicated(["replicate", "phi", "parameter"]).any()
    assert sorted(ranks["replicate"].unique()) == list(range(n_replicates))
    assert ranks["rank"].between(0, 19).all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_replicates_ok"] == n_replicates
    assert {(p["parameter"], p["phi"]) for p in summary["parameters"]} == {
        (name, phi) for name in PARAMETERS for phi in (0.602, 0.622)
    }
    for p in summary["parameters"]:
        assert 0.0 <= p["uniformity"]["p_value"] <= 1.0
        assert set(p["coverage"]) == {"50%", "90%"}
    assert (out / "sbc_ecdf.png").stat().st_size > 10_000
    tasks = pd.read_csv(out / "tasks.csv")
    assert (tasks["status"] == "ok").all() and len(tasks) == n_replicates
    return ranks


# ----------------------------------------------------------------------------------------
# Statistics (no cluster)
# ----------------------------------------------------------------------------------------
def test_summary_of_uniform_and_of_biased_ranks(rng: np.random.Generator) -> None:
    n, n_draws = 400, 99

    def table(ranks: np.ndarray) -> pd.DataFrame:
        return pd.DataFrame(
            {
                "replicate": np.arange(n),
                "phi": 0.6,
                "parameter": "k",
                "rank": ranks,
                "n_draws": n_draws,
                "converged": True,
            }
        )

    uniform = summarize_ranks(table(rng.integers(0, n_draws + 1, n)))[0]
    assert uniform["uniformity"]["bins"] == 20
    assert uniform["uniformity"]["p_value"] > 0.01
    assert uniform["uniformity"]["pot_c_p_value"] > 0.01
    for level, cov in (("50%", 0.5), ("90%", 0.9)):
        c = uniform["coverage"][level]
        assert c["nominal"] == pytest.approx(cov)
        assert abs(c["observed"] - cov) < 4 * c["nominal_se"]
        assert c["se"] == pytest.approx(np.sqrt(c["observed"] * (1 - c["observed"]) / n))
    # an overconfident posterior: the truth falls in the tails too often
    tails = np.where(rng.random(n) < 0.5, rng.integers(0, 10, n), rng.integers(90, 100, n))
    biased = summarize_ranks(table(tails))[0]
    assert biased["uniformity"]["p_value"] < 1e-6
    assert biased["coverage"]["50%"]["observed"] == 0.0


# ----------------------------------------------------------------------------------------
# (a) a real scheduler and two workers as separate processes
# ----------------------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(procs: list[subprocess.Popen]) -> None:
    """Stop the process groups this test started (each process leads its own group)."""
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
    deadline = time.monotonic() + 15
    for p in procs:
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=10)


@pytest.fixture
def dask_cluster(tmp_path: Path) -> Iterator[tuple[str, list[str]]]:
    """``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1 (cleaned up)."""
    address = f"tcp://127.0.0.1:{_free_port()}"
    env = {**os.environ, "NUMBA_NUM_THREADS": "1"}
    log = open(tmp_path / "dask.log", "w")
    common = {"stdout": log, "stderr": subprocess.STDOUT, "env": env, "start_new_session": True}
    procs = [
        subprocess.Popen(
            [
                BIN / "dask",
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                address.rsplit(":")[-1],
                "--dashboard-address",
                "127.0.0.1:0",
            ],
            **common,
        )
    ]
    try:
        for name in ("w1", "w2"):
            procs.append(
                subprocess.Popen(
                    [
                        BIN / "dask",
                        "worker",
                        address,
                        "--name",
                        name,
                        "--nthreads",
                        "1",
                        "--host",
                        "127.0.0.1",
                        "--no-dashboard",
                        "--death-timeout",
                        "60",
                    ],
                    **common,
                )
            )
        with Client(address, timeout="60s", set_as_default=False) as client:
            client.wait_for_workers(2, timeout=90)
            workers = sorted(client.scheduler_info()["workers"])
        yield address, workers
    finally:
        _stop(procs)
        log.close()


@pytest.mark.long
def test_sbc_runs_on_a_dask_scheduler_with_two_worker_processes(
    tmp_path: Path, design: Path, dask_cluster: tuple[str, list[str]]
) -> None:
    address, workers = dask_cluster
    out = tmp_path / "sbc"
    code = main(
        [
            *["sbc", str(design), "--out", str(out), "--replicates", "4", "--seed", "2"],
            *MACHINERY,
            "--scheduler",
            address,
        ]
    )
    assert code == EXIT_OK
    ranks = check_outputs(out, 4)
    tasks = pd.read_csv(out / "tasks.csv")
    assert set(tasks["worker"]) == set(workers)  # both workers, and only those, ran them
    assert set(ranks["worker"]) <= set(workers)
    assert json.loads((out / "summary.json").read_text())["workers"] == workers


# ----------------------------------------------------------------------------------------
# (b) a killed campaign resumes without recomputing finished replicates
# ----------------------------------------------------------------------------------------
@pytest.mark.slow  # ~20-35 s; a killed campaign's resume in the fast suite: test_campaign.py
def test_killed_campaign_resumes_without_recomputing(
    tmp_path: Path, design: Path, kill_when_written
) -> None:
    out = tmp_path / "sbc"
    partial = tmp_path / "sbc.partial"
    args = ["sbc", str(design), "--out", str(out), "--replicates", "3", "--seed", "4"]
    args += MACHINERY
    kill_when_written(
        [BIN / "granbayes", *args, "--workers", "1"], partial / "tasks", "replicate-*.json"
    )
    assert not out.exists()  # the output appears only when the campaign completes
    finished = {
        p.name: (p.read_bytes(), p.stat().st_mtime_ns)
        for p in (partial / "tasks").glob("replicate-*.json")
    }
    assert 1 <= len(finished) < 3

    assert main([*args, "--resume", "--workers", "2"]) == EXIT_OK
    for name, (content, mtime) in finished.items():  # not recomputed, not rewritten
        path = out / "tasks" / name
        assert (path.read_bytes(), path.stat().st_mtime_ns) == (content, mtime)
    check_outputs(out, 3)
    assert not partial.exists()
    assert not list((out / "tasks").glob(".*"))  # no half-written leftovers


# ----------------------------------------------------------------------------------------
# (d) refusals and (e) seeds
# ----------------------------------------------------------------------------------------
@pytest.mark.slow  # two SBC campaigns (~34 s): with the slow suite
def test_same_seed_same_ranks_with_one_or_two_workers_and_foreign_resume_refused(
    tmp_path: Path, design: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    experiment = load_experiment(design)
    jumps = load_jumps(design, experiment)
    runs = {}
    for workers in (1, 2):
        res = run_sbc(
            experiment,
            jumps,
            tmp_path / f"w{workers}",
            settings=FAST_CONFIG,
            n_replicates=2,
            seed=9,
            n_rank_draws=19,
            cluster=ClusterSettings(n_workers=workers),
            progress=False,
        )
        assert res.campaign.n_failed == 0
        runs[workers] = res.ranks.drop(columns=["worker"])
    pd.testing.assert_frame_equal(runs[1], runs[2])
    assert len(runs[1]) == 2 * 2 * len(PARAMETERS)

    # --resume with another seed, other settings or other data: refused, nothing touched
    folder = tmp_path / "w1"
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    base = ["sbc", str(design), "--out", str(folder), "--replicates", "2", "--resume"]
    base += ["--walkers", "8", "--max-steps", "100", "--rank-draws", "19", "--quiet"]
    for change in (["--seed", "10"], ["--seed", "9", "--max-steps", "200"]):
        capsys.readouterr()
        assert main(base + change) == EXIT_INPUT
        err = capsys.readouterr().err
        assert "--resume:" in err and "holds another campaign" in err
    assert {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()} == before


def test_unreachable_scheduler_exits_nonzero_and_writes_nothing(
    tmp_path: Path, design: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "sbc"
    address = f"tcp://127.0.0.1:{_free_port()}"
    code = main(
        [
            "sbc",
            str(design),
            "--out",
            str(out),
            "--replicates",
            "2",
            "--scheduler",
            address,
            "--connect-timeout",
            "1",
            "--quiet",
        ]
    )
    assert code == EXIT_INPUT
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"granbayes: error: --scheduler '{address}': no Dask scheduler")
    assert len(err.splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--replicates", "0"], "--replicates 0: must be >= 1"),
        (["--replicates", "2", "--rank-draws", "0"], "--rank-draws 0: must be in"),
        (["--replicates", "2", "--workers", "0"], "--workers 0: must be >= 1"),
        (["--replicates", "2", "--terms", "depth,dragg"], "--terms depth,dragg"),
        (
            ["--replicates", "2", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"],
            "--workers sizes the local cluster",
        ),
    ],
)
def test_bad_sbc_arguments_one_line_and_nothing_written(
    tmp_path: Path, design: Path, capsys: pytest.CaptureFixture[str], extra, message
) -> None:
    out = tmp_path / "sbc"
    assert main(["sbc", str(design), "--out", str(out), *extra]) == EXIT_INPUT
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not out.exists() and not (tmp_path / "sbc.partial").exists()


# ----------------------------------------------------------------------------------------
# (f) the joint fit: replicates of every kind of measurement, made by the oracle
# ----------------------------------------------------------------------------------------
#: A tiny design of every kind: one jump filmed at 200 frames/s, one intrusion test.
JOINT_DESIGN = LabDesign(
    phis=(0.612,),
    commands=("single",),
    trials=2,
    tracked_trials=1,
    fps=200.0,
    track_from_s=-0.01,
    track_after_end_s=0.05,
    intrusion_speeds_mm_s=(100.0,),
    depth_step_mm=2.0,
    depth_max_mm=20.0,
)
JOINT_TRUTH = {
    "k": 3000.0,
    "c_d": 20.0,
    "kappa": 1.0,
    "sigma_mm": 1.5,
    "frame_sd_foot_mm": 0.3,
    "frame_sd_rod_mm": 0.2,
    "frame_tau_ms": 4.0,
    "force_sd_N": 0.5,
}


@pytest.fixture(scope="module")
def joint_design(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An experiment folder with jumps, a tracked jump and an intrusion test (SYNTHETIC)."""
    data = synthetic_lab_data({"k": 3000.0}, seed=3, design=JOINT_DESIGN)
    return write_lab_experiment(tmp_path_factory.mktemp("joint"), data, truth_file=False)


def test_replicates_are_the_oracle_plus_the_observation_noise(joint_design: Path) -> None:
    """Every value is the oracle's at the truth, and the noise is each kind's model."""
    experiment = load_experiment(joint_design)
    tables = load_measurements(joint_design, experiment).tables
    window = 3e-3
    jump = tables["trajectories"]["jump"].iloc[0]  # as loaded (a label, not a number)
    out = replicate_measurements(
        experiment,
        tables,
        {0.612: JOINT_TRUTH},
        rng=np.random.default_rng(1),
        offset_window_s={jump: window},
    )
    heights = out["heights"]
    for _, row in heights.iterrows():
        expected = simulate_height_scipy(
            str(row["command"]), 0.612, {"k": 3000.0, "c_d": 20.0, "kappa": 1.0}
        )
        assert row["true_height_mm"] == pytest.approx(expected, abs=1e-9)
    assert not np.allclose(heights["height_mm"], heights["true_height_mm"])
    frames = out["trajectories"]
    offset = float(frames["true_offset_s"].iloc[0])
    assert 0.0 < abs(offset) <= window and (frames["true_offset_s"] == offset).all()
    oracle = simulate_trajectory_scipy(
        "single",
        0.612,
        {"k": 3000.0, "c_d": 20.0, "kappa": 1.0},
        frames["t_s"].to_numpy() + offset,  # frame i shows the robot at t_i + offset
    )
    np.testing.assert_allclose(frames["true_x_foot_mm"], oracle.x_foot_mm, atol=1e-9)
    np.testing.assert_allclose(frames["true_x_rod_mm"], oracle.x_rod_mm, atol=1e-9)
    tests = out["intrusions"]
    force = intrusion_force_scipy(
        0.612, {"k": 3000.0, "c_d": 20.0, "kappa": 1.0}, tests["depth_mm"].to_numpy(), 100.0
    )
    np.testing.assert_allclose(tests["true_force_N"], force, atol=1e-9)
    # the same seed gives the same replicate; the design's other columns are kept
    again = replicate_measurements(
        experiment,
        tables,
        {0.612: JOINT_TRUTH},
        rng=np.random.default_rng(1),
        offset_window_s={jump: window},
    )
    for kind in out:
        pd.testing.assert_frame_equal(out[kind], again[kind])
        kept = [
            c
            for c in tables[kind].columns
            if c not in ("height_mm", "x_foot_mm", "x_rod_mm", "force_N")
        ]
        pd.testing.assert_frame_equal(out[kind][kept], tables[kind][kept])
    with pytest.raises(KeyError, match="frame_tau_ms"):
        replicate_measurements(
            experiment,
            tables,
            {0.612: {k: v for k, v in JOINT_TRUTH.items() if k != "frame_tau_ms"}},
            rng=np.random.default_rng(1),
            offset_window_s={jump: window},
        )
    with pytest.raises(KeyError, match="offset"):
        replicate_measurements(
            experiment, tables, {0.612: JOINT_TRUTH}, rng=np.random.default_rng(1)
        )


def test_frame_noise_is_a_stationary_ornstein_uhlenbeck_process() -> None:
    """Marginal sd and the correlation exp(-gap / tau) at uneven frame gaps.

    20,000 frames: the sd's relative SE is about 1/sqrt(2 n_eff) ~ 1.2% here (n_eff ~
    n (1 - rho) / (1 + rho) for the regular part); tolerances are 5 SE.
    """
    rng = np.random.default_rng(7)
    gaps = np.where(np.arange(20_000) % 2 == 0, 1e-3, 3e-3)  # two frame spacings
    t = np.cumsum(gaps)
    sd, tau = 0.4, 2e-3
    e = _ou(rng, t, sd, tau)
    assert np.std(e) == pytest.approx(sd, rel=0.06)
    for gap in (1e-3, 3e-3):
        pick = np.flatnonzero(np.isclose(np.diff(t), gap)) + 1
        rho = np.corrcoef(e[pick], e[pick - 1])[0, 1]
        assert rho == pytest.approx(np.exp(-gap / tau), abs=0.05)
    # whitened, the residuals are independent standard normal
    rho_all = np.exp(-np.diff(t) / tau)
    white = (e[1:] - rho_all * e[:-1]) / (sd * np.sqrt(1 - rho_all**2))
    assert np.std(white) == pytest.approx(1.0, abs=0.03)
    assert abs(np.corrcoef(white[1:], white[:-1])[0, 1]) < 0.03


def test_a_joint_replicate_draws_every_parameter_from_the_priors(joint_design: Path) -> None:
    """Every sampled parameter of every kind is drawn inside its prior; every value is new."""
    experiment = load_experiment(joint_design)
    design = load_measurements(joint_design, experiment)
    priors = default_priors()
    replicate, truths = draw_measurements(
        experiment, design, FAST_CONFIG, priors, np.random.default_rng(8)
    )
    assert replicate.kinds == design.kinds
    expected = ["k", "c_d", "sigma_mm", "frame_sd_foot_mm", "frame_sd_rod_mm"]
    expected += ["frame_tau_ms", "force_sd_N"]
    assert list(truths[0.612]) == expected
    (_, model, _), *_ = part_models(experiment, design, FAST_CONFIG, priors)
    for c in model.coordinates:
        lo, hi = c.prior.bounds_u
        assert lo <= c.prior.to_u(truths[0.612][c.parameter]) <= hi, c.name
    for kind, column in (("heights", "height_mm"), ("trajectories", "x_foot_mm")):
        new, old = replicate.tables[kind][column], design.tables[kind][column]
        assert len(new) == len(old) and not np.allclose(new, old)
        assert not any(c.startswith("true_") for c in replicate.tables[kind].columns)
    assert not np.allclose(
        replicate.tables["intrusions"]["force_N"], design.tables["intrusions"]["force_N"]
    )


def test_the_force_noise_likelihood_is_the_gaussian_of_the_oracles_residuals(
    joint_design: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """At a replicate's truth, the joint log-posterior moves with the force noise exactly as
    a Gaussian log-likelihood of the oracle's own force residuals written by hand: the
    intrusion curves are counted once, with the oracle's noise model (the SBC of the joint
    fit found the force noise's ranks uneven: emcee 3.1.6's snooker update was why, not
    this; ``granbayes._sampler.SnookerMove``)."""
    import granbayes.testing

    tables = {}
    oracle = granbayes.testing.replicate_measurements

    def keep(*args, **kwargs):
        tables.update(oracle(*args, **kwargs))  # with the noise-free true_force_N
        return dict(tables)

    monkeypatch.setattr(granbayes.testing, "replicate_measurements", keep)
    experiment = load_experiment(joint_design)
    design = load_measurements(joint_design, experiment)
    priors = default_priors()
    replicate, truths = draw_measurements(
        experiment, design, FAST_CONFIG, priors, np.random.default_rng(5)
    )
    (_, model, _), *_ = part_models(experiment, replicate, FAST_CONFIG, priors)
    truth = truths[0.612]
    u = np.array([[c.prior.to_u(truth[c.parameter]) for c in model.coordinates]], dtype=float)
    j = [c.parameter for c in model.coordinates].index("force_sd_N")
    sd = truth["force_sd_N"]
    forces = tables["intrusions"]
    residual = (forces["force_N"] - forces["true_force_N"]).to_numpy()
    for factor in (0.8, 1.25):
        v = u.copy()
        v[0, j] = model.coordinates[j].prior.to_u(factor * sd)  # log coordinate, prior flat in it
        by_hand = np.sum(norm.logpdf(residual, scale=factor * sd) - norm.logpdf(residual, scale=sd))
        assert model(v)[0][0] - model(u)[0][0] == pytest.approx(by_hand, rel=1e-9, abs=1e-9)


@pytest.mark.slow  # two capped joint fits on a Dask worker (~35 s)
def test_sbc_of_a_joint_fit_draws_every_kinds_noise_and_ranks_it(
    tmp_path: Path, joint_design: Path
) -> None:
    """``granbayes sbc`` on a folder of every kind: oracle replicates, every noise ranked."""
    out = tmp_path / "sbc"
    code = main(
        [
            *["sbc", str(joint_design), "--out", str(out), "--replicates", "2", "--seed", "4"],
            *FAST,
            *["--workers", "1", "--threads", "1"],
        ]
    )
    assert code == EXIT_OK
    ranks = pd.read_csv(out / "ranks.csv")
    expected = {"k", "c_d", *PARAMETERS} | {
        "frame_sd_foot_mm",
        "frame_sd_rod_mm",
        "frame_tau_ms",
        "force_sd_N",
    }
    assert set(ranks["parameter"]) == expected
    assert len(ranks) == 2 * len(expected)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["kinds"] == ["heights", "trajectories", "intrusions"]
    assert "oracle" in summary["generator"]
    assert "frame_tau_ms" in summary["priors"]
    # the same replicate's truths are what draw_measurements gives for its seed
    experiment = load_experiment(joint_design)
    design = load_measurements(joint_design, experiment)
    truth_seed, _ = spawn_seeds(spawn_seeds(4, 2)[0], 2)
    _, truths = draw_measurements(
        experiment, design, FAST_CONFIG, default_priors(), np.random.default_rng(truth_seed)
    )
    first = ranks[ranks["replicate"] == 0].set_index("parameter")["true_value"]
    assert first.to_dict() == pytest.approx(truths[0.612])
    # the truth's log-posterior is recorded, and every run's truth checked against its draws
    assert np.isfinite(ranks["log_prob_truth"]).all()
    assert summary["mode_check"]["n_runs"] == 2
    # and the log-posterior's rank, one per run, with the ranked draws' spread
    assert ranks["log_prob_rank"].between(0, ranks["n_draws"]).all()
    assert summary["log_prob_rank"]["n_runs"] == 2
    assert (ranks["spread_ratio"] > 0).all()


def test_mode_check_flags_runs_whose_truth_beats_every_draw_by_more_than_the_gap() -> None:
    """A run whose truth's log-posterior is above all its draws by more than the gap is a
    missed mode; one below its best draw (a typical truth) or just above it is not."""
    from granbayes._sbc import _mode_check

    rows = []
    for rep, (truth, best) in enumerate([(10.0, 14.0), (20.0, 17.0), (400.0, 220.0)]):
        for name in ("k", "c_d"):  # one row per parameter; the run's values repeat
            rows.append(
                {"replicate": rep, "phi": 0.612, "parameter": name}
                | {"log_prob_truth": truth, "log_prob_max": best}
            )
    check = _mode_check(pd.DataFrame(rows), gap=5.0)
    assert (check["n_runs"], check["n_missed"]) == (3, 1)
    assert check["missed"] == [{"replicate": 2, "phi": 0.612, "excess_nats": 180.0}]


def test_log_prob_rank_check_flags_truths_in_the_tails() -> None:
    """Log-posterior ranks piled at the bottom (truths less probable than the draws) give a
    small one-sided p; uniform ranks do not. Ranks repeat per parameter: one per run."""
    from granbayes._sbc import _log_prob_rank_check

    def frame(values: np.ndarray) -> pd.DataFrame:
        rows = []
        for rep, r in enumerate(values):
            for name in ("k", "c_d"):
                rows.append(
                    {"replicate": rep, "phi": 0.612, "parameter": name, "rank": 0}
                    | {"n_draws": 99, "converged": True, "log_prob_rank": float(r)}
                )
        return pd.DataFrame(rows)

    rng = np.random.default_rng(3)
    uniform = _log_prob_rank_check(frame(rng.integers(0, 100, 60)))
    tails = _log_prob_rank_check(frame(np.r_[rng.integers(0, 10, 20), rng.integers(0, 100, 40)]))
    assert uniform["n_runs"] == tails["n_runs"] == 60
    assert uniform["expected_fraction"] == pytest.approx(0.1)
    # 20 of 60 forced into the lowest tenth, ~4 more by chance: 24 against an expected 6
    assert tails["n_lowest_tenth"] >= 20 and tails["p_lowest_tenth"] < 1e-5
    assert uniform["p_lowest_tenth"] > 0.01
    assert _log_prob_rank_check(frame(np.full(3, np.nan)))["n_runs"] == 0


def test_start_modes_of_a_replicate_record_every_climb(joint_design: Path) -> None:
    """``replicate_start_modes`` (``benchmarks/start_modes.py``'s task): the replicate of
    the SBC's seed, restricted to the kinds asked for, started with ``climbs`` climbs per
    ensemble; every climb's end is recorded, none above the best reachable, and the best
    climbs reach the truth's neighbourhood on this easy one-phi design."""
    from granbayes._sbc import replicate_start_modes

    experiment = load_experiment(joint_design)
    design = load_measurements(joint_design, experiment)
    kinds = ("heights", "intrusions")
    rows = replicate_start_modes(
        experiment, design, FAST_CONFIG, default_priors(), kinds, 1, 7, seed=11
    )
    assert [(r["replicate"], r["phi"], r["kinds"]) for r in rows] == [
        (7, 0.612, "heights,intrusions")
    ]
    ends = np.array([float(v) for v in rows[0]["climb_ends"].split(";")])
    assert ends.size == FAST_CONFIG.sampler.n_ensembles and np.isfinite(ends).all()
    assert ends.max() > rows[0]["log_prob_truth"] - 5.0  # d = 5: the mode is ~2.5 above
    # with intrusion curves, the global phase's climb of every ensemble, recorded apart
    anchors = np.array([float(v) for v in rows[0]["anchor_ends"].split(";")])
    assert anchors.size == FAST_CONFIG.sampler.n_ensembles
    assert anchors.max() > rows[0]["log_prob_truth"] - 5.0


# ----------------------------------------------------------------------------------------
# (g) a quadratic fit's replicates: every jump on its own bed, made by the oracle
# ----------------------------------------------------------------------------------------
QUADRATIC = FitSettings(
    terms=("depth", "drag"),
    phi_mode="quadratic",
    sigma_mode="global",
    # walkers from the search's ball: the Laplace start's climbs were most of a capped
    # replicate's time, and what these tests check is the ranking, not the start
    sampler=SamplerSettings(n_walkers=8, check_every=60, max_steps=60, n_draws=60, start="search"),
)


@pytest.fixture(scope="module")
def bed_design() -> pd.DataFrame:
    """3 volume fractions x 5 commands x 2 trials (SYNTHETIC design; heights replaced)."""
    return synthetic_jumps(
        {"k": 3000.0}, 2.0, seed=1, phis=(0.602, 0.612, 0.622), trials=2, settings_columns=True
    )


@pytest.mark.parametrize("phi_sd", [0.0, 0.004])
def test_a_quadratic_replicate_puts_every_jump_on_its_own_bed(
    bed_design: pd.DataFrame, phi_sd: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The oracle simulates each jump at its bed's phi (Normal(written, phi_sd)) with the
    drawn law there; the law is one quadratic (in each prior's coordinate) through the beds and
    the truths at the written volume fractions; the table keeps the written phi."""
    import granbayes.testing

    seen = {}
    oracle = granbayes.testing.replicate_measurements

    def spy(experiment, tables, truth, **kwargs):
        seen["beds"] = tables["heights"]["phi"].to_numpy(float)
        seen["truth"] = truth
        made = oracle(experiment, tables, truth, **kwargs)
        seen["true_height_mm"] = made["heights"]["true_height_mm"].to_numpy(float)
        return made

    monkeypatch.setattr(granbayes.testing, "replicate_measurements", spy)
    experiment = Experiment().replace(phi_sd=phi_sd)
    table, truths = draw_beds(
        experiment, bed_design, QUADRATIC, default_priors(), np.random.default_rng(4)
    )
    written = bed_design["phi"].to_numpy(float)
    np.testing.assert_array_equal(table["phi"].to_numpy(float), written)
    pd.testing.assert_frame_equal(
        table.drop(columns="height_mm"), bed_design.drop(columns="height_mm")
    )
    beds = seen["beds"]
    if phi_sd == 0.0:
        np.testing.assert_array_equal(beds, written)
    else:  # 30 beds: the sd of their offsets is within 4 SE (SE ~ phi_sd / sqrt(60))
        offsets = beds - written
        assert np.all(offsets != 0.0)
        assert abs(offsets.std() / phi_sd - 1.0) < 4 / np.sqrt(2 * len(beds))
    priors = default_priors()
    for name in ("k", "c_d"):  # quadratic in the coordinate of the parameter's prior
        to_u = priors[name].to_u
        at_beds = np.array([float(to_u(np.asarray(seen["truth"][float(b)][name]))) for b in beds])
        coef = np.polyfit(beds - experiment.phi_c, at_beds, 2)
        np.testing.assert_allclose(np.polyval(coef, beds - experiment.phi_c), at_beds, atol=1e-9)
        for phi, values in truths.items():
            assert np.polyval(coef, phi - experiment.phi_c) == pytest.approx(
                float(to_u(np.asarray(values[name]))), abs=1e-6
            )
    sigma = {values["sigma_mm"] for values in truths.values()}
    assert len(sigma) == 1 and {t["sigma_mm"] for t in seen["truth"].values()} == sigma
    noise = table["height_mm"].to_numpy(float) - seen["true_height_mm"]
    assert np.all(np.isfinite(noise)) and np.all(noise != 0.0)


def test_sbc_of_a_quadratic_fit_takes_jump_heights_alone(
    tmp_path: Path, joint_design: Path
) -> None:
    experiment = load_experiment(joint_design)
    measurements = load_measurements(joint_design, experiment)
    with pytest.raises(ValueError, match="jump heights alone"):
        run_sbc(experiment, measurements, tmp_path / "out", settings=QUADRATIC, n_replicates=1)
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.partial").exists()


@pytest.mark.long
def test_a_quadratic_replicate_ranks_the_law_at_every_written_phi(
    bed_design: pd.DataFrame,
) -> None:
    """One capped replicate (not a calibration study): a rank per written phi and
    parameter, from one run's draws."""
    experiment = Experiment().replace(phi_sd=0.002)
    small = bed_design[bed_design["command"].isin(["single", "stutter"])]
    rows = pd.DataFrame(
        replicate_ranks(experiment, small, QUADRATIC, default_priors(), 19, 0, seed=3)
    )
    assert len(rows) == 3 * len(PARAMETERS)
    assert set(rows["phi"]) == {0.602, 0.612, 0.622}
    assert set(rows["parameter"]) == set(PARAMETERS)
    assert rows["rank"].between(0, 19).all() and (rows["n_steps"] == 60).all()
    assert rows["log_prob_truth"].isna().all()  # coordinates are coefficients
    per_phi = rows.pivot(index="phi", columns="parameter", values="true_value")
    assert per_phi["sigma_mm"].nunique() == 1 and per_phi["k"].nunique() == 3


def test_sbc_cli_refuses_a_quadratic_fit_of_several_kinds(
    tmp_path: Path, joint_design: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "sbc"
    argv = ["sbc", str(joint_design), "--out", str(out), "--replicates", "1"]
    assert main([*argv, "--phi-mode", "quadratic", *FAST]) == EXIT_INPUT
    err = capsys.readouterr().err
    assert "takes jump heights alone" in err and "--data heights" in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists() and not (tmp_path / "sbc.partial").exists()
