"""The batched Nelder-Mead visits SciPy's points: same minimum, value and evaluations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import optimize

from granbayes._search import drive, nelder_mead


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
