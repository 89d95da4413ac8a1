"""The fallbacks of ``diagnose``'s model comparison where PSIS-LOO flags jumps.

Moment matching first (its agreement with ArviZ is ``tests/test_moment_matching.py``), then
exact leave-one-out refits, or K-fold of the volume fractions holding many flagged jumps;
every refit of every law sampled side by side. Data: SYNTHETIC (the test kit), two volume
fractions, three commands, three trials; the law is the truth (depth only), so the
held-out densities must agree with PSIS-LOO where PSIS is reliable.
"""

from __future__ import annotations

import numpy as np
import pytest

from granbayes import Experiment
from granbayes._criticism import DiagnoseSettings
from granbayes._criticism._bank import FitBank, Pointwise
from granbayes.testing import QUICK_SAMPLER, synthetic_jumps

PHIS = (0.602, 0.622)
DEPTH = ("depth",)
DRAG = ("depth", "drag")


def _quiet(*args, **kwargs) -> None:
    """A ``log`` that prints nothing."""


@pytest.fixture(scope="module")
def bank() -> FitBank:
    """A bank holding the depth and depth + drag fits of depth-only SYNTHETIC data."""
    table = synthetic_jumps(
        lambda phi: {"k": 4000.0 + 1.5e5 * (phi - 0.612)},
        2.0,
        seed=4,
        phis=PHIS,
        commands=("single", "preload", "delayed_stutter"),
        trials=3,
        label="tests/test_loo_fallbacks.py",
        settings_columns=True,
    )
    config = DiagnoseSettings(sampler=QUICK_SAMPLER, n_threads=1, max_refits=2, kfold=3)
    b = FitBank(Experiment(), table, config, None, 5, "", _quiet)
    b.get(DEPTH)
    b.get(DRAG, parent=DEPTH)
    return b


def _flag(bank: FitBank, monkeypatch: pytest.MonkeyPatch, rows: dict) -> None:
    """Make exactly the given jumps keep a bad Pareto k after moment matching, per law."""

    def flagged(keys):
        out = []
        for key in keys:
            reliable = np.ones(len(bank.units), dtype=bool)
            reliable[rows.get(key, [])] = False
            out.append((np.array(bank.loos[key]["elpd_i"], dtype=float), reliable, 0))
        return out

    monkeypatch.setattr(bank, "moment_matched_many", flagged)


def test_reliable_psis_needs_no_fallback(bank: FitBank, monkeypatch: pytest.MonkeyPatch) -> None:
    """No jump flagged in either law: PSIS-LOO values, unchanged, and no refit."""
    _flag(bank, monkeypatch, {})
    monkeypatch.setattr(bank, "held_out", lambda req: pytest.fail("refit") if req else [])
    (e_depth, e_drag), method = Pointwise(bank)((DEPTH, DRAG))
    assert method == "psis-loo"
    np.testing.assert_array_equal(e_depth, bank.loos[DEPTH]["elpd_i"])
    np.testing.assert_array_equal(e_drag, bank.loos[DRAG]["elpd_i"])


def test_exact_refits_are_paired_side_by_side_and_agree_with_psis(
    bank: FitBank, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Jumps flagged in one law are refitted in both, in one batch of refits.

    Two jumps flagged (one in each law, at the first volume fraction): each law gets two
    exact refits (the union), all four sampled side by side (one ``held_out`` call). The
    truth is in both laws and PSIS is in fact reliable here, so an exact held-out density
    matches its PSIS value within 0.5 nats (the refit's Monte Carlo error and the
    lighter settings).
    """
    t = bank.units
    first = np.flatnonzero(t["phi"].to_numpy() == PHIS[0])
    _flag(bank, monkeypatch, {DEPTH: [first[0]], DRAG: [first[4]]})
    calls = []
    real = bank.held_out
    monkeypatch.setattr(bank, "held_out", lambda req: calls.append(len(req)) or real(req))
    pw = Pointwise(bank)
    (e_depth, e_drag), method = pw((DEPTH, DRAG))
    assert method == "psis-loo + 2 exact refit(s)"
    assert calls == [4]
    for law, e in ((DEPTH, e_depth), (DRAG, e_drag)):
        psis = np.asarray(bank.loos[law]["elpd_i"])
        changed = np.flatnonzero(e != psis)
        assert set(changed) <= {first[0], first[4]}
        np.testing.assert_allclose(e[[first[0], first[4]]], psis[[first[0], first[4]]], atol=0.5)
    # cached: asking again refits nothing
    again, _ = pw((DEPTH, DRAG))
    assert calls == [4]
    np.testing.assert_array_equal(again[0], e_depth)


def test_kfold_of_one_volume_fraction_is_paired(
    bank: FitBank, monkeypatch: pytest.MonkeyPatch
) -> None:
    """More flagged jumps at a volume fraction than ``max_refits``: K-fold of it alone.

    Every jump of that volume fraction is replaced by its K-fold value in both laws (the
    same folds, stratified by command), the other volume fraction keeps PSIS; the K
    refits of each law are one batch.
    """
    t = bank.units
    second = np.flatnonzero(t["phi"].to_numpy() == PHIS[1])
    _flag(bank, monkeypatch, {DEPTH: list(second[:3])})
    calls = []
    real = bank.held_out
    monkeypatch.setattr(bank, "held_out", lambda req: calls.append(len(req)) or real(req))
    (e_depth, e_drag), method = Pointwise(bank)((DEPTH, DRAG))
    assert method == f"psis-loo + 3-fold of phi = {PHIS[1]:g}"
    assert calls == [2 * 3]
    folds = bank.folds(PHIS[1])
    assert set(folds[second]) == {0, 1, 2} and np.all(folds[t["phi"] == PHIS[0]] == -1)
    # folds hold every command: one jump of each command in each fold (3 trials)
    at = t.loc[second].assign(fold=folds[second])
    assert (at.groupby(["fold", "command"]).size() == 1).all()
    for law, e in ((DEPTH, e_depth), (DRAG, e_drag)):
        psis = np.asarray(bank.loos[law]["elpd_i"])
        first = t["phi"].to_numpy() == PHIS[0]
        np.testing.assert_array_equal(e[first], psis[first])
        assert np.all(np.isfinite(e[second])) and np.any(e[second] != psis[second])
        # K-fold predicts from 2/3 of the data: a little worse than LOO, not wildly
        assert abs(np.sum(e[second]) - np.sum(psis[second])) < 5.0


def test_moment_matching_replaces_only_flagged_jumps(bank: FitBank) -> None:
    """Moment matching leaves reliable jumps alone; the flagged ones get finite values."""
    elpd, reliable, n = bank.moment_matched(DRAG)
    loo = bank.loos[DRAG]
    good = np.asarray(loo["pareto_k"]) <= loo["good_k"]
    np.testing.assert_array_equal(elpd[good], np.asarray(loo["elpd_i"])[good])
    assert reliable[good].all() and np.all(np.isfinite(elpd))
    assert n == int(np.sum(~good))
