"""Simulation-based calibration: uniformity of the ranks of true values, interval coverage."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd
import xarray as xr
from scipy import stats

#: Central posterior intervals whose coverage is reported.
COVERAGE_LEVELS: tuple[float, ...] = (0.5, 0.9)


def _chi_square(ranks: np.ndarray, n_draws: int) -> dict[str, Any]:
    """Chi-square test of uniformity of ranks ``0..n_draws`` in about n/5 bins (2-20)."""
    n = len(ranks)
    bins = int(min(max(n // 5, 2), 20, n_draws + 1))
    which = np.arange(n_draws + 1) * bins // (n_draws + 1)  # bin of every possible rank
    expected = np.bincount(which, minlength=bins) / (n_draws + 1) * n
    observed = np.bincount(which[ranks], minlength=bins)
    statistic, p_value = stats.chisquare(observed, expected)
    return {"bins": bins, "statistic": float(statistic), "p_value": float(p_value)}


def _coverage(ranks: np.ndarray, n_draws: int, level: float) -> dict[str, float]:
    """How often the truth lies in the central ``level`` interval of the draws."""
    n = len(ranks)
    lo, hi = (1.0 - level) / 2.0 * n_draws, (1.0 + level) / 2.0 * n_draws
    observed = float(np.mean((ranks >= lo) & (ranks <= hi)))
    possible = np.arange(n_draws + 1)
    nominal = float(np.mean((possible >= lo) & (possible <= hi)))  # under uniform ranks
    return {
        "observed": observed,
        "se": math.sqrt(observed * (1.0 - observed) / n),
        "nominal": nominal,
        "nominal_se": math.sqrt(nominal * (1.0 - nominal) / n),
    }


def normalised_ranks(ranks: pd.DataFrame) -> tuple[dict[str, np.ndarray], list[float]]:
    """Normalised ranks ``(rank + 0.5) / (n_draws + 1)`` per parameter: (replicate, phi).

    Parameters
    ----------
    ranks : pandas.DataFrame
        ``ranks.csv`` rows (``parameter``, ``phi``, ``replicate``, ``rank``, ``n_draws``).

    Returns
    -------
    pit : dict of str to ndarray, shape (replicate, phi)
        Replicates that have a rank at every volume fraction.
    phis : list of float
        The volume fractions of the columns.
    """
    phis = sorted(ranks["phi"].unique())
    n_draws = int(ranks["n_draws"].iloc[0])
    pit = {}
    for name in dict.fromkeys(ranks["parameter"]):
        wide = ranks[ranks["parameter"] == name].pivot_table(
            index="replicate", columns="phi", values="rank"
        )
        wide = wide.reindex(columns=phis).dropna()
        pit[name] = (wide.to_numpy(float) + 0.5) / (n_draws + 1)
    return pit, phis


def summarize_ranks(ranks: pd.DataFrame) -> list[dict[str, Any]]:
    """Per parameter and volume fraction: uniformity tests and interval coverage.

    Parameters
    ----------
    ranks : pandas.DataFrame
        ``ranks.csv`` rows (``parameter``, ``phi``, ``rank``, ``n_draws``, ``converged``).

    Returns
    -------
    list of dict
        ``parameter``, ``phi``, ``n_replicates``, ``n_draws``, ``mean_normalised_rank``
        (0.5 if calibrated), ``uniformity`` (chi-square on binned ranks: ``bins``,
        ``statistic``, ``p_value``; and ArviZ's ``pot_c_p_value``), ``coverage`` (per
        level ``"50%"``, ``"90%"``: ``observed`` with its binomial ``se``, and the
        ``nominal`` value expected for uniform ranks with its ``nominal_se``), and
        ``fraction_converged``.
    """
    if ranks.empty:
        return []
    if ranks["n_draws"].nunique() != 1:
        raise ValueError("ranks must all be among the same number of draws (n_draws)")
    n_draws = int(ranks["n_draws"].iloc[0])
    pit, phis = normalised_ranks(ranks)
    pot_c = sbc_uniformity(pit, phis) if all(len(v) >= 2 for v in pit.values()) else {}
    out = []
    for (name, phi), group in ranks.groupby(["parameter", "phi"], sort=False):
        r = group["rank"].to_numpy(int)
        uniformity = _chi_square(r, n_draws)
        p_arviz = pot_c.get(name)
        uniformity["pot_c_p_value"] = (
            None if p_arviz is None else float(p_arviz[phis.index(float(phi))])
        )
        out.append(
            {
                "parameter": str(name),
                "phi": float(phi),
                "n_replicates": len(r),
                "n_draws": n_draws,
                "mean_normalised_rank": float(np.mean(r) / n_draws),
                "uniformity": uniformity,
                "coverage": {f"{lv:.0%}": _coverage(r, n_draws, lv) for lv in COVERAGE_LEVELS},
                "fraction_converged": float(group["converged"].astype(bool).mean()),
            }
        )
    return out


def sbc_table(parameters: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """The rows of :func:`summarize_ranks` as a table to print or write.

    Parameters
    ----------
    parameters : sequence of mapping
        :func:`summarize_ranks`'s output (``summary.json``'s ``parameters``).

    Returns
    -------
    pandas.DataFrame
        One row per parameter and volume fraction: ``parameter``, ``phi``, ``n``,
        ``mean rank`` (0.5 if calibrated), ``<level> coverage`` as ``"observed ± se"``,
        ``chi2 p``, ``pot_c p`` and ``converged`` (the fraction of converged fits).
    """
    rows = [
        {
            "parameter": p["parameter"],
            "phi": p["phi"],
            "n": p["n_replicates"],
            "mean rank": round(p["mean_normalised_rank"], 3),
            **{
                f"{level} coverage": f"{c['observed']:.2f} ± {c['se']:.2f}"
                for level, c in p["coverage"].items()
            },
            "chi2 p": p["uniformity"]["p_value"],
            "pot_c p": p["uniformity"]["pot_c_p_value"],
            "converged": p["fraction_converged"],
        }
        for p in parameters
    ]
    return pd.DataFrame(rows)


def _sbc_dataset(pit: Mapping[str, np.ndarray], phis: Sequence[float]) -> xr.Dataset:
    n = len(next(iter(pit.values())))
    return xr.Dataset(
        {name: (("replicate", "phi"), np.asarray(v, dtype=float)) for name, v in pit.items()},
        coords={"replicate": np.arange(n), "phi": np.asarray(phis, dtype=float)},
    )


def sbc_uniformity(pit: Mapping[str, np.ndarray], phis: Sequence[float]) -> dict[str, np.ndarray]:
    """ArviZ's uniformity test of SBC PIT values (``pot_c``, arviz-stats), per phi.

    Parameters
    ----------
    pit : mapping of str to ndarray, shape (replicate, phi)
        PIT values in (0, 1) (normalised ranks) per parameter.
    phis : sequence of float
        The volume fractions of the second axis.

    Returns
    -------
    dict of str to ndarray, shape (phi,)
        p-value per parameter and volume fraction.
    """
    import arviz_stats  # noqa: F401  (registers the ``azstats`` accessor)

    ds = _sbc_dataset(pit, phis)
    p_values, _, _ = ds.azstats.uniformity_test(dim=["replicate"], method="pot_c")
    return {name: np.atleast_1d(p_values[name].values) for name in pit}
