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

from granbayes import load_experiment, load_jumps
from granbayes._cli import EXIT_INPUT, EXIT_OK, main
from granbayes._fitting import FitSettings
from granbayes._sampler import SamplerSettings
from granbayes._sbc import run_sbc
from granbayes.campaign import ClusterSettings
from granbayes.stats import summarize_ranks

BIN = Path(sys.executable).parent
#: Capped fits for machinery tests (not converged; not a calibration study).
FAST = ["--walkers", "8", "--max-steps", "100", "--rank-draws", "19", "--quiet"]
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
            *FAST,
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
@pytest.mark.long
def test_killed_campaign_resumes_without_recomputing(tmp_path: Path, design: Path) -> None:
    out = tmp_path / "sbc"
    partial = tmp_path / "sbc.partial"
    args = [*["sbc", str(design), "--out", str(out), "--replicates", "5", "--seed", "4"], *FAST]
    proc = subprocess.Popen(
        [BIN / "granbayes", *args, "--workers", "1"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # the CLI and its local cluster: one group to kill
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if len(list((partial / "tasks").glob("replicate-*.json"))) >= 2:
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the campaign ended before it could be killed"
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
    assert not out.exists()  # the output appears only when the campaign completes
    finished = {
        p.name: (p.read_bytes(), p.stat().st_mtime_ns)
        for p in (partial / "tasks").glob("replicate-*.json")
    }
    assert 2 <= len(finished) < 5

    assert main([*args, "--resume", "--workers", "2"]) == EXIT_OK
    for name, (content, mtime) in finished.items():  # not recomputed, not rewritten
        path = out / "tasks" / name
        assert (path.read_bytes(), path.stat().st_mtime_ns) == (content, mtime)
    check_outputs(out, 5)
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
