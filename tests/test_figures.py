"""The ensemble grouping of a fit's walkers, and the trace plot drawn from it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import xarray as xr

from granbayes import figures
from granbayes.stats import by_ensemble

N_ENS, WALKERS, N_DRAW, PHIS = 3, 4, 25, (0.602, 0.622)


def _fit(runs: list[dict]) -> xr.DataTree:
    """A fit-shaped DataTree whose draw of (ensemble e, walker w, draw d, phi p) is
    ``1000 e + 100 w + d + 0.5 p`` (chains: walkers, ensemble by ensemble)."""
    e, w, d, p = np.meshgrid(
        np.arange(N_ENS), np.arange(WALKERS), np.arange(N_DRAW), np.arange(len(PHIS)), indexing="ij"
    )
    k = (1000.0 * e + 100.0 * w + d + 0.5 * p).reshape(N_ENS * WALKERS, N_DRAW, len(PHIS))
    post = xr.Dataset(
        {"k": (("chain", "draw", "phi"), k)},
        coords={"chain": np.arange(N_ENS * WALKERS), "draw": np.arange(N_DRAW), "phi": list(PHIS)},
    )
    observed = xr.Dataset(
        {"height_mm": ("jump", [50.0, 60.0])},
        coords={"source": ("jump", ["synthetic: tests/test_figures.py"] * 2)},
    )
    tree = xr.DataTree.from_dict({"posterior": post, "observed_data": observed})
    tree.attrs["runs"] = json.dumps(runs)
    return tree


SAME = [{"n_ensembles": N_ENS, "n_chains": N_ENS * WALKERS}] * len(PHIS)


def test_by_ensemble_puts_each_ensembles_walkers_inside_each_step():
    out = by_ensemble(_fit(SAME))["k"]
    assert out.sizes == {"chain": N_ENS, "draw": N_DRAW * WALKERS, "phi": len(PHIS)}
    for e in range(N_ENS):
        for d in (0, 7, N_DRAW - 1):
            for w in range(WALKERS):
                assert out.values[e, d * WALKERS + w, 1] == 1000 * e + 100 * w + d + 0.5


def test_by_ensemble_keeps_the_walkers_when_runs_disagree():
    runs = [SAME[0], {"n_ensembles": 2, "n_chains": N_ENS * WALKERS}]
    assert by_ensemble(_fit(runs))["k"].sizes["chain"] == N_ENS * WALKERS


@pytest.mark.parametrize("runs, groups", [(SAME, N_ENS), ([], 1)])
def test_trace_draws_every_walker_and_each_ensembles_median(runs, groups):
    fig = figures.plot_trace(_fit(runs), ["k"])
    axes = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title() for ax in axes] == [f"phi = {p:g}" for p in PHIS]
    for p, ax in enumerate(axes):
        thin = [line for line in ax.lines if line.get_linewidth() < 1.0]
        thick = [line for line in ax.lines if line.get_linewidth() >= 1.0]
        assert len(thin) == N_ENS * WALKERS
        assert len(thick) == groups
        per_group = N_ENS * WALKERS // groups
        for g, line in enumerate(thick):
            chains = slice(g * per_group, (g + 1) * per_group)
            values = _fit(runs).posterior["k"].values[chains, :, p]
            np.testing.assert_array_equal(line.get_ydata(), np.median(values, axis=0))
    assert "kept draw" in [ax.get_xlabel() for ax in axes]
    assert fig.get_suptitle().startswith("SYNTHETIC data (tests/test_figures.py)")


def test_trace_panels_of_a_parameter_with_a_named_coordinate():
    """A coordinate that is not a number (here a command) names its panels as it is."""
    tree = _fit(SAME)
    post = tree.posterior.to_dataset()
    k = post["k"].rename(phi="command").assign_coords(command=["single", "stutter"])
    tree = xr.DataTree.from_dict(
        {
            "posterior": post.drop_vars("k").drop_dims("phi").assign(k=k),
            "observed_data": tree.observed_data.to_dataset(),
        }
    )
    tree.attrs["runs"] = json.dumps(SAME)
    fig = figures.plot_trace(tree, ["k"])
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible() and ax.lines]
    assert titles == ["command = single", "command = stutter"]
