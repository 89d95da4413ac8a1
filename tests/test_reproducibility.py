"""A fit reruns as promised: bit for bit in the same environment, within Monte Carlo error
elsewhere (README, "Reproducibility").

``tests/data/reproducibility-fit.json`` is a small fit with a fixed seed: the environment
it ran in (package versions and machine, ``granbayes._provenance``), a SHA-256 of its
posterior draws, and posterior quantiles with their Monte Carlo standard errors. The test
reruns the fit. When the reproducibility key of this environment equals the recorded one
(same versions, same numba target CPU and features, same numpy SIMD targets, same C
library), the draws must be bit-identical. Otherwise each quantile must agree within
``Z_TOL`` combined Monte Carlo standard errors (the two runs are independent MCMC runs of
the same posterior; a changed last bit anywhere makes the chains diverge).

Regenerate the file (after a change of the fit, or of the lock file) with
``python tests/test_reproducibility.py --write``.
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
from pathlib import Path

import numpy as np
from arviz_stats.base import array_stats

from granbayes import load_experiment, load_jumps
from granbayes._fitting import FitSettings, fit
from granbayes._provenance import environment, reproducibility_key
from granbayes._sampler import SamplerSettings
from granbayes._synthetic import REFERENCE_DATA

RECORD = Path(__file__).resolve().parent / "data" / "reproducibility-fit.json"
SEED = 20261124
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)
#: Allowed difference of a quantile between environments, in combined MCSEs (two-sided
#: 4 sigma: about 6e-5 false alarms per quantile if the MCSEs are right; the MCSEs of
#: quantiles from autocorrelated chains are themselves uncertain by some 10-20%).
Z_TOL = 4.0


def small_fit() -> dict:
    """Fit the depth-only law to 10 SYNTHETIC reference jumps (phi = 0.612, 12 Hz, preload and
    stutter) with seed :data:`SEED`; the record to compare (see the module docstring)."""
    experiment = load_experiment(REFERENCE_DATA)
    table = load_jumps(REFERENCE_DATA, experiment)
    keep = (table.phi == 0.612) & (table.freq_hz == 12.0)
    table = table[keep & table.command.isin(["preload", "stutter"])].reset_index(drop=True)
    sampler = SamplerSettings(
        n_walkers=8, n_ensembles=2, max_steps=1500, check_every=100, min_ess=200, n_draws=100
    )
    config = FitSettings(terms=("depth",), sampler=sampler, n_prior_draws=0)
    result = fit(experiment, table, config, seed=SEED, data_source="reference subset")
    post = result.datatree.posterior.to_dataset().squeeze("phi", drop=True)
    digest = hashlib.sha256()
    quantiles, mcse = {}, {}
    for name in sorted(post.data_vars):
        values = np.ascontiguousarray(post[name].values, dtype=float)  # (chain, draw)
        digest.update(name.encode() + values.tobytes())
        quantiles[name] = [float(q) for q in np.quantile(values.ravel(), QUANTILES)]
        mcse[name] = [float(array_stats.mcse(values, method="quantile", prob=q)) for q in QUANTILES]
    env = environment()
    return {
        "what": "posterior of the depth-only law on 10 SYNTHETIC reference jumps "
        "(phi 0.612, 12 Hz, preload + stutter); tests/test_reproducibility.py",
        "seed": SEED,
        "converged": bool(result.converged),
        "reproducibility_key": reproducibility_key(env),
        **env,
        "posterior_sha256": digest.hexdigest(),
        "quantile_probs": list(QUANTILES),
        "quantiles": quantiles,
        "mcse": mcse,
    }


def compare(new: dict, ref: dict) -> list[str]:
    """What disagrees between two records at the promised level (empty: they agree)."""
    if new["reproducibility_key"] == ref["reproducibility_key"]:
        if new["posterior_sha256"] != ref["posterior_sha256"]:
            return ["same environment, but the posterior draws are not bit-identical"]
        return []
    problems = []
    for name, ref_q in ref["quantiles"].items():
        for i, p in enumerate(ref["quantile_probs"]):
            tol = Z_TOL * math.hypot(ref["mcse"][name][i], new["mcse"][name][i])
            diff = new["quantiles"][name][i] - ref_q[i]
            if not abs(diff) <= tol:
                problems.append(
                    f"{name} {p:.0%} quantile {new['quantiles'][name][i]:.6g} vs "
                    f"{ref_q[i]:.6g}: differs by {diff:.3g}, tolerance {tol:.3g}"
                )
    return problems


def test_fit_reruns_as_promised() -> None:
    """Bit-identical in the recorded environment; within Monte Carlo error elsewhere."""
    ref = json.loads(RECORD.read_text())
    new = small_fit()
    assert new["converged"] and ref["converged"]
    problems = compare(new, ref)
    same = new["reproducibility_key"] == ref["reproducibility_key"]
    level = "bit-identical (same environment)" if same else "within Monte Carlo error"
    assert not problems, f"not {level}:\n" + "\n".join(problems)


def test_compare_is_strict_where_promised() -> None:
    """The comparison itself: a changed bit fails in the same environment; elsewhere a
    shift of one MCSE passes and one of ten fails."""
    ref = json.loads(RECORD.read_text())
    assert compare(ref, ref) == []
    tampered = {**ref, "posterior_sha256": "0" * 64}
    assert compare(tampered, ref)
    other = {**ref, "reproducibility_key": "elsewhere"}
    for shift, ok in ((1.0, True), (10.0, False)):
        moved = {
            name: [q + shift * m for q, m in zip(qs, ref["mcse"][name], strict=True)]
            for name, qs in ref["quantiles"].items()
        }
        assert (compare({**other, "quantiles": moved}, ref) == []) is ok


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        sys.exit("usage: python tests/test_reproducibility.py --write")
    RECORD.write_text(json.dumps(small_fit(), indent=1) + "\n")
    print(f"wrote {RECORD}")
