"""Tests of the Bayesian fit (``granbayes.fit``), its DataTree and the ``granbayes fit`` CLI.

All data here are SYNTHETIC: heights simulated with :func:`granbayes.simulate` from a
known force law plus seeded Gaussian noise (sigma = 3 mm), never measurements. Fits are
kept small (12 walkers, one or two volume fractions, 10-15 jumps each) and the simulator
runs on one thread (faster than the default for batches this small); the expensive fits
are module-scoped fixtures shared by several tests.
"""

from __future__ import annotations

import dataclasses
import json
import types
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr

import granbayes.fitting as gfit
import granbayes.report as greport
import granbayes.sampler as gsampler
from granbayes import COMMAND_NAMES, Experiment, load_experiment, load_jumps, simulate
from granbayes.cli import EXIT_INPUT, EXIT_OK, main
from granbayes.datatree import read_datatree, write_datatree
from granbayes.fitting import FitConfig, FitResult, compare_commands, data_hash, fit
from granbayes.sampler import SamplerSettings, load_checkpoint

#: The synthetic truth: a depth-only law [N/m] and the trial-to-trial scatter [mm].
TRUE_K = 4000.0
TRUE_SIGMA_MM = 3.0
PHI_C = 0.612

#: Small sampler settings: converges in a few hundred steps for a depth-only law.
SMALL = SamplerSettings(n_walkers=12, check_every=100, max_steps=1500, n_draws=60)
#: Capped sampler settings for tests that only need a posterior, not a converged one.
TINY = SamplerSettings(n_walkers=12, check_every=50, max_steps=100, n_draws=40)

GROUPS = ("posterior", "log_likelihood", "posterior_predictive", "observed_data", "sample_stats")

CLI_FIT = ["--terms", "depth", "--seed", "3", "--walkers", "12", "--max-steps", "1500"]
CLI_FIT += ["--threads", "1"]


def write_synthetic_experiment(
    folder: Path,
    *,
    seed: int,
    phis: tuple[float, ...] = (PHI_C,),
    trials: int = 3,
    freqs_hz: tuple[float, ...] = (10.0,),
) -> Path:
    """Write a SYNTHETIC experiment folder (experiment.toml + jumps.csv) and return it.

    Heights: the depth-only truth ``k = TRUE_K`` simulated for the five commands at every
    ``phi`` and frequency, plus seeded Gaussian noise of ``TRUE_SIGMA_MM``, rounded to
    micrometres like a lab table.
    """
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "experiment.toml").write_text(
        "# SYNTHETIC test data (granbayes.simulate + seeded Gaussian noise); not measured.\n"
        f"[command]\namplitude_mm = 20.0\nfreq_hz = 10.0\n\n[bed]\nphi_c = {PHI_C}\n",
        encoding="utf-8",
    )
    experiment = load_experiment(folder)
    rng = np.random.default_rng(seed)
    rows = []
    for phi in phis:
        for freq in freqs_hz:
            exp = experiment.replace(freq_hz=freq)
            for command in COMMAND_NAMES:
                true_h = float(simulate(command, phi, {"k": TRUE_K}, experiment=exp).height_mm[0])
                for trial in range(trials):
                    noisy = true_h + TRUE_SIGMA_MM * rng.standard_normal()
                    rows.append(
                        {
                            "phi": phi,
                            "command": command,
                            "freq_hz": freq,
                            "trial": trial + 1,
                            "height_mm": round(noisy, 3),
                            "source": "synthetic",
                        }
                    )
    pd.DataFrame(rows).to_csv(folder / "jumps.csv", index=False)
    return folder


def load_folder(folder: Path) -> tuple[Experiment, pd.DataFrame]:
    """Experiment and validated jumps table of a folder (as the CLI reads them)."""
    experiment = load_experiment(folder)
    return experiment, load_jumps(folder, experiment)


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file below ``folder`` (relative path -> bytes)."""
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def assert_same_groups(a: xr.DataTree, b: xr.DataTree, groups=GROUPS) -> None:
    """Every variable and coordinate of the given groups is bit-identical."""
    for group in groups:
        da, db = a[group].to_dataset(), b[group].to_dataset()
        assert sorted(da.data_vars) == sorted(db.data_vars), group
        for name in da.data_vars:
            np.testing.assert_array_equal(da[name].values, db[name].values, err_msg=name)
        for name in da.coords:
            np.testing.assert_array_equal(da[name].values, db[name].values, err_msg=name)


def interrupt_sampling_after(monkeypatch: pytest.MonkeyPatch, n_calls: int, run: int = 0) -> None:
    """Make the fit's log-probability raise KeyboardInterrupt: a simulated Ctrl-C mid-run.

    Wraps the function handed to ``run_ensemble`` and raises at its ``n_calls``-th call
    in the ``run``-th ensemble run of the fit (0: the first volume fraction);
    ``find_start`` is not counted.
    """
    original = gfit.run_ensemble
    runs = 0

    def wrapper(log_prob_fn, *args, **kwargs):
        nonlocal runs
        this_run = runs
        runs += 1
        calls = 0

        def counted(x):
            nonlocal calls
            calls += 1
            if this_run == run and calls >= n_calls:
                raise KeyboardInterrupt
            return log_prob_fn(x)

        return original(counted, *args, **kwargs)

    monkeypatch.setattr(gfit, "run_ensemble", wrapper)


# ----------------------------------------------------------------------------------------
# Fixtures: the shared fits
# ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def one_phi(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """SYNTHETIC folder: phi_c, five commands x 10 Hz x 3 trials (15 jumps)."""
    return write_synthetic_experiment(tmp_path_factory.mktemp("one_phi") / "exp", seed=20)


@pytest.fixture(scope="module")
def two_phis(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """SYNTHETIC folder: phis 0.602 and 0.622, five commands x 10 Hz x 2 trials."""
    return write_synthetic_experiment(
        tmp_path_factory.mktemp("two_phis") / "exp", seed=21, phis=(0.602, 0.622), trials=2
    )


@pytest.fixture(scope="module")
def recovery_fit(one_phi: Path) -> FitResult:
    """Depth-only fit of the one-phi synthetic data with the small settings (seed 4)."""
    experiment, table = load_folder(one_phi)
    config = FitConfig(terms=("depth",), sampler=SMALL, n_threads=1)
    return fit(experiment, table, config, seed=4, data_source=str(one_phi))


@pytest.fixture(scope="module")
def tiny_fits(two_phis: Path) -> tuple[FitResult, FitResult]:
    """Two capped fits of the two-phi data with the same seed (11)."""
    experiment, table = load_folder(two_phis)
    config = FitConfig(terms=("depth",), sampler=TINY, n_threads=1)
    return tuple(fit(experiment, table, config, seed=11) for _ in range(2))


@pytest.fixture(scope="module")
def cli_reference(tmp_path_factory: pytest.TempPathFactory, one_phi: Path) -> Path:
    """OUT of one uninterrupted ``granbayes fit`` run (seed 3) into an existing folder.

    OUT already holds a stale file, which a successful run must replace.
    """
    out = tmp_path_factory.mktemp("cli") / "OUT"
    out.mkdir()
    (out / "stale.txt").write_text("from an earlier run\n")
    code = main(["fit", str(one_phi), "--out", str(out), *CLI_FIT])
    assert code == EXIT_OK
    return out


# ----------------------------------------------------------------------------------------
# Recovery and the DataTree
# ----------------------------------------------------------------------------------------


def _interval(values: np.ndarray, prob: float = 0.90) -> tuple[float, float]:
    lo, hi = np.quantile(values.ravel(), [(1 - prob) / 2, 1 - (1 - prob) / 2])
    return float(lo), float(hi)


def test_recovers_truth(recovery_fit: FitResult) -> None:
    """The 90 % equal-tailed intervals of k and sigma_mm cover the synthetic truth.

    A single seeded data set: each interval misses with probability 0.1 in general, but
    this data set and seed are fixed, so the outcome is deterministic (the statistical
    calibration is checked over 20 replicates in ``test_coverage_slow.py``). Also
    checks that the run converged and the interval of k is informative (< 10 % wide).
    """
    r = recovery_fit
    assert r.warnings == []
    assert all(p.run.converged for p in r.parts)
    post = r.datatree.posterior
    k_lo, k_hi = _interval(post["k"].sel(phi=PHI_C).values)
    s_lo, s_hi = _interval(post["sigma_mm"].sel(phi=PHI_C).values)
    assert k_lo <= TRUE_K <= k_hi
    assert s_lo <= TRUE_SIGMA_MM <= s_hi
    assert (k_hi - k_lo) / TRUE_K < 0.10


def test_datatree_contents(recovery_fit: FitResult, one_phi: Path) -> None:
    """Groups, shapes and the bookkeeping that ties draws, log-likelihoods and data together.

    ``lp`` must equal log prior + summed pointwise log-likelihood of the same draw, and
    the simulated heights of a draw must equal a direct simulation (same arithmetic:
    rtol 1e-12).
    """
    r = recovery_fit
    dt = r.datatree
    experiment, table = load_folder(one_phi)
    assert set(GROUPS) <= set(dt.children)
    n_chain, n_draw = SMALL.n_walkers, SMALL.n_draws
    assert dt.posterior["k"].dims == ("chain", "draw", "phi")
    assert dt.posterior["k"].shape == (n_chain, n_draw, 1)
    assert dt.log_likelihood["height_mm"].shape == (n_chain, n_draw, len(table))
    assert dt.posterior_predictive["height_mm"].shape == (n_chain, n_draw, len(table))
    np.testing.assert_array_equal(dt.observed_data["height_mm"].values, table["height_mm"])
    np.testing.assert_array_equal(dt.observed_data["command"].values, table["command"])
    # lp of each kept draw = prior + the sum of its pointwise log-likelihood
    part = r.parts[0]
    samples = part.run.samples.reshape(-1, part.model.ndim)
    expected = part.model.log_prior(samples) + part.run.blobs.reshape(len(samples), -1).sum(-1)
    np.testing.assert_allclose(part.run.log_prob.ravel(), expected, rtol=1e-12)
    np.testing.assert_allclose(
        dt.sample_stats["lp"].values[..., 0], part.run.log_prob[:, -n_draw:], rtol=0
    )
    # posterior k is exp of the sampled coordinate; the simulated heights belong to it
    np.testing.assert_array_equal(
        dt.posterior["k"].values[..., 0], np.exp(part.run.samples[..., 0])
    )
    k0 = float(dt.posterior["k"].values[0, 0, 0])
    sim = dt.posterior_predictive["height_sim_mm"].values[0, 0]
    for i, row in enumerate(table.itertuples()):
        exp = experiment.replace(freq_hz=row.freq_hz)
        direct = simulate(row.command, row.phi, {"k": k0}, experiment=exp).height_mm[0]
        assert sim[i] == pytest.approx(direct, rel=1e-12)


def test_datatree_round_trip(recovery_fit: FitResult, one_phi: Path, tmp_path: Path) -> None:
    """posterior.nc written and read back has the same groups, arrays and provenance."""
    dt = recovery_fit.datatree
    path = tmp_path / "posterior.nc"
    write_datatree(dt, path)
    back = read_datatree(path)
    assert set(GROUPS) <= set(back.children)
    assert_same_groups(dt, back)
    assert int(back.attrs["seed"]) == 4
    for key in ("versions", "config", "data_sha256", "data_source", "priors", "runs"):
        assert back.attrs[key] == dt.attrs[key], key
    versions = json.loads(back.attrs["versions"])
    assert {"granbayes", "numpy", "emcee", "arviz"} <= set(versions)
    config = json.loads(back.attrs["config"])
    assert config["terms"] == ["depth"]
    assert config["sampler"]["n_walkers"] == SMALL.n_walkers
    experiment, table = load_folder(one_phi)
    assert back.attrs["data_sha256"] == data_hash(experiment, table)
    assert len(back.attrs["data_sha256"]) == 64


# ----------------------------------------------------------------------------------------
# Determinism, resume and compare_commands on the capped two-phi fit
# ----------------------------------------------------------------------------------------


def test_same_seed_bit_identical(tiny_fits: tuple[FitResult, FitResult]) -> None:
    """Two fits with the same seed give bit-identical posteriors; the seed is recorded."""
    a, b = tiny_fits
    assert_same_groups(a.datatree, b.datatree)
    assert a.datatree.attrs["seed"] == b.datatree.attrs["seed"] == 11
    assert a.seed == 11
    # two volume fractions, sampled independently: both columns are filled
    assert np.all(np.isfinite(a.datatree.posterior["k"].values))
    assert a.datatree.posterior["k"].shape == (TINY.n_walkers, TINY.n_draws, 2)


def test_library_resume_across_volume_fractions(
    tiny_fits: tuple[FitResult, FitResult], two_phis: Path, tmp_path: Path, monkeypatch
) -> None:
    """A fit interrupted in its second volume fraction resumes to the same posterior.

    The run of the first volume fraction is complete in its checkpoint and must be
    reused; the second is interrupted at its 170th log-probability call (DE moves call it
    two or four times per step), after its first checkpoint (50 steps), and continues.
    The result equals the uninterrupted fit bit for bit.
    """
    experiment, table = load_folder(two_phis)
    config = FitConfig(terms=("depth",), sampler=TINY, n_threads=1)
    backend = tmp_path / "chains"
    with monkeypatch.context() as m:
        interrupt_sampling_after(m, 170, run=1)
        with pytest.raises(KeyboardInterrupt):
            fit(experiment, table, config, seed=11, backend=backend)
    assert load_checkpoint(backend / "phi=0.602.h5").iteration == TINY.max_steps
    assert load_checkpoint(backend / "phi=0.622.h5").iteration == TINY.check_every
    resumed = fit(experiment, table, config, seed=11, backend=backend, resume=True)
    assert_same_groups(resumed.datatree, tiny_fits[0].datatree)


def test_compare_commands(tiny_fits: tuple[FitResult, FitResult], two_phis: Path) -> None:
    """One row per volume fraction with the documented columns and consistent values."""
    experiment, table = load_folder(two_phis)
    result = compare_commands(experiment, table, tiny_fits[0], seed=2)
    expected_columns = [
        "phi",
        "elpd_shared",
        "elpd_per_command",
        "elpd_diff",
        "elpd_diff_se",
        "max_pareto_k_shared",
        "max_pareto_k_per_command",
        "preferred",
        "k_intervals_overlap",
    ]
    assert list(result.columns) == expected_columns
    assert result["phi"].tolist() == [0.602, 0.622]
    numeric = result[expected_columns[1:7]].to_numpy(float)
    assert np.all(np.isfinite(numeric))
    np.testing.assert_allclose(
        result["elpd_diff"], result["elpd_shared"] - result["elpd_per_command"], rtol=1e-9
    )
    assert np.all(result["elpd_diff_se"] >= 0)
    assert set(result["preferred"]) <= {"shared", "per_command"}
    assert result["k_intervals_overlap"].dtype == bool
    # the per-command intervals behind the overlap flags (same seed: the same fits)
    again, intervals = compare_commands(experiment, table, tiny_fits[0], seed=2, details=True)
    pd.testing.assert_frame_equal(again, result)
    assert list(intervals.columns) == ["phi", "command", "parameter", "median", "lo", "hi"]
    assert np.all(
        (intervals["lo"] <= intervals["median"]) & (intervals["median"] <= intervals["hi"])
    )
    for phi, group in intervals.groupby("phi"):
        overlap = group["lo"].max() <= group["hi"].min()
        assert overlap == bool(result.set_index("phi").loc[phi, "k_intervals_overlap"])


def test_compare_commands_needs_per_phi(tiny_fits: tuple[FitResult, FitResult]) -> None:
    """compare_commands refuses a quadratic fit (no per-phi runs to compare against)."""
    quad = dataclasses.replace(
        tiny_fits[0], config=dataclasses.replace(tiny_fits[0].config, phi_mode="quadratic")
    )
    with pytest.raises(ValueError, match="per_phi"):
        compare_commands(Experiment(), pd.DataFrame(), quad)


def test_volume_fraction_with_one_jump(tmp_path: Path) -> None:
    """A phi with only one measured jump is a valid data set and must fit.

    ``run_ensemble`` returns blobs of shape (walkers, draws) instead of
    (walkers, draws, 1) when there is one observation (see test_sampler.py), and
    ``fit`` fails with "shape mismatch" after sampling.
    """
    table = pd.DataFrame(
        {
            "phi": [0.612, 0.612, 0.602],
            "command": ["single", "preload", "single"],
            "height_mm": [50.0, 62.0, 45.0],  # arbitrary synthetic values
            "freq_hz": 10.0,
            "amplitude_mm": 20.0,
            "delay_ms": 50.0,
            "settle_periods": 3.0,
        }
    )
    sampler = SamplerSettings(n_walkers=8, check_every=100, max_steps=100, n_draws=20)
    res = fit(Experiment(), table, FitConfig(sampler=sampler, n_threads=1), seed=0)
    assert res.datatree.log_likelihood["height_mm"].shape == (8, 20, 3)


# ----------------------------------------------------------------------------------------
# The command line
# ----------------------------------------------------------------------------------------

REPORT_FILES = (
    "posterior.nc",
    "summary.csv",
    "summary.md",
    "predictive.png",
    "trace.png",
    "rank.png",
)


def test_cli_fit_writes_report(cli_reference: Path, capsys) -> None:
    """``granbayes fit`` exits 0 and writes the posterior, tables and figures into OUT.

    OUT existed with a stale file: it is replaced as a whole, and neither the staging
    folder nor the backup is left behind.
    """
    out = cli_reference
    for name in REPORT_FILES:
        assert (out / name).is_file(), name
        assert (out / name).stat().st_size > 0, name
    corners = list(out.glob("corner_phi*.png"))
    assert [p.name for p in corners] == ["corner_phi0.612.png"]
    for png in [*corners, out / "predictive.png", out / "trace.png", out / "rank.png"]:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (out / "stale.txt").exists()
    assert not out.with_name("OUT.partial").exists()
    assert not out.with_name("OUT.old").exists()
    summary = pd.read_csv(out / "summary.csv")
    assert summary["parameter"].tolist() == ["k[0.612]", "sigma_mm[0.612]"]
    assert "eti90_lb" in summary.columns
    dt = read_datatree(out / "posterior.nc")
    assert set(GROUPS) <= set(dt.children)
    assert int(dt.attrs["seed"]) == 3
    assert dt.posterior["k"].shape[:2] == (12, 125)


def test_cli_resume_bit_identical(cli_reference: Path, one_phi: Path, tmp_path, monkeypatch):
    """An interrupted CLI fit continued with ``--resume`` reproduces the reference run.

    The run is interrupted (KeyboardInterrupt) at its 300th log-probability call (step
    ~130 of ~600); OUT is not created and OUT.partial keeps the checkpoint of step 100.
    ``--resume`` then finishes it, and every array of posterior.nc equals that of the
    uninterrupted run with the same seed, bit for bit.
    """
    out = tmp_path / "OUT"
    argv = ["fit", str(one_phi), "--out", str(out), *CLI_FIT]
    with monkeypatch.context() as m:
        interrupt_sampling_after(m, 300)
        with pytest.raises(KeyboardInterrupt):
            main(argv)
    assert not out.exists()
    checkpoint = tmp_path / "OUT.partial" / "chains" / "phi=0.612.h5"
    assert load_checkpoint(checkpoint).iteration == 100  # the CLI checks every 100 steps
    assert main([*argv, "--resume"]) == EXIT_OK
    assert not (tmp_path / "OUT.partial").exists()
    resumed = read_datatree(out / "posterior.nc")
    reference = read_datatree(cli_reference / "posterior.nc")
    assert_same_groups(resumed, reference)
    assert resumed.attrs["seed"] == reference.attrs["seed"]
    assert resumed.attrs["runs"] == reference.attrs["runs"]


def _edit_jumps(folder: Path, edit: Callable[[list[str]], list[str]]) -> None:
    lines = (folder / "jumps.csv").read_text().splitlines()
    (folder / "jumps.csv").write_text("\n".join(edit(lines)) + "\n")


def _set_cell(lines: list[str], row: int, column: str, value: str) -> list[str]:
    header = lines[0].split(",")
    cells = lines[row].split(",")
    cells[header.index(column)] = value
    lines[row] = ",".join(cells)
    return lines


def _drop_column(lines: list[str], column: str) -> list[str]:
    j = lines[0].split(",").index(column)
    return [",".join(c for i, c in enumerate(line.split(",")) if i != j) for line in lines]


BAD_INPUTS = {
    "unknown-command": (
        lambda d: _edit_jumps(d, lambda ls: _set_cell(ls, 4, "command", "singel")),
        [],
        ["jumps.csv", "row 4", "column 'command'", "singel"],
    ),
    "infinite-height": (
        lambda d: _edit_jumps(d, lambda ls: _set_cell(ls, 7, "height_mm", "inf")),
        [],
        ["jumps.csv", "row 7", "column 'height_mm'"],
    ),
    "nan-height": (
        lambda d: _edit_jumps(d, lambda ls: _set_cell(ls, 2, "height_mm", "nan")),
        [],
        ["jumps.csv", "row 2", "column 'height_mm'"],
    ),
    "missing-column": (
        lambda d: _edit_jumps(d, lambda ls: _drop_column(ls, "height_mm")),
        [],
        ["jumps.csv", "column 'height_mm'", "missing"],
    ),
    "unknown-toml-key": (
        lambda d: (d / "experiment.toml").write_text("[robot]\nm_motr = 1.0\n"),
        [],
        ["experiment.toml", "row 2", "column 'robot.m_motr'", "unknown key"],
    ),
    "unknown-term": (
        lambda d: None,
        ["--terms", "depth,dragg"],
        ["--terms", "dragg"],
    ),
    "bad-prior-file": (
        lambda d: (d / "priors.toml").write_text("[k]\nlower = true\n"),
        ["--priors", "PRIORS"],
        ["priors.toml", "column 'k.lower'"],
    ),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_cli_bad_input(case: str, one_phi: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    """Bad input exits 2 with one line naming file/row/column, before any sampling.

    run_ensemble (and the fit itself) are replaced by functions that fail the test if
    called; OUT and OUT.partial must not be created.
    """

    def forbidden(*args, **kwargs):
        raise AssertionError("sampling started despite bad input")

    monkeypatch.setattr(gsampler, "run_ensemble", forbidden)
    monkeypatch.setattr(gfit, "run_ensemble", forbidden)
    monkeypatch.setattr(gfit, "find_start", forbidden)
    data = tmp_path / "exp"
    data.mkdir()
    for name in ("experiment.toml", "jumps.csv"):
        (data / name).write_bytes((one_phi / name).read_bytes())
    make_bad, extra, fragments = BAD_INPUTS[case]
    make_bad(data)
    extra = [str(data / "priors.toml") if a == "PRIORS" else a for a in extra]
    out = tmp_path / "OUT"
    code = main(["fit", str(data), "--out", str(out), *CLI_FIT, *extra])
    captured = capsys.readouterr()
    assert code == EXIT_INPUT
    assert captured.out == ""
    lines = captured.err.splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("granbayes: error: ")
    for fragment in fragments:
        assert fragment in lines[0]
    assert not out.exists()
    assert not (tmp_path / "OUT.partial").exists()


# ----------------------------------------------------------------------------------------
# An existing OUT is never half-overwritten
# ----------------------------------------------------------------------------------------


def _fail_in_fit(exc: type[BaseException]):
    def fake_fit(experiment, table, config, *, backend, **kwargs):
        work = Path(backend).parent  # the staging folder
        (work / "posterior.nc").write_bytes(b"half-written")
        (work / "summary.md").write_text("partial\n")
        raise exc("failed mid-way")

    return {"fit": fake_fit}


def _fail_in_report(exc: type[BaseException]):
    def fake_fit(*args, **kwargs):
        return types.SimpleNamespace(warnings=[])

    def fake_report(result, out, **kwargs):
        (Path(out) / "posterior.nc").write_bytes(b"half-written")
        (Path(out) / "summary.csv").write_text("parameter\n")
        raise exc("failed while writing the report")

    return {"fit": fake_fit, "write_fit_report": fake_report}


@pytest.mark.parametrize("where", [_fail_in_fit, _fail_in_report], ids=["fit", "report"])
@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt])
def test_existing_out_untouched_by_failed_run(
    where, exc, one_phi: Path, tmp_path: Path, monkeypatch
) -> None:
    """A run that fails mid-way leaves an existing OUT byte-identical (files and content)."""
    out = tmp_path / "OUT"
    (out / "figures").mkdir(parents=True)
    (out / "marker.txt").write_text("results of an earlier fit\n")
    (out / "posterior.nc").write_bytes(b"\x89HDF earlier posterior")
    (out / "figures" / "a.png").write_bytes(b"\x89PNG earlier")
    before = snapshot(out)
    for name, fake in where(exc).items():
        module = gfit if name == "fit" else greport
        monkeypatch.setattr(module, name, fake)
    with pytest.raises(exc):
        main(["fit", str(one_phi), "--out", str(out), *CLI_FIT])
    assert snapshot(out) == before
    assert not (tmp_path / "OUT.old").exists()


def test_cli_help_mentions_fit(capsys) -> None:
    """``granbayes fit --help`` exits 0 and documents --resume and --terms."""
    assert main(["fit", "--help"]) == EXIT_OK
    text = capsys.readouterr().out
    assert "--resume" in text and "--terms" in text


def test_resume_refuses_a_checkpoint_made_for_other_data(tmp_path: Path) -> None:
    """``--resume`` with changed heights must not silently continue the old chains."""
    import granbayes.sampler as gs

    rng = np.random.default_rng(0)
    x = rng.normal(size=(8, 2))

    def target(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lp = -0.5 * np.sum(u * u, axis=1)
        return lp, np.stack([lp, lp], axis=1)

    settings = gs.SamplerSettings(n_walkers=8, check_every=50, max_steps=100, n_draws=10)
    ckpt = tmp_path / "run.h5"
    gs.run_ensemble(target, x, 2, seed=1, settings=settings, checkpoint=ckpt, fingerprint="a")
    with pytest.raises(ValueError, match="other data or settings"):
        gs.run_ensemble(
            target, x, 2, seed=1, settings=settings, checkpoint=ckpt, resume=True, fingerprint="b"
        )
