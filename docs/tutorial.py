# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # granbayes tutorial: from one simulated jump to a diagnosis
#
# This tutorial walks through the whole workflow on a small experiment of your own:
#
# 1. simulate a jump;
# 2. make an experiment folder (**synthetic** data, labelled as such);
# 3. fit a force law to it;
# 4. read the posterior;
# 5. check it (R-hat, ESS, prior vs posterior, LOO-PIT);
# 6. predict heights at a setting that was not measured;
# 7. diagnose what the law gets wrong.
#
# It is a plain Python script in jupytext's percent format: run it with
# `python docs/tutorial.py`, or open it as a notebook with jupytext. Everything it writes
# goes to `tutorial-output/` in the current folder. The sampler settings are **short**, so
# that the tutorial runs in about a minute; the numbers are rough. For real work keep
# granbayes' defaults (chains of >= 10 autocorrelation times, 4 ensembles, ESS >= 400).

# %%
from pathlib import Path

import arviz as az
import matplotlib
import numpy as np

import granbayes as gb
from granbayes import DiagnoseSettings, FitSettings, SamplerSettings, diagnose, fit
from granbayes._synthetic import make_jumps, write_experiment

matplotlib.use("Agg")  # figures are written to files
OUT = Path("tutorial-output")
OUT.mkdir(exist_ok=True)
SEED = 2026  # every random step below derives from an explicit seed
CI_PROB = 0.90  # intervals are 90% equal-tailed, always named explicitly

# Short chains and relaxed convergence criteria, for the tutorial only (see above).
FAST = SamplerSettings(
    n_walkers=8,
    n_ensembles=2,
    max_steps=1500,
    tau_factor=5.0,
    min_ess=100,
    max_rhat=1.05,
    n_draws=50,
)

# %% [markdown]
# ## 1. Simulate a jump
#
# The force law is a sum of named terms (`depth`: `k z`, `drag`: `c_d z'^2`, ...; see
# `docs/physics-model.md`). `simulate` takes a command, a volume fraction `phi` and the
# parameters [SI], and simulates any number of parameter sets in one call. A jump that
# fails gets a NaN height and a status instead of an exception.

# %%
law = {"k": 4000.0, "c_d": 30.0}
one = gb.simulate("delayed_stutter", 0.612, law)
status = gb.Status(one.status[0]).label  # "ok", or why the jump failed
print(f"delayed stutter at phi = 0.612: {one.height_mm[0]:.1f} mm ({status})")

sweep = gb.simulate("preload", 0.612, {"k": np.linspace(1e3, 1e4, 5), "c_d": 30.0})
print("preload height [mm] for k = 1000 ... 10000 N/m:", np.round(sweep.height_mm, 1))

trajectory = gb.simulate_trajectory("delayed_stutter", 0.612, law)
print(trajectory.data[["t_s", "x_foot_mm", "z_max_mm", "ground_force_N"]].tail(3))

# %% [markdown]
# ## 2. An experiment folder of your own (SYNTHETIC)
#
# An experiment is a folder with `experiment.toml` (robot and command settings) and
# `jumps.csv` (`phi`, `command`, `height_mm`, ...; `docs/data-format.md`). With no
# measurements at hand, we make one: a loose bed (phi = 0.592, below the critical packing
# 0.612) that the first intrusion compacts (the `compaction` term, `docs/physics-model.md`
# section 8), plus 3 mm of Gaussian scatter.
# `make_jumps` writes a `source` column `synthetic: ...` in every row, and every
# figure and report made from these data says **SYNTHETIC data**.

# %%
PHI = 0.592
TRUTH = {"k": 1800.0, "c_comp": 0.7}  # the law we will try to recover
jumps = make_jumps(
    lambda phi: TRUTH,
    3.0,
    phis=(PHI,),
    freqs_hz=(12.0,),
    commands=("single", "preload", "delayed_stutter_preload"),
    trials=5,
    seed=SEED,
    label="docs/tutorial.py",
)
folder = write_experiment(OUT / "my-lab", jumps, gb.Experiment())
experiment = gb.load_experiment(folder)
table = gb.load_jumps(folder, experiment)  # validated, as `granbayes fit` reads it
print(table[["phi", "command", "freq_hz", "trial", "height_mm", "source"]].head())

# %% [markdown]
# ## 3. Fit
#
# `fit` samples the posterior of the law's parameters per volume fraction, shared by every
# command, plus the scatter `sigma_mm`, with emcee; `granbayes fit my-lab --out fit
# --terms depth,compaction --seed 2026` does the same from the command line and writes a
# report. Here we fit the law the data were made with; step 7 finds it without being told.

# %%
config = FitSettings(terms=("depth", "compaction"), sampler=FAST, n_prior_draws=100)
result = fit(experiment, table, config, seed=SEED, data_source="my-lab (synthetic)")
print("converged:", result.converged)
for warning in result.warnings:
    print("warning:", warning)
dt = result.datatree  # an ArviZ DataTree; granbayes fit writes it as posterior.nc
print(list(dt.children))

# %% [markdown]
# ## 4. Read the posterior
#
# ArviZ's summary with an explicit interval: posterior mean, sd, the 90% equal-tailed
# interval, and the convergence diagnostics of the next step.

# %%
summary = az.summary(dt, var_names=["k", "c_comp", "sigma_mm"], ci_prob=CI_PROB)
print(summary)
print("truth:", TRUTH, "sigma_mm = 3.0")

# %% [markdown]
# ## 5. Check it
#
# * **R-hat** near 1 (granbayes requires <= 1.01 across ensembles at its defaults) and
#   **ESS** in the hundreds: the chains agree and are long enough.
# * **Prior vs posterior**: a parameter whose posterior looks like its prior is not
#   identified by these jumps.
# * **LOO-PIT**: for a calibrated model the leave-one-out probability integral transforms
#   of the observations are uniform.

# %%
print(summary[["r_hat", "ess_bulk", "ess_tail"]])

az.plot_prior_posterior(dt, var_names=["k", "c_comp"]).savefig(OUT / "prior_posterior.png")

pit = az.loo_pit(dt)
print("LOO-PIT values:", np.round(pit["height_mm"].values, 2))
az.plot_loo_pit(dt).savefig(OUT / "loo_pit.png")

# %% [markdown]
# ## 6. Predict a setting that was not measured
#
# `gb.predict` simulates the jump for posterior draws of the law (keeping the draws joint)
# and adds the fitted scatter for a new jump. The setting: a delayed stutter at 10 Hz, a
# frequency absent from the data.

# %%
pred = gb.predict(result, "delayed_stutter", PHI, freq_hz=10.0, ci_prob=CI_PROB, rng=SEED)
print(pred.table.T)
new_setting = experiment.replace(freq_hz=10.0)
true_height = gb.simulate("delayed_stutter", PHI, TRUTH, experiment=new_setting)
print(f"truth (noiseless): {true_height.height_mm[0]:.1f} mm")

# %% [markdown]
# ## 7. Diagnose
#
# `diagnose` starts from a baseline law (here the thesis's depth-only law), shows where
# it misfits, tries the candidate terms and adds one only when PSIS-LOO clearly prefers
# it. The data were made with compaction, so compaction should be found, and drag not.
# `granbayes diagnose my-lab --out diag` does the same and writes `diagnosis.json` and a
# report; there every other term of the library is a candidate (here two, to be quick).
# A term that the named one does not beat by the rule's margin is listed as
# indistinguishable from it: the data then do not say which of the two is the cause.

# %%
diag_config = DiagnoseSettings(baseline=("depth",), candidates=("drag", "compaction"), sampler=FAST)
diagnosis = diagnose(experiment, table, diag_config, seed=SEED, data_source="my-lab")
record = diagnosis.to_json()
print("verdict:", record["verdict"])
print("added:", record["selected"]["added"])
# terms the data predict about as well with (a name among equals is not a cause)
print("not told apart from:", [t["term"] for t in record["selected"]["indistinguishable"]])
gain, se = record["selected"]["elpd_gain"], record["selected"]["elpd_gain_se"]
print(f"ELPD gain: {gain:.1f} +- {se:.1f} nats")
rmse_before, rmse_after = record["selected"]["rmse_before_mm"], record["selected"]["rmse_after_mm"]
print(f"RMSE: {rmse_before:.2f} -> {rmse_after:.2f} mm")
