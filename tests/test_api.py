"""The public API after a fit: ``gb.fit`` & co., ``load_fit``, ``predict``, the re-rendered
report, the identifiability table, LOO-PIT, ``granbayes priors`` and batch simulation input.

All data here are SYNTHETIC: heights simulated with :func:`granbayes.simulate` from a known
depth-only law plus seeded Gaussian noise (the test kit,
:func:`granbayes.testing.synthetic_jumps`). The fits are short (two ensembles of 8 walkers,
at most 300 steps): they need a posterior, not a converged one.
"""

from __future__ import annotations

import importlib
import io
import json
import re
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr

import granbayes as gb
from granbayes._cli import EXIT_INPUT, EXIT_OK, main
from granbayes._synthetic import write_experiment
from granbayes.report import write_fit_report
from granbayes.stats import IDENTIFIABILITY_LEVELS, identifiability_table, loo, loo_pit
from granbayes.testing import synthetic_jumps

SHORT = gb.SamplerSettings(
    n_walkers=8, n_ensembles=2, check_every=50, max_steps=300, n_draws=30, min_ess=50
)
PHIS = (0.602, 0.622)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def true_k(phi: float) -> float:
    """The synthetic depth stiffness [N/m]: rising with phi."""
    return 4000.0 * (1.0 + 10.0 * (phi - 0.612))


def write_folder(folder: Path, phis=PHIS, trials: int = 2, seed: int = 5) -> Path:
    """A SYNTHETIC experiment folder (the test kit): five commands per phi at 10 Hz,
    ``trials`` jumps each, heights from the independent oracle, 3 mm of scatter."""
    jumps = synthetic_jumps(
        lambda phi: {"k": true_k(phi)},
        3.0,
        seed=seed,
        phis=phis,
        trials=trials,
        label="tests/test_api.py",
    )
    return write_experiment(folder, jumps, gb.Experiment())


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_folder(tmp_path_factory.mktemp("api") / "lab")


def _fit(folder: Path, phi_mode: str) -> gb.FitResult:
    exp = gb.load_experiment(folder)
    jumps = gb.load_jumps(folder, exp)
    config = gb.FitSettings(
        terms=("depth",), phi_mode=phi_mode, sampler=SHORT, n_threads=1, n_prior_draws=60
    )
    return gb.fit(exp, jumps, config, seed=3, data_source=str(folder))


@pytest.fixture(scope="module")
def per_phi(folder: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[gb.FitResult, Path]:
    """A per_phi fit and its report folder (with a truth and a small uniqueness table)."""
    result = _fit(folder, "per_phi")
    out = tmp_path_factory.mktemp("report") / "fit"
    out.mkdir()
    uniqueness = pd.DataFrame(
        {"phi": list(PHIS), "elpd_diff": [1.0, -2.0], "preferred": ["shared", "shared"]}
    )
    truth = {phi: {"k": true_k(phi), "sigma_mm": 3.0} for phi in PHIS}
    write_fit_report(result.datatree, out, truth=truth, uniqueness=uniqueness)
    return result, out


@pytest.fixture(scope="module")
def quadratic(folder: Path) -> gb.FitResult:
    return _fit(folder, "quadratic")


# ----------------------------------------------------------------------------------------
# The public API
# ----------------------------------------------------------------------------------------


def test_public_names_are_the_functions_and_classes() -> None:
    import granbayes._fitting as fitting_module

    assert callable(gb.fit) and gb.fit is fitting_module.fit
    assert gb.fit.__module__ == "granbayes._fitting"
    for name in ("fit", "diagnose", "load_fit", "predict", "compare_commands", "residual_table"):
        assert callable(getattr(gb, name)), name
        assert not isinstance(getattr(gb, name), type(fitting_module)), name
    for name in ("FitSettings", "FitResult", "DiagnoseSettings", "Diagnosis", "SamplerSettings"):
        assert isinstance(getattr(gb, name), type), name
    for name in ("SavedFit", "Prediction", "Prior"):
        assert isinstance(getattr(gb, name), type), name
    assert set(gb.__all__) <= set(dir(gb))
    with pytest.raises(AttributeError):
        gb.no_such_name  # noqa: B018


@pytest.mark.parametrize(
    ("module", "old", "new"),
    [
        ("granbayes", "FitConfig", "FitSettings"),
        ("granbayes", "DiagnoseConfig", "DiagnoseSettings"),
        ("granbayes", "SolverOptions", "SolverSettings"),
        ("granbayes._fitting", "FitConfig", "FitSettings"),
        ("granbayes._criticism", "DiagnoseConfig", "DiagnoseSettings"),
        ("granbayes._simulator", "SolverOptions", "SolverSettings"),
    ],
)
def test_former_names_of_the_settings_are_deprecated_aliases(
    module: str, old: str, new: str
) -> None:
    """The former names still import (the same class), warn where they are used, and are
    not exported."""
    namespace: dict = {}
    with pytest.warns(DeprecationWarning, match=f"{old} is a deprecated alias of {new}") as rec:
        exec(compile(f"from {module} import {old}", __file__, "exec"), namespace)
    assert rec[0].filename == __file__  # points at the line that used the old name
    mod = importlib.import_module(module)
    assert namespace[old] is getattr(mod, new)
    assert old not in mod.__all__ and new in mod.__all__


@pytest.mark.parametrize(
    ("function", "old"),
    [
        ("simulate", "options"),
        ("simulate_rows", "options"),
        ("simulate_table", "options"),
        ("simulate_trajectory", "options"),
        ("simulate_frames", "options"),
        ("simulate_frames_rows", "options"),
        ("make_jumps", "options"),
        ("fit", "config"),
        ("fit", "backend"),
        ("diagnose", "config"),
        ("run_sbc", "config"),
    ],
)
def test_former_settings_keywords_are_deprecated(function: str, old: str) -> None:
    """Every ``*Settings`` argument is called ``settings``; the former keyword still reaches
    it, with a warning at the caller's line, and both at once are refused."""
    func = getattr(gb, function)
    new = "checkpoint" if old == "backend" else "settings"
    with pytest.raises(TypeError, match=f"got both {old}= and {new}="):
        func(**{old: None, new: None})
    with pytest.warns(
        DeprecationWarning, match=rf"{function}\({old}=\.\.\.\) is deprecated; use {new}="
    ) as rec:
        with pytest.raises(Exception):  # noqa: B017 (no arguments: fails after the warning)
            func(**{old: None})
    assert rec[0].filename == __file__


def test_the_config_attribute_is_a_deprecated_alias_of_settings() -> None:
    """``FitResult.config`` and ``SavedFit.config`` still read the fit's settings, warned."""
    from granbayes.testing import fake_fit

    saved = gb.SavedFit.from_datatree(fake_fit(seed=1))
    with pytest.warns(DeprecationWarning, match="SavedFit.config is a deprecated alias"):
        assert saved.config is saved.settings


#: The README's "API" section (granbayes.README_API in the report of this change); run as
#: written on a small SYNTHETIC folder "my-lab" in the current directory.
README_API = """
import granbayes as gb

exp = gb.load_experiment("my-lab")                   # robot, command settings, phi_c
jumps = gb.load_jumps("my-lab", exp)                 # one validated row per jump
settings = gb.FitSettings(terms=("depth", "drag"), sampler=gb.SamplerSettings(n_ensembles=2))
result = gb.fit(exp, jumps, settings, seed=1)        # until converged (result.converged)
result.diagnostics()                                 # tau, R-hat, ESS per run
result.save("posterior.nc")                          # the DataTree, as netCDF

saved = gb.load_fit("posterior.nc")                  # SavedFit: datatree, settings, priors, ...
saved.datatree.posterior["k"]                        # k [N/m] over (chain, draw, phi)
gb.residual_table(saved.datatree)                    # misfit per command x phi x setting
pred = gb.predict(saved, "stutter", 0.612, freq_hz=[8, 12], rng=1)
pred.table[["freq_hz", "height_mm_median", "height_mm_lo", "height_mm_hi"]]
"""


def _readme_api_code() -> str:
    """The Python block of the README's "## API" section if it has one, else README_API."""
    readme = Path(__file__).resolve().parents[1] / "README.md"
    text = readme.read_text(encoding="utf-8") if readme.exists() else ""
    section = re.search(r"^## API\n(.*?)(?=^## )", text, flags=re.S | re.M)
    if section:
        block = re.search(r"```python\n(.*?)```", section.group(1), flags=re.S)
        if block:
            return block.group(1)
    return README_API


def test_readme_api_example_runs_as_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    write_folder(tmp_path / "my-lab", phis=(0.612,), trials=2, seed=9)
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(textwrap.dedent(_readme_api_code()), "README-API", "exec"), namespace)
    assert namespace["result"].converged
    table = namespace["pred"].table
    assert list(table["freq_hz"]) == [8.0, 12.0]
    assert (table["height_mm_lo"] < table["height_mm_median"]).all()
    assert (table["height_mm_median"] < table["height_mm_hi"]).all()


# ----------------------------------------------------------------------------------------
# load_fit
# ----------------------------------------------------------------------------------------


def test_load_fit_gives_back_the_fit(per_phi: tuple[gb.FitResult, Path]) -> None:
    result, out = per_phi
    saved = gb.load_fit(out / "posterior.nc")
    assert gb.load_fit(out).source == out / "posterior.nc"  # the folder works too
    assert saved.settings == result.settings
    assert saved.seed == result.seed == 3
    assert saved.converged == result.converged
    assert saved.parameters == ("k",)
    np.testing.assert_array_equal(saved.phis, PHIS)
    exp = gb.load_experiment(Path(result.datatree.attrs["data_source"]))
    assert (saved.experiment.robot, saved.experiment.command) == (exp.robot, exp.command)
    assert saved.experiment.phi_c == exp.phi_c
    assert saved.priors == gb.default_priors()
    assert saved.labels == tuple(p.label for p in result.parts)
    pd.testing.assert_frame_equal(saved.diagnostics(), result.diagnostics())


def test_saved_models_reproduce_the_stored_log_likelihood(
    per_phi: tuple[gb.FitResult, Path],
) -> None:
    """The rebuilt models and draws give back the log-likelihood stored with the fit."""
    result, out = per_phi
    saved = gb.load_fit(out / "posterior.nc")
    ll = result.datatree["log_likelihood"]["height_mm"].values
    ll = ll.reshape(-1, ll.shape[-1])
    for label, part in zip(saved.labels, result.parts, strict=True):
        model = saved.model(label)
        assert model.coordinate_names == part.model.coordinate_names
        u = saved.draws(label)
        _, ll_rebuilt = model(u)
        np.testing.assert_allclose(ll_rebuilt, ll[:, part.jumps], rtol=1e-9, atol=1e-9)


def test_saved_fit_serves_residuals_and_loo(per_phi: tuple[gb.FitResult, Path]) -> None:
    result, out = per_phi
    saved = gb.load_fit(out / "posterior.nc")
    pd.testing.assert_frame_equal(
        gb.residual_table(saved.datatree), gb.residual_table(result.datatree)
    )
    assert loo(saved.datatree)["elpd"] == pytest.approx(loo(result.datatree)["elpd"])
    assert saved.loo()["elpd"] == pytest.approx(loo(result.datatree)["elpd"])


def test_loo_flags_bad_pareto_k_by_arviz_good_k(per_phi: tuple[gb.FitResult, Path]) -> None:
    """``n_bad_k`` counts k above ArviZ's sample-size dependent ``good_k`` in both branches."""
    import arviz as az

    dt = per_phi[0].datatree
    with warnings.catch_warnings():  # ArviZ warns when a k is bad: what is counted here
        warnings.filterwarnings("ignore", message="Estimated shape parameter of Pareto")
        res = az.loo(dt, pointwise=True, var_name="height_mm")
    got = loo(dt)
    assert got["good_k"] == pytest.approx(float(res.good_k))
    assert got["n_bad_k"] == int(np.sum(np.asarray(res.pareto_k) > float(res.good_k)))
    ll = dt["log_likelihood"]["height_mm"].transpose("chain", "draw", "jump").to_numpy()
    for chains in (2, ll.shape[0]):  # few draws: good_k < 0.7
        arr = loo(ll[:chains])
        s = chains * ll.shape[1]
        assert arr["good_k"] == pytest.approx(min(1.0 - 1.0 / np.log10(s), 0.7))
        assert arr["n_bad_k"] == int(np.sum(arr["pareto_k"] > arr["good_k"]))


def test_load_fit_bad_input(tmp_path: Path) -> None:
    with pytest.raises(gb.InputError, match="no such file"):
        gb.load_fit(tmp_path / "posterior.nc")
    bad = tmp_path / "other.nc"
    xr.DataTree.from_dict({"posterior": xr.Dataset({"x": ("a", [1.0])})}).to_netcdf(
        bad, engine="h5netcdf"
    )
    with pytest.raises(gb.InputError, match=r"other\.nc: not a granbayes fit"):
        gb.load_fit(bad)


# ----------------------------------------------------------------------------------------
# predict
# ----------------------------------------------------------------------------------------


def test_predict_reproduces_the_posterior_predictive(per_phi: tuple[gb.FitResult, Path]) -> None:
    """At a fitted setting, the simulated heights are those stored in the DataTree."""
    result, _ = per_phi
    table = gb.SavedFit.from_datatree(result.datatree).observed()
    row = table.iloc[3]
    pred = gb.predict(
        result,
        row["command"],
        row["phi"],
        freq_hz=row["freq_hz"],
        amplitude_mm=row["amplitude_mm"],
        delay_ms=row["delay_ms"],
        settle_periods=row["settle_periods"],
        n_draws=None,
    )
    stored = result.datatree["posterior_predictive"]["height_sim_mm"].values[..., 3].ravel()
    np.testing.assert_allclose(pred.height_sim_mm[:, 0], stored, rtol=1e-12)
    r = pred.table.iloc[0]
    assert r["height_sim_mm_lo"] <= r["height_sim_mm_median"] <= r["height_sim_mm_hi"]
    assert r["height_mm_lo"] < r["height_sim_mm_lo"] and r["height_mm_hi"] > r["height_sim_mm_hi"]
    assert r["n_failed"] == 0 and r["n_draws"] == stored.size


def test_predict_grid_inputs_and_seed(per_phi: tuple[gb.FitResult, Path]) -> None:
    result, out = per_phi
    a = gb.predict(result, ["single", "stutter"], list(PHIS), freq_hz=[8, 12], n_draws=40, rng=2)
    assert len(a.table) == 2 * 2 * 2
    assert list(a.table["command"][:4]) == ["single"] * 4
    assert a.height_sim_mm.shape == a.height_mm.shape == (40, 8)
    b = gb.predict(out / "posterior.nc", ["single", "stutter"], list(PHIS), freq_hz=[8, 12],
                   n_draws=40, rng=np.random.default_rng(2))  # fmt: skip
    pd.testing.assert_frame_equal(a.table, b.table)
    c = gb.predict(result.datatree, "single", PHIS[0], n_draws=40, rng=3)
    assert c.table["freq_hz"].item() == 10.0  # the experiment's setting by default
    doc = json.loads(json.dumps(a.to_json()))
    assert doc["ci_prob"] == 0.9 and len(doc["predictions"]) == 8


def test_predict_per_phi_only_at_fitted_phis(per_phi: tuple[gb.FitResult, Path]) -> None:
    result, _ = per_phi
    with pytest.raises(ValueError, match=r"phi = 0\.612: .*phi = 0\.602, 0\.622.*quadratic"):
        gb.predict(result, "single", 0.612)
    with pytest.raises(ValueError, match="unknown; valid commands"):
        gb.predict(result, "hop", PHIS[0])
    with pytest.raises(ValueError, match="freq_hz = 0"):
        gb.predict(result, "single", PHIS[0], freq_hz=0.0)


def test_predict_quadratic_anywhere(quadratic: gb.FitResult) -> None:
    pred = gb.predict(quadratic, "preload", [0.612, 0.64], n_draws=50, rng=1)
    assert np.isfinite(pred.table["height_mm_median"]).all()
    assert np.isfinite(pred.table["sigma_mm_median"]).all()
    assert any("interpolated" in n for n in pred.notes)
    assert any("0.64" in n and "extrapolated" in n for n in pred.notes)


def test_cli_predict(per_phi: tuple[gb.FitResult, Path], capsys, tmp_path: Path) -> None:
    _, out = per_phi
    code, text, err = run(
        capsys, "predict", str(out), "--command", "single,stutter", "--phi", "0.602",
        "--freq-hz", "8,12", "--draws", "30", "--out", str(tmp_path / "p.csv"),
    )  # fmt: skip
    assert code == EXIT_OK, err
    assert text.count(", new jump") == 4 and "[90% interval]" in text
    assert len(pd.read_csv(tmp_path / "p.csv")) == 4
    code, text, err = run(
        capsys, "predict", str(out / "posterior.nc"), "--command", "single", "--phi", "0.602",
        "--json", "--seed", "4", "--draws", "30",
    )  # fmt: skip
    assert code == EXIT_OK, err
    doc = json.loads(text)
    assert doc["predictions"][0]["command"] == "single" and doc["seed"] == 4
    code, text, err = run(capsys, "predict", str(out), "--command", "single", "--phi", "0.61")
    assert code == EXIT_INPUT and text == ""
    assert "0.602, 0.622" in err and "--phi-mode quadratic" in err
    code, _, err = run(capsys, "predict", str(out), "--command", "hop", "--phi", "0.602")
    assert code == EXIT_INPUT and "unknown command" in err
    code, _, err = run(capsys, "predict", str(tmp_path / "x.nc"), "--command", "single",
                       "--phi", "0.602")  # fmt: skip
    assert code == EXIT_INPUT and "x.nc: no such file" in err


# ----------------------------------------------------------------------------------------
# Report: re-rendered, prior vs posterior, LOO-PIT, identifiability
# ----------------------------------------------------------------------------------------


def test_report_rerendered_from_posterior_equals_original(
    per_phi: tuple[gb.FitResult, Path], capsys, tmp_path: Path
) -> None:
    _, out = per_phi
    again = tmp_path / "again"
    code, text, err = run(capsys, "report", str(out / "posterior.nc"), "--out", str(again))
    assert code == EXIT_OK, err
    assert (again / "summary.md").read_text() == (out / "summary.md").read_text()
    assert text.strip() == (out / "summary.md").read_text().strip()
    for name in ("summary.csv", "identifiability.csv", "uniqueness.csv", "diagnostics.csv"):
        assert (again / name).read_text() == (out / name).read_text(), name
    assert "truth" in pd.read_csv(again / "summary.csv").columns  # kept with the posterior
    code, _, err = run(capsys, "report", str(out), "--out", str(out))
    assert code == EXIT_INPUT and "is the folder holding posterior.nc" in err


def test_report_has_prior_posterior_loo_pit_and_identifiability(
    per_phi: tuple[gb.FitResult, Path],
) -> None:
    _, out = per_phi
    summary = (out / "summary.md").read_text()
    for name in ("prior_posterior.png", "loo_pit.png"):
        assert (out / name).read_bytes()[:8] == PNG_MAGIC
        assert f"({name})" in summary
    assert "## Identifiability" in summary and "LOO-PIT calibration" in summary
    ident = pd.read_csv(out / "identifiability.csv")
    assert set(ident["parameter"]) == {"k", "sigma_mm"}
    assert sorted(set(ident["phi"])) == list(PHIS)
    k = ident[ident["parameter"] == "k"]
    assert (k["contraction"] > 0.9).all() and (k["scale"] == "log").all()
    assert k["verdict"].str.startswith("well identified").all()


def test_identifiability_posterior_equal_to_prior_is_not_identified(
    per_phi: tuple[gb.FitResult, Path],
) -> None:
    result, _ = per_phi
    dt = result.datatree.copy()
    prior = dt["prior"].to_dataset()
    # a "posterior" that is the prior itself: nothing learned
    n = prior.sizes["draw"]
    fake = prior.isel(draw=slice(0, n // 2)).assign_coords(draw=np.arange(n // 2))
    dt["posterior"] = fake
    table = identifiability_table(dt)
    assert (table["contraction"].abs() < 0.5).all()
    low = table[table["contraction"] < IDENTIFIABILITY_LEVELS[0][0]]
    assert (low["verdict"] == "not identified: posterior ~ prior").all()
    assert identifiability_table(dt.drop_nodes("prior")).empty


def test_loo_pit_values(per_phi: tuple[gb.FitResult, Path]) -> None:
    result, _ = per_phi
    pit = loo_pit(result.datatree)
    assert pit.shape == (len(PHIS) * 5 * 2,)
    assert ((pit >= 0) & (pit <= 1)).all()
    # the report reuses LOO's smoothed weights: the same values as smoothing them again
    res = loo(result.datatree, log_weights=True)
    again = loo_pit(result.datatree, log_weights=res["log_weights"], pareto_k=res["pareto_k"])
    np.testing.assert_array_equal(again, pit)
    assert "log_weights" not in loo(result.datatree)
    with pytest.raises(ValueError, match="together"):
        loo_pit(result.datatree, log_weights=res["log_weights"])


# ----------------------------------------------------------------------------------------
# granbayes priors
# ----------------------------------------------------------------------------------------


def test_priors_toml_round_trip(capsys, tmp_path: Path) -> None:
    code, text, err = run(capsys, "priors")
    assert code == EXIT_OK, err
    file = tmp_path / "priors.toml"
    file.write_text(text)
    assert gb.load_priors(file) == gb.default_priors()
    for name, prior in gb.default_priors().items():
        assert f"[{name}]" in text and prior.why in text
    code, text, _ = run(capsys, "priors", "--terms", "drag")
    assert code == EXIT_OK
    assert re.findall(r"^\[(\w+)\]", text, flags=re.M) == ["k", "c_d", "sigma_mm"]
    file.write_text(text.replace("upper = 300.0", "upper = 100.0"))
    assert gb.load_priors(file)["c_d"].upper == 100.0
    code, _, err = run(capsys, "priors", "--terms", "dragg")
    assert code == EXIT_INPUT and "--terms dragg" in err


# ----------------------------------------------------------------------------------------
# granbayes simulate: batch input and single-jump settings
# ----------------------------------------------------------------------------------------


def test_batch_without_k_names_file_and_column(capsys, tmp_path: Path) -> None:
    table = tmp_path / "in.csv"
    table.write_text("command,phi,c_d\nsingle,0.6,10\nstutter,0.6,20\n")
    code, out, err = run(capsys, "simulate", "--batch", str(table), "--out", str(tmp_path / "o"))
    assert code == EXIT_INPUT and out == ""
    assert re.fullmatch(
        r"granbayes: error: .*in\.csv, column 'k': missing required column.*k \[N/m\].*\n", err
    )
    assert not (tmp_path / "o").exists()


def test_batch_to_stdout(capsys, tmp_path: Path) -> None:
    table = tmp_path / "in.csv"
    table.write_text("command,phi,k\nsingle,0.612,3000\npreload,0.612,4000\n")
    code, out, err = run(capsys, "simulate", "--batch", str(table), "--out", "-")
    assert code == EXIT_OK, err
    result = pd.read_csv(io.StringIO(out))
    assert list(result.columns) == ["command", "phi", "k", "height_mm", "status"]
    expected = gb.simulate("preload", 0.612, {"k": 4000.0}).height_mm[0]
    assert result["height_mm"].iloc[1] == pytest.approx(float(expected))
    assert list(tmp_path.iterdir()) == [table]


def test_single_jump_setting_flags(capsys) -> None:
    argv = ["simulate", "--command", "delayed_stutter", "--phi", "0.612", "--param", "k=3000"]
    flags = ["--freq-hz", "12", "--amplitude-mm", "15", "--delay-ms", "30", "--settle-periods", "2"]
    code, out, err = run(capsys, *argv, *flags, "--json")
    assert code == EXIT_OK, err
    record = json.loads(out)
    settings = {"freq_hz": 12.0, "amplitude_mm": 15.0, "delay_ms": 30.0, "settle_periods": 2.0}
    assert record["command_settings"] == settings
    exp = gb.Experiment().replace(**settings)
    expected = gb.simulate("delayed_stutter", 0.612, {"k": 3000.0}, experiment=exp)
    assert record["height_mm"] == pytest.approx(float(expected.height_mm[0]), abs=1e-9)
    default = gb.simulate("delayed_stutter", 0.612, {"k": 3000.0}).height_mm[0]
    assert record["height_mm"] != pytest.approx(float(default))
    code, out, err = run(capsys, *argv, "--freq-hz", "0")
    assert code == EXIT_INPUT and "--freq-hz 0: must be > 0" in err
    code, out, err = run(capsys, *argv, "--delay-ms", "abc")
    assert code == EXIT_INPUT and "--delay-ms abc: expected a number" in err


def test_diagnose_progress_labels_name_law_and_run() -> None:
    """diagnose hands every fit a progress callback labelled by law and run."""
    from granbayes._criticism._bank import FitBank
    from granbayes._sampler import ProgressInfo

    seen = []
    bank = FitBank(
        gb.Experiment(), pd.DataFrame(), gb.DiagnoseSettings(), None, 0, "", print,
        lambda label, info: seen.append((label, info.step)),
    )  # fmt: skip
    info = ProgressInfo(100, 1000, 12.0, 1.02, 300.0, False)
    bank._progress(("depth", "drag"))("phi=0.602", info)
    bank._progress(("depth",), " (rerun 1)")("all", info)
    assert seen == [("depth + drag, phi=0.602", 100), ("depth (rerun 1), all", 100)]
    assert FitBank(gb.Experiment(), pd.DataFrame(), gb.DiagnoseSettings(), None, 0, "",
                   print)._progress(("depth",)) is None  # fmt: skip


def test_progress_bars_one_per_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """ProgressBars: one bar per label; with leave=False removed once the run ends."""
    from granbayes._cli import ProgressBars
    from granbayes._sampler import ProgressInfo

    bars = ProgressBars(quiet=False, leave=False)
    bars.enabled = True  # as on a terminal
    with bars:
        bars("depth, phi=0.6", ProgressInfo(100, 300, 10.0, 1.1, 50.0, False))
        bars("depth, phi=0.7", ProgressInfo(100, 300, 10.0, 1.1, 50.0, False))
        assert set(bars.bars) == {"depth, phi=0.6", "depth, phi=0.7"}
        bars("depth, phi=0.6", ProgressInfo(200, 300, 10.0, 1.0, 500.0, True))
        bars("depth, phi=0.7", ProgressInfo(300, 300, 10.0, 1.1, 50.0, False))
        assert bars.bars == {}
    assert not ProgressBars(quiet=True).enabled
