"""Where the ensembles start: the Laplace start of fits with tracked jumps or intrusions.

The data are SYNTHETIC, from the independent scipy oracle (``granbayes.testing``'s lab).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from granbayes import default_priors, load_experiment, load_measurements
from granbayes._fitting import (
    FitSettings,
    _adapted_step,
    _climbs,
    _find_starts_many,
    _hessian,
    _hessian_points,
    _laplace_cov,
    fit,
    part_models,
)
from granbayes._sampler import SamplerSettings
from granbayes.testing import LabDesign, synthetic_lab_data, write_lab_experiment

#: One volume fraction, one filmed jump at 500 frames/s, one intrusion test (seed 5).
DESIGN = LabDesign(
    phis=(0.612,),
    commands=("single",),
    trials=3,
    tracked_trials=1,
    fps=500.0,
    track_from_s=-0.01,
    track_after_end_s=0.05,
    intrusion_speeds_mm_s=(100.0,),
    depth_step_mm=1.0,
    depth_max_mm=30.0,
)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    data = synthetic_lab_data({"k": 3000.0, "c_d": 20.0}, seed=5, design=DESIGN)
    return write_lab_experiment(tmp_path_factory.mktemp("lab"), data, truth_file=False)


def test_hessian_of_central_differences_is_exact_for_a_quadratic(
    rng: np.random.Generator,
) -> None:
    """Second differences are exact for a quadratic, whatever the steps."""
    d = 4
    a = rng.standard_normal((d, d))
    A = a @ a.T + d * np.eye(d)
    b = rng.standard_normal(d)
    x = rng.standard_normal(d)
    h = np.array([1e-2, 3e-3, 0.1, 1.0])
    pts = _hessian_points(x, h)
    values = -0.5 * np.einsum("ni,ij,nj->n", pts, A, pts) + pts @ b
    np.testing.assert_allclose(_hessian(values, h), -A, rtol=1e-6, atol=1e-6)


def test_laplace_covariance_inverts_a_concave_hessian_and_bounds_the_rest() -> None:
    """-H^-1 where the log-posterior is concave; at most 5% of the prior's width elsewhere."""
    width = np.array([10.0, 2.0, 4.0])
    sd = np.array([0.01, 0.02, 0.03])
    H = -np.diag(1.0 / sd**2)
    np.testing.assert_allclose(np.sqrt(np.diag(_laplace_cov(H, width))), sd, rtol=1e-9)
    H[2, 2] = +5.0  # convex in the last direction (a saddle), and unmeasured in the second
    H[1, 1] = np.nan
    cov = _laplace_cov(H, width)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), [0.01, 0.05 * 2.0, 0.05 * 4.0], rtol=1e-9)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_laplace_starts_climb_thrice_beyond_heights_only(folder: Path) -> None:
    """The posteriors of tracked jumps and intrusions get ``start_climbs`` climbs per
    ensemble (separated modes), fits of heights alone one."""
    experiment = load_experiment(folder)
    priors = default_priors()
    settings = FitSettings(terms=("depth", "drag"))
    for use, climbs in ((["heights"], 1), (None, 3), (["heights", "intrusions"], 3)):
        data = load_measurements(folder, experiment, use)
        (_, model, _), *_ = part_models(experiment, data, settings, priors)
        assert _climbs(model, 3) == climbs
    with pytest.raises(ValueError, match="start"):
        SamplerSettings(start="mode")


@pytest.mark.slow  # a converged joint fit (~30 s on 2 cores)
def test_laplace_start_is_at_the_posteriors_own_scale(folder: Path) -> None:
    """The walkers of a Laplace start spread like the posterior the fit then samples.

    Per coordinate, the sd of the 4 x 28 start positions against the posterior sd of a
    converged fit: a ratio within [1/3, 3]. Measured (seed 3 and 1): 0.98-1.23 for the
    law and the noise of frames and forces, 0.41 for the scatter of the 3 jump heights,
    whose posterior piles on its prior's lower bound (not normal: the Laplace width at the
    bound is narrower than its sd); the search start it replaces: 2.9-634 (k 634, c_d 70).
    The sd of 112 draws alone is uncertain by about 7%.
    """
    experiment = load_experiment(folder)
    data = load_measurements(folder, experiment)
    settings = FitSettings(terms=("depth", "drag"))
    result = fit(experiment, data, settings, seed=3)
    part = result.parts[0]
    assert part.run.converged
    model = part.model
    post_sd = part.run.samples.reshape(-1, model.ndim).std(axis=0)
    nw = settings.sampler.walkers_for(model.ndim)
    ratios = {}
    for start in ("laplace", "search"):
        starts = _find_starts_many([model], [np.random.default_rng(1)], 4, [nw], [None], start)
        ratios[start] = np.concatenate(starts[0]).std(axis=0) / post_sd
    names = model.coordinate_names
    message = {s: dict(zip(names, np.round(r, 2), strict=True)) for s, r in ratios.items()}
    assert np.all((ratios["laplace"] > 1 / 3) & (ratios["laplace"] < 3)), message


def test_a_start_note_is_reported_but_is_not_a_restart() -> None:
    """Notes on where the ensembles started come first among a run's warnings and do not
    use up ``max_restarts`` (a restart note does)."""
    from granbayes._sampler import START_NOTE, RunSpec, _start_run

    initial = [np.random.default_rng(i).standard_normal((8, 2)) for i in range(2)]
    s = SamplerSettings(n_walkers=8, n_ensembles=2)
    run = _start_run(RunSpec(initial, 0, seed=1, notes=(START_NOTE + "ensemble(s) 1 ...",)), s)
    assert run.restarts == 0 and run.notes == [START_NOTE + "ensemble(s) 1 ..."]
    assert _start_run(RunSpec(initial, 0, seed=1, notes=("step 50: restarted",)), s).restarts == 1


class _TwoModes:
    """A stub posterior on [-10, 10]^2: two narrow modes, the better one at (6, 6).

    The better mode is too narrow for the evolution strategy's steps to land in by chance
    from the other, and off the coordinate lines through the worse one (Powell's first
    line searches).
    """

    ndim = 2
    bounds_u = np.array([[-10.0, 10.0], [-10.0, 10.0]])
    closed_form_columns = np.zeros(2, dtype=bool)  # no intrusion curves
    centres = np.array([[-6.0, -6.0], [6.0, 6.0]])
    heights = np.array([0.0, 30.0])  # [nats]
    sds = np.array([0.3, 0.05])

    def log_prob(self, u: np.ndarray) -> np.ndarray:
        d2 = ((u[:, None, :] - self.centres[None]) ** 2).sum(axis=2)
        return np.max(self.heights - d2 / (2 * self.sds**2), axis=1)

    def log_prior(self, u: np.ndarray) -> np.ndarray:
        inside = np.all((u >= -10.0) & (u <= 10.0), axis=1)
        return np.where(inside, 0.0, -np.inf)


def _stub_evaluate(models, points):
    from types import SimpleNamespace

    return [
        SimpleNamespace(log_prob=m.log_prob(np.asarray(u)))
        for m, u in zip(models, points, strict=True)
    ]


@pytest.mark.parametrize("climbs", [1, 3])
def test_each_ensemble_starts_from_the_best_of_its_climbs(
    monkeypatch: pytest.MonkeyPatch, climbs: int
) -> None:
    """A climb from the worse mode's basin stays there (a local climb cannot cross); with
    further starting points of its own, one of them in the better basin, the ensemble
    starts at the better mode, and the run's notes say that the climbs ended in separated
    modes. (Why several climbs: ``_laplace_starts``' docstring, measured on a SBC
    replicate of tracked jumps whose climbs found the truth's mode in 5 of 16.)"""
    import granbayes._fitting as gfit

    monkeypatch.setattr(gfit, "evaluate_models", _stub_evaluate)
    model = _TwoModes()
    searched = np.array([[-5.6, -6.2]])  # the one ensemble's searched point: worse basin
    others = {(0, 0): np.array([[-6.3, -6.4], [5.9, 6.05]])[: climbs - 1]}
    notes: dict[int, list[str]] = {}
    drawn = gfit._laplace_starts(
        [model], [np.random.default_rng(3)], [searched], [64], [0], [None], 5.0, notes, others
    )
    centre = drawn[0, 0].mean(axis=0)
    expected = model.centres[1] if climbs == 3 else model.centres[0]
    np.testing.assert_allclose(centre, expected, atol=0.15)  # 64 walkers of sd <= 0.3
    if climbs == 3:
        assert "2 of 3 climbs ended more than" in notes[0][0]
        # the note says which value is the best mode's and which are the lower climbs'
        best = float(re.search(r"of the best (-?[\d.]+);", notes[0][0]).group(1))
        lower = re.search(r"of the lower ([-\d., ]+)\)", notes[0][0]).group(1).split(", ")
        assert len(lower) == 2 and all(float(v) < best - 5.0 for v in lower)
    else:
        assert not notes


class _TwoModesWithCurves(_TwoModes):
    """The stub with intrusion curves: their own posterior, broad, peaks at the better mode."""

    closed_form_columns = np.ones(2, dtype=bool)

    def closed_form_log_prob(self, u: np.ndarray) -> np.ndarray:
        d2 = ((np.atleast_2d(u) - self.centres[1]) ** 2).sum(axis=1)
        return self.log_prior(np.atleast_2d(u)) - d2 / (2 * 2.0**2)


def test_intrusion_curves_add_a_climb_from_their_own_mode(monkeypatch: pytest.MonkeyPatch):
    """The global phase: with intrusion curves, each ensemble gets one more climb, from
    its searched point with the curves' coordinates at the curves' own mode. From a
    searched point in the worse basin and no other start, that climb reaches the better
    mode, and the ensemble starts there; the climb from the searched point ends where it
    ends without curves, bit for bit (the new climb's steps have a generator of their
    own)."""
    import granbayes._fitting as gfit

    monkeypatch.setattr(gfit, "evaluate_models", _stub_evaluate)
    searched = np.array([[-5.6, -6.2]])
    runs = {}
    for label, model in (("plain", _TwoModes()), ("curves", _TwoModesWithCurves())):
        notes: dict[int, list[str]] = {}
        ends: dict = {}
        drawn = gfit._laplace_starts(
            [model],
            [np.random.default_rng(3)],
            [searched],
            [64],
            [0],
            [None],
            5.0,
            notes,
            {},
            ends,
        )
        runs[label] = (drawn[0, 0].mean(axis=0), ends[0, 0], notes)
    centre, ends, notes = runs["curves"]
    np.testing.assert_allclose(centre, _TwoModes.centres[1], atol=0.15)
    assert len(ends) == 2 and ends[1] > ends[0] + 25.0
    assert "1 of 2 climbs ended more than" in notes[0][0]
    plain_centre, plain_ends, _ = runs["plain"]
    np.testing.assert_allclose(plain_centre, _TwoModes.centres[0], atol=0.15)
    assert plain_ends == [ends[0]]


def test_the_evolution_strategies_step_grows_where_a_round_improved_and_shrinks_elsewhere():
    """x1.5 after a success, capped at a quarter of the prior's width; x0.6 after a failure;
    one flag per row of steps (screening's points) or one for all (a climb)."""
    width = np.array([1.0, 8.0])
    steps = np.array([[0.1, 1.0], [0.2, 1.9], [0.3, 0.5]])
    out = _adapted_step(steps, np.array([True, True, False]), width)
    np.testing.assert_allclose(out, [[0.15, 1.5], [0.25, 2.0], [0.18, 0.3]])
    np.testing.assert_allclose(_adapted_step(steps[0], True, width), [0.15, 1.5])
    np.testing.assert_allclose(_adapted_step(steps[0], False, width), [0.06, 0.6])
