"""The one interval of granbayes: the median and the equal-tailed interval of a sample."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

#: Probability of every interval granbayes reports (equal-tailed; ArviZ's default is 89%,
#: so it is always passed explicitly).
CI_PROB = 0.90


def eti_probs(ci_prob: float = CI_PROB) -> tuple[float, float, float]:
    """The quantile levels of the lower end, the median and the upper end of an interval.

    Parameters
    ----------
    ci_prob : float
        Probability of the equal-tailed interval, in (0, 1).

    Returns
    -------
    tuple of float
        ``((1 - ci_prob) / 2, 0.5, 1 - (1 - ci_prob) / 2)``.
    """
    return (1.0 - ci_prob) / 2.0, 0.5, 1.0 - (1.0 - ci_prob) / 2.0


def interval(values: ArrayLike, ci_prob: float = CI_PROB) -> tuple[float, float, float]:
    """Median and the equal-tailed ``ci_prob`` interval of ``values`` (NaNs ignored).

    Parameters
    ----------
    values : array_like
        A sample (any shape; flattened).
    ci_prob : float
        Probability of the interval, in (0, 1).

    Returns
    -------
    tuple of float
        ``(median, lo, hi)``; all NaN if no value is finite.
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return (math.nan, math.nan, math.nan)
    lo, med, hi = np.quantile(v, eti_probs(ci_prob))
    return float(med), float(lo), float(hi)


def fmt_triple(med: float, lo: float, hi: float, fmt: str = ".3g") -> str:
    """``"median [lo, hi]"`` of a precomputed triple, each value formatted with ``fmt``.

    Parameters
    ----------
    med, lo, hi : float
        Median and interval bounds.
    fmt : str
        Format specification.
    """
    return f"{med:{fmt}} [{lo:{fmt}}, {hi:{fmt}}]"


def fmt_interval(values: ArrayLike, digits: int = 3, ci_prob: float = CI_PROB) -> str:
    """``"median [lo, hi]"`` of ``values`` with ``digits`` significant digits.

    Parameters
    ----------
    values : array_like
        Draws.
    digits : int
        Significant digits.
    ci_prob : float
        Probability of the equal-tailed interval.
    """
    return fmt_triple(*interval(values, ci_prob), fmt=f".{digits}g")
