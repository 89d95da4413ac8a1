"""Batched searches: the Nelder-Mead visits SciPy's points; blocking climbs in threads too."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import optimize

from granbayes._search import drive, in_thread, nelder_mead


def rosen(x: np.ndarray) -> float:
    """Rosenbrock's function with a kink (|.|) so that shrinks happen."""
    return float(optimize.rosen(x) + 0.3 * np.abs(x[0] - 0.2))


@pytest.mark.parametrize("maxfev", [7, 40, 400, 2000])
@pytest.mark.parametrize("adaptive", [False, True])
def test_nelder_mead_is_scipys(maxfev: int, adaptive: bool) -> None:
    """Six searches side by side (one call per round) give SciPy's results one by one,
    whether the evaluation budget stops them or the tolerances do."""
    rng = np.random.default_rng(1)
    starts = [rng.normal(size=4) for _ in range(5)] + [np.zeros(4)]
    options = {"maxfev": maxfev, "xatol": 1e-4, "fatol": 1e-3, "adaptive": adaptive}
    expected = [optimize.minimize(rosen, x, method="Nelder-Mead", options=options) for x in starts]
    rounds = []

    def evaluate(points: list[np.ndarray], which: list[int]) -> np.ndarray:
        rounds.append(len(points))
        return np.array([rosen(p) for p in points])

    got = drive([nelder_mead(x, **options) for x in starts], evaluate)
    for (x, fun, nfev), ref in zip(got, expected, strict=True):
        np.testing.assert_array_equal(x, ref.x)
        assert fun == ref.fun and nfev == ref.nfev
    assert max(rounds) == len(starts)  # the searches share calls
    assert sum(rounds) == sum(r.nfev for r in expected)


def _scipy_climb(x0: np.ndarray, shift: float, method: str):
    """A blocking SciPy minimisation of ``rosen(x - shift)`` through ``ask``."""

    def climb(ask):
        def f(u: np.ndarray) -> float:
            return float(ask((shift, u))[0])

        return optimize.minimize(f, x0, method=method, options={"maxfev": 3000})

    return climb


def _rosen_rounds(rounds: list):
    def evaluate(requests: list, which: list[int]) -> list[np.ndarray]:
        rounds.append(list(which))
        return [np.array([rosen(u - shift)]) for shift, u in requests]

    return evaluate


def test_blocking_climbs_in_threads_are_scipys_and_share_rounds() -> None:
    """SciPy's Powell and Nelder-Mead run in threads (:func:`in_thread`) side by side give
    the results of running them alone, bit for bit, with one ``evaluate`` call a round
    (as many rounds as the longest climb's evaluations, the first holding every climb)."""
    rng = np.random.default_rng(3)
    starts = [rng.normal(size=3) for _ in range(5)]
    shifts = [0.0, 0.5, -1.0, 2.0, 0.25]
    methods = ["Powell", "Nelder-Mead", "Powell", "Nelder-Mead", "Powell"]
    rounds: list = []
    together = drive(
        [in_thread(_scipy_climb(x, s, m)) for x, s, m in zip(starts, shifts, methods, strict=True)],
        _rosen_rounds(rounds),
    )
    for x, s, m, res in zip(starts, shifts, methods, together, strict=True):
        alone = optimize.minimize(
            lambda u, s=s: rosen(u - s), x, method=m, options={"maxfev": 3000}
        )
        np.testing.assert_array_equal(res.x, alone.x)
        assert res.fun == alone.fun
        assert res.nfev == alone.nfev
    assert len(rounds) == max(r.nfev for r in together)
    assert rounds[0] == list(range(5))
    assert sum(len(r) for r in rounds) == sum(r.nfev for r in together)


def test_an_error_in_a_threaded_climb_is_raised_and_the_others_stop() -> None:
    """The climb's own exception comes out of :func:`drive`; every thread ends."""
    import threading

    def bad(ask):
        ask((0.0, np.zeros(2)))
        raise ValueError("climb failed")

    before = threading.active_count()
    searches = [in_thread(_scipy_climb(np.zeros(2), 0.0, "Powell")), in_thread(bad)]
    with pytest.raises(ValueError, match="climb failed"):
        drive(searches, _rosen_rounds([]))
    assert threading.active_count() == before


def test_a_failing_evaluation_stops_the_threads() -> None:
    import threading

    def evaluate(requests: list, which: list[int]) -> list[np.ndarray]:
        raise RuntimeError("simulator failed")

    before = threading.active_count()
    searches = [in_thread(_scipy_climb(np.zeros(2), 0.0, "Powell")) for _ in range(3)]
    with pytest.raises(RuntimeError, match="simulator failed"):
        drive(searches, evaluate)
    assert threading.active_count() == before
