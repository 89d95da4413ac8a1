"""Hide an effect in SYNTHETIC data and require ``diagnose`` to find it (slow; run in CI).

For every term of the library: data from ``k(phi)`` + that effect + Gaussian noise
(sigma = 2 mm) for a robot other than the default (lighter motor, softer spring, smaller
foot, 18 mm amplitude), 2 volume fractions x 5 commands x 2 frequencies (7 and 12 Hz) x 3
trials, made by the test kit (:func:`granbayes.testing.synthetic_jumps`) with a fixed
seed. ``diagnose`` starts from the depth-only law and must

- name exactly the hidden term (verdict ``extended``, ``added == [term]``),
- recover its parameter: the 90% interval covers the truth at >= 1 of the 2 volume
  fractions and the posterior medians are within 35% of it (each interval covers with
  probability 0.9, both only 81% of the time; the seeds are fixed, so the outcome is
  deterministic),
- predict a fresh replicate (same experiment, new noise, never seen by the diagnosis) as
  well as the truth does, within the rule's own margin (a deficit larger than 4 nats and
  2 SE fails; :func:`granbayes.calibration.fresh_deficit`), and better than the baseline;
- converge: every fit the decision rests on converged (``all_converged``).

A null case (no hidden effect) must give ``baseline_adequate``. The confusable pair drag /
viscous is separated by the two frequencies (different intrusion speeds): each wins by
ELPD when it is the truth, by the rule's margin (more than 4 nats and 2 SE of the paired
difference), or its rival is screened out; with drag as the truth this design does not
reach the margin (6.0 +- 4.0 nats, a strict ``xfail`` that records it), and the diagnosis
must then report the tie; the jumps ``granbayes design`` proposes for that tie, simulated
from the truth and fitted with the data, must then separate them.

Effects *outside* the library (``granbayes.calibration.OUT_OF_LIBRARY``: four ground
forces of the oracle's out-of-library physics, a depth-dependent drag, a saturating depth
force, a bed that relaxes during a pause, a strength that grows with the intrusion rate;
and the two earlier cell-wise rescalings of ``k``) must not be blamed on a library term:
the verdict is ``misfit_remains``, or a law that predicts a fresh replicate as well as
the truth does (within the rule's margin). A term named whose predictions fall short of
the truth's fails, and so does an effect left undetected whose baseline falls short.

Every table is made by the independent oracle (the test kit), never by the fitting
kernel.

These are single draws: the measured error rates over many draws are in
``docs/verdicts/`` (``benchmarks/calibrate_verdicts.py``).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pandas as pd
import pytest

from granbayes import CommandSettings, Experiment, Robot, stats
from granbayes._criticism import DiagnoseSettings, diagnose, distinguished
from granbayes._fitting import FitSettings, fit
from granbayes.calibration import OUT_OF_LIBRARY, as_good_as_truth, fresh_deficit, make_case
from granbayes.design import candidate_settings, design_jumps
from granbayes.forces import terms_of
from granbayes.testing import simulate_height_scipy, synthetic_jumps

pytestmark = pytest.mark.slow

ROBOT = Robot(m_motor=0.8, m_rod=0.25, m_foot=0.12, k_spring=4500.0, c_spring=4.0, foot_radius=0.03)
EXPERIMENT = Experiment(robot=ROBOT, command=CommandSettings(amplitude_mm=18.0))
EFFECTS = {
    "drag": {"c_d": 60.0},
    "added_mass": {"kappa": 1.5},
    "stiffening": {"k2": 1.5e5},
    "viscous": {"b": 30.0},
    "compaction": {"c_comp": 0.6},
    "unloading": {"r_unload": 3.0},
}
CONFIG = DiagnoseSettings()
SIGMA_MM = 2.0


def _truth(term: str | None):
    def truth(phi: float) -> dict[str, float]:
        x = phi - 0.612
        return {"k": 3500.0 + 1.2e5 * x + 1.5e6 * x * x, **EFFECTS.get(term or "", {})}

    return truth


def _table(term: str | None, seed: int):
    return synthetic_jumps(
        _truth(term),
        SIGMA_MM,
        seed=seed,
        experiment=EXPERIMENT,
        phis=(0.597, 0.627),
        freqs_hz=(7.0, 12.0),
        label=f"tests/test_hidden_effects.py {term}",
        settings_columns=True,
        true_heights=True,
    )


def _fresh_deficit(law, term: str | None) -> tuple[float, float]:
    """The truth's advantage over ``law`` on a fresh replicate (seed 12) [nats], and its SE."""
    fresh = _table(term, seed=12)
    return fresh_deficit(law, fresh, fresh["true_height_mm"].to_numpy(), SIGMA_MM)


def _rate_law_margin(d, truth: str, rival: str) -> tuple[float, float]:
    """PSIS-LOO ELPD of ``depth + truth`` minus ``depth + rival`` [nats], and its SE."""
    loo = {t: stats.loo(d.fits[terms_of(("depth", t))].datatree) for t in (truth, rival)}
    return stats.elpd_difference(loo[truth]["elpd_i"], loo[rival]["elpd_i"])


@functools.cache
def _diagnosis(term: str | None, screen: bool = True):
    table = _table(term, seed=11).drop(columns="true_height_mm")
    config = dataclasses.replace(CONFIG, screen=screen)
    return diagnose(EXPERIMENT, table, config, seed=5, log=lambda *a, **k: None)


#: The cases ``.ci/run`` runs on every submission (marker ``ci_subset``): a false
#: discovery, a hidden term (added mass, the thesis's term and the one at the detection
#: limit of the verdict study; 42 s on a slow 2-core machine, compaction 60 s, drag 65 s)
#: and an effect outside the library (a ground force of the oracle: a depth force that
#: saturates; the cheapest of the four, 40 s; with the pause-relaxing bed, 85 s, ``.ci/run``
#: took 8 min 3 s on a fast machine).
#: The whole suite runs with ``make test-slow``.
CI_SUBSET = ("null", "added_mass", "janssen_saturation")


def _marks(name: str) -> list:
    marks = [pytest.mark.xdist_group(name)]
    return [*marks, pytest.mark.ci_subset] if name in CI_SUBSET else marks


@pytest.mark.parametrize("term", [pytest.param(t, marks=_marks(t)) for t in EFFECTS])
def test_diagnose_finds_the_hidden_term(term: str) -> None:
    """Exactly the hidden term is added; its parameter is recovered; the gain is real."""
    d = _diagnosis(term)
    rec = d.to_json()
    assert rec["verdict"] == "extended", rec["candidates"]
    assert rec["selected"]["added"] == [term]
    ((name, true_value),) = EFFECTS[term].items()
    intervals = rec["selected"]["parameters"][name]
    covered = [lo <= true_value <= hi for lo, _, hi in intervals.values()]
    assert sum(covered) >= 1, intervals
    assert all(abs(med / true_value - 1) < 0.35 for _, med, _ in intervals.values()), intervals
    assert rec["selected"]["rmse_after_mm"] < rec["selected"]["rmse_before_mm"]
    deficit, se = _fresh_deficit(d.selected, term)
    baseline_deficit, _ = _fresh_deficit(d.baseline, term)
    print(f"{term}: fresh deficit {deficit:.1f} +- {se:.1f}, baseline {baseline_deficit:.1f}")
    assert as_good_as_truth(deficit, se, CONFIG)
    assert deficit < baseline_deficit
    assert rec["all_converged"], rec["fits"]
    assert rec["residual_misfit"] == []


@pytest.mark.xdist_group("null")
@pytest.mark.ci_subset
def test_null_case_keeps_the_baseline() -> None:
    """No hidden effect: no term may be added (false discoveries are as bad as misses)."""
    d = _diagnosis(None)
    assert d.verdict == "baseline_adequate", d.to_json()["candidates"]
    assert d.added == []
    assert d.to_json()["all_converged"]


@pytest.mark.parametrize(
    ("truth", "rival"),
    [
        pytest.param(
            "drag",
            "viscous",
            marks=[
                pytest.mark.xdist_group("drag"),
                # measured 2026-11-26 (oracle data, seed 11, diagnosis seed 5): drag beats
                # viscous by 6.0 +- 4.0 nats, 1.5 SE, short of the rule's 2 SE; the
                # diagnosis reports the tie (test_an_unseparated_pair_is_reported_as_a_tie).
                # strict: a design or sampler change that separates them must say so here.
                pytest.mark.xfail(
                    strict=True,
                    reason="7 and 12 Hz x 3 trials do not separate drag from viscous by the "
                    "rule's margin when drag is the truth (6.0 +- 4.0 nats)",
                ),
            ],
        ),
        pytest.param("viscous", "drag", marks=pytest.mark.xdist_group("viscous")),
    ],
)
def test_two_frequencies_separate_drag_from_viscous(truth: str, rival: str) -> None:
    """The true rate law beats its rival by ELPD (recorded with the SE of the difference)."""
    d = _diagnosis(truth)
    first = {c.term: c for c in d.candidates if c.round == 1}
    assert first[truth].converged
    if first[rival].screened_out:
        # the rival's best in-sample gain is below the truth's ELPD gain (less the margin):
        # it cannot win, a stronger separation than an ELPD margin
        print(f"{rival} screened out: {first[rival].screen_gain:.1f} vs {first[truth].gain:.1f}")
        assert first[rival].screen_gain < first[truth].gain
        return
    margin, se = _rate_law_margin(d, truth, rival)
    print(f"{truth} vs {rival}: elpd margin {margin:.1f} +- {se:.1f}")
    assert distinguished(margin, se, CONFIG)
    assert np.isfinite(first[rival].elpd)
    assert first[rival].converged


@pytest.mark.parametrize(
    "truth",
    [
        pytest.param("drag", marks=pytest.mark.xdist_group("drag")),
        pytest.param("viscous", marks=pytest.mark.xdist_group("viscous")),
    ],
)
def test_an_unseparated_pair_is_reported_as_a_tie(truth: str) -> None:
    """Where the data do not separate the rate laws by the rule's margin, the diagnosis
    says so: the rival fitted and not beaten is listed as indistinguishable from the truth."""
    d = _diagnosis(truth)
    rival = {"drag": "viscous", "viscous": "drag"}[truth]
    first = {c.term: c for c in d.candidates if c.round == 1}
    rec = d.to_json()
    assert rec["selected"]["added"] == [truth]
    ties = {t["term"] for t in rec["selected"]["indistinguishable"]}
    if first[rival].screened_out:
        assert rival not in ties
        return
    margin, se = _rate_law_margin(d, truth, rival)
    separated = distinguished(margin, se, CONFIG)
    print(f"{truth} vs {rival}: {margin:.1f} +- {se:.1f}, reported ties {sorted(ties)}")
    assert (rival in ties) == (not separated)


@pytest.mark.parametrize("effect", [pytest.param(e, marks=_marks(e)) for e in OUT_OF_LIBRARY])
def test_effect_outside_the_library_is_not_blamed_on_a_term(effect: str) -> None:
    """The library cannot explain it: misfit_remains, or a law as good as the truth."""
    case = make_case(effect, seed=7, trials=3)
    d = diagnose(case.experiment, case.table, CONFIG, seed=5, log=lambda *a, **k: None)
    rec = d.to_json()
    fresh = make_case(effect, seed=7, trials=3, replicate=1)
    sigma_mm = case.truth["sigma_mm"]
    deficit, se = fresh_deficit(d.selected, fresh.table, fresh.true_height_mm, sigma_mm)
    print(
        f"{effect}: {rec['verdict']} {rec['selected']['added']}, "
        f"{len(rec['residual_misfit'])} misfit cells, fresh deficit {deficit:.1f} +- {se:.1f}"
    )
    if rec["verdict"] != "misfit_remains":
        assert as_good_as_truth(deficit, se, CONFIG), (rec["verdict"], rec["selected"]["added"])


@pytest.mark.parametrize(
    "term",
    [
        pytest.param(None, id="null", marks=pytest.mark.xdist_group("null")),
        pytest.param("drag", id="drag", marks=pytest.mark.xdist_group("drag")),
        pytest.param("compaction", id="compaction", marks=pytest.mark.xdist_group("compaction")),
    ],
)
def test_screening_makes_the_decision_of_the_full_comparison(term: str | None) -> None:
    """Screening only skips candidates that cannot win: same verdict and terms as fitting all.

    The same data and seed diagnosed with every candidate fitted in full: the verdict,
    the added terms and the residual misfit agree; every screened-out candidate's full
    ELPD gain is below the chosen one's (or below ``min_gain`` when none was chosen).
    """
    screened, full = _diagnosis(term), _diagnosis(term, screen=False)
    a, b = screened.to_json(), full.to_json()
    assert a["verdict"] == b["verdict"]
    assert a["selected"]["added"] == b["selected"]["added"]
    assert len(a["residual_misfit"]) == len(b["residual_misfit"])
    full_gain = {(c.round, c.term): c.gain for c in full.candidates}
    for c in screened.candidates:
        chosen = [
            x.gain
            for x in screened.candidates
            if x.round == c.round and x.term in screened.added and not x.screened_out
        ]
        if not c.screened_out or not chosen:
            continue  # with nothing chosen, the equal decisions above are the check
        print(
            f"round {c.round} {c.term}: screen {c.screen_gain:.1f}, full "
            f"{full_gain[(c.round, c.term)]:.1f}, chosen {chosen[0]:.1f}"
        )
        assert full_gain[(c.round, c.term)] < chosen[0]


@pytest.mark.xdist_group("drag")
def test_the_designed_jumps_settle_the_drag_viscous_tie() -> None:
    """The tie above (drag true, viscous not beaten by the rule's margin) is what
    ``granbayes design`` is for: the jumps it proposes from the diagnosis's two fits
    (every command, both volume fractions, 7-12 Hz; at most 60), simulated from the truth
    by the oracle with the same scatter and fitted with the data, separate drag from
    viscous by the rule's margin, the right way round. One draw: the rates over many
    ties are in ``benchmarks/results/design_ties_*.md``."""
    d = _diagnosis("drag")
    rec = d.to_json()
    ties = [t for t in rec["selected"]["indistinguishable"] if t["term"] == "viscous"]
    assert ties, "the diagnosis no longer reports the tie: update this test"
    (tie,) = ties
    laws = {t: d.fits[terms_of(("depth", t))] for t in ("drag", "viscous")}
    table = _table("drag", seed=11).drop(columns="true_height_mm")
    grid = candidate_settings(table, freqs_hz=(7.0, 8.0, 10.0, 12.0), delays_ms=[np.nan])
    plan = design_jumps(
        laws,
        evidence={("drag", "viscous"): (tie["elpd_diff"], tie["elpd_diff_se"])},
        candidates=grid,
        max_jumps=60,
        settings=CONFIG,
        rng=0,
    )
    print(plan.plan.to_string(), plan.hypotheses.round(2).to_string(), sep="\n")
    assert plan.settled
    rng = np.random.default_rng(13)
    rows = []
    for r in plan.plan.itertuples():
        exp = EXPERIMENT.replace(freq_hz=float(r.freq_hz))
        height = simulate_height_scipy(r.command, r.phi, _truth("drag")(r.phi), exp)
        for trial in range(int(r.trials)):
            rows.append(
                {"phi": r.phi, "command": r.command, "freq_hz": float(r.freq_hz),
                 "trial": 4 + trial, "height_mm": height + rng.normal(0.0, SIGMA_MM),
                 "source": "synthetic: tests/test_hidden_effects.py designed jumps",
                 "amplitude_mm": EXPERIMENT.command.amplitude_mm,
                 "delay_ms": EXPERIMENT.command.delay_ms,
                 "settle_periods": EXPERIMENT.command.settle_periods}
            )  # fmt: skip
    more = pd.concat([table, pd.DataFrame(rows)], ignore_index=True)
    loo = {}
    for term in ("drag", "viscous"):
        settings = FitSettings(
            terms=("depth", term), sampler=CONFIG.sampler, n_prior_draws=0, n_threads=1
        )
        refit = fit(EXPERIMENT, more, settings, seed=5)
        assert refit.converged
        loo[term] = stats.loo(refit.datatree)["elpd_i"]
    diff, se = stats.elpd_difference(loo["drag"], loo["viscous"])
    print(f"after {plan.n_jumps} designed jumps: drag - viscous = {diff:.1f} +- {se:.1f}")
    assert distinguished(diff, se, CONFIG)
