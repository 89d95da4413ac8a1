"""The ensemble grouping of a fit's walkers, and the trace plot drawn from it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import xarray as xr
from matplotlib.colors import to_rgb

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
        # the walkers: one thin line collection per ensemble, in its median's colour
        thin = [seg for c in ax.collections for seg in c.get_segments()]
        assert len(thin) == N_ENS * WALKERS
        assert all(c.get_linewidth()[0] < 1.0 for c in ax.collections)
        np.testing.assert_array_equal(
            [seg[:, 1] for seg in thin], _fit(runs).posterior["k"].values[:, :, p]
        )
        thick = [line for line in ax.lines if line.get_linewidth() >= 1.0]
        assert len(thick) == groups == len(ax.collections)
        per_group = N_ENS * WALKERS // groups
        for g, line in enumerate(thick):
            chains = slice(g * per_group, (g + 1) * per_group)
            values = _fit(runs).posterior["k"].values[chains, :, p]
            np.testing.assert_array_equal(line.get_ydata(), np.median(values, axis=0))
            np.testing.assert_array_equal(
                ax.collections[g].get_edgecolor()[0][:3], to_rgb(line.get_color())
            )
        # the walkers' lines are inside the axes' limits (a collection does not widen them
        # unless added with its limits)
        low, high = ax.get_ylim()
        assert low <= _fit(runs).posterior["k"].values[:, :, p].min()
        assert high >= _fit(runs).posterior["k"].values[:, :, p].max()
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


@pytest.mark.parametrize(
    "value, minus, plus, text",
    [
        (1857.3, 93.5, 81.3, "$1857^{+81}_{-94}$"),  # two digits of the smaller error
        (11.83, 5.49, 6.29, "$11.8^{+6.3}_{-5.5}$"),
        (12345.0, 930.0, 1020.0, "$12340^{+1020}_{-930}$"),  # rounded to tens
        (0.5, 0.1, 0.2, "$0.50^{+0.20}_{-0.10}$"),
        (5.0, 0.0, 0.0, "$5^{+0}_{-0}$"),  # no error: three significant digits
    ],
)
def test_a_value_is_printed_to_the_precision_of_its_errors(value, minus, plus, text):
    assert figures.value_with_errors(value, minus, plus) == text


def _text_boxes(fig) -> tuple[list, object]:
    """Window extents of the figure's title and of every axes title, after a draw."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    titles = [ax.title for ax in fig.axes if ax.get_visible() and ax.get_title()]
    return [t.get_window_extent(renderer) for t in titles], fig._suptitle.get_window_extent(
        renderer
    )


def test_a_corner_plot_titles_its_marginals_clear_of_the_figure_title_inside_the_figure():
    """Saved uncropped (no second draw), so every title must lie inside the figure; the
    figure's two-line title used to overlap the first marginal's."""
    from granbayes.testing import fake_fit

    dt = fake_fit(3, terms=("depth", "drag"))
    fig = figures.plot_corner(dt, float(dt.posterior["phi"].values[0]), ["k", "c_d", "sigma_mm"])
    titles, suptitle = _text_boxes(fig)
    assert len(titles) == 3
    assert "\n" in fig._suptitle.get_text()  # SYNTHETIC label and the title
    width, height = fig.bbox.width, fig.bbox.height
    for box in [*titles, suptitle]:
        assert box.x0 >= 0 and box.y0 >= 0 and box.x1 <= width and box.y1 <= height
    for box in titles:
        assert not box.overlaps(suptitle)
    k = next(ax.get_title() for ax in fig.axes if ax.get_title().startswith("k "))
    assert "e+" not in k and k.startswith("k [N/m] = $")


def test_a_rank_plot_names_units_volume_fractions_and_ensembles():
    from granbayes.testing import fake_fit

    dt = fake_fit(3, terms=("depth", "drag"))
    fig = figures.plot_rank(dt, ["k", "c_d"])
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert titles and all(t.split("\n")[0] in ("k [N/m]", "c_d [kg/m]") for t in titles)
    assert all("φ = " in t for t in titles)
    (legend,) = fig.legends
    n_ens = json.loads(dt.attrs["runs"])[0]["n_ensembles"]
    assert [t.get_text() for t in legend.get_texts()] == [f"ensemble {e}" for e in range(n_ens)]
    assert "SYNTHETIC" in fig._suptitle.get_text()


def test_every_robot_parameter_a_fit_can_sample_is_labelled_with_its_unit():
    from granbayes._likelihood import CALIBRATED_KEYS

    for name in CALIBRATED_KEYS:
        assert figures.param_unit(name), name
        assert not figures.param_label(name).endswith("[]"), name
    assert figures.param_label("k_spring") == "k_spring [N/m]"
    assert figures.param_label("amplitude_mm") == "stroke amplitude [mm]"


def test_a_residual_map_of_one_volume_fraction_keeps_its_long_title_inside_the_figure():
    import pandas as pd

    cells = pd.DataFrame(
        {
            "command": ["single", "preload", "delayed_stutter"],
            "phi": 0.602,
            "freq_hz": 10.0,
            "amplitude_mm": 20.0,
            "delay_ms": 50.0,
            "settle_periods": 3.0,
            "mean_residual_mm": [0.6, -1.2, 0.0],
            "z": [0.3, -0.6, 3.5],
        }
    )
    title = "SYNTHETIC data (tests/test_figures.py seed=3): selected depth + drag + compaction"
    fig = figures.plot_residual_heatmap(cells, title, 2.93)
    _, suptitle = _text_boxes(fig)
    assert suptitle.x0 >= 0 and suptitle.x1 <= fig.bbox.width and suptitle.y1 <= fig.bbox.height
    assert fig._suptitle.get_text().replace("\n", " ").startswith(title)


def test_a_predictive_check_of_one_volume_fraction_draws_its_bands():
    """A lone volume fraction has no neighbour to join a band to: drawn as boxes."""
    from granbayes.testing import fake_fit

    dt = fake_fit(3, terms=("depth", "drag"))
    phi = float(dt.observed_data["phi"].values[0])
    jumps = np.flatnonzero(dt.observed_data["phi"].values == phi)
    one = xr.DataTree.from_dict(
        {
            "observed_data": dt.observed_data.to_dataset().isel(jump=jumps),
            "posterior_predictive": dt.posterior_predictive.to_dataset().isel(jump=jumps),
        }
    )
    one.attrs = dt.attrs
    n_freq = len(np.unique(one.observed_data["freq_hz"].values))
    fig = figures.plot_predictive(one)
    for ax in fig.axes:
        widths = [np.ptp(p.vertices[:, 0]) for c in ax.collections for p in c.get_paths()]
        assert sum(w > 0 for w in widths) == 2 * n_freq  # light and dark band per frequency


def test_the_rank_test_takes_one_walker_in_turn_every_step_of_each_ensemble():
    from granbayes.stats._summaries import rank_test_draws

    out = rank_test_draws(_fit(SAME), ["k"], step=3)["k"]
    draws = np.arange(0, N_DRAW, 3)
    assert out.sizes == {"chain": N_ENS, "draw": len(draws), "phi": len(PHIS)}
    for e in range(N_ENS):
        expected = 1000 * e + 100 * (np.arange(len(draws)) % WALKERS) + draws + 0.5
        np.testing.assert_array_equal(out.values[e, :, 1], expected)
    # ensembles that cannot be grouped: every walker a chain, thinned by the step
    loose = rank_test_draws(_fit([]), ["k"], step=3)["k"]
    assert loose.sizes == {"chain": N_ENS * WALKERS, "draw": len(draws), "phi": len(PHIS)}


def test_a_rank_plot_of_walkers_that_cannot_be_grouped_has_no_ensemble_legend():
    from granbayes.testing import fake_fit

    dt = fake_fit(3, terms=("depth", "drag"))
    runs = json.loads(dt.attrs["runs"])
    runs[0] = {**runs[0], "n_ensembles": runs[0]["n_ensembles"] + 1}  # runs disagree
    dt.attrs["runs"] = json.dumps(runs)
    fig = figures.plot_rank(dt, ["k"])
    assert not fig.legends
    assert "every walker a chain" in fig._suptitle.get_text()
