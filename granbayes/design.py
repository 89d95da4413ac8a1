"""The experiment that settles a tie: which jumps to measure next to separate rival laws.

Where ``diagnose`` reports laws it cannot tell apart (``selected.indistinguishable``: the
paired ELPD difference is short of the rule's margin, more than ``min_gain`` nats *and*
``se_factor`` standard errors), :func:`design_jumps` proposes the jumps (command, volume
fraction, frequency, delay) that are expected to separate them, and how many.

The criterion (Box & Hill 1967, "Discrimination among mechanistic models",
*Technometrics* 9, 57-71): a new jump at setting ``x`` adds to the ELPD difference of the
true law T over its rival R, in expectation, the Kullback-Leibler divergence of their
posterior predictive distributions at ``x``,

    D_TR(x) = E_{y ~ p_T(y | x, data)} [log p_T(y | x, data) - log p_R(y | x, data)],

and the variance of that log ratio, V_TR(x), adds to the variance of the paired sum. Both
predictive distributions are those of a *new measured jump* (:func:`granbayes.predict`:
posterior draws of the law, the fitted scatter and, for fits that integrate each bed's
volume fraction, a new bed), summarised by their mean and variance and taken as normal,
which gives D and V in closed form (Box & Hill's own approximation). As the truth is not
known, every ordered pair of the laws is a hypothesis ("T is true, R its rival"); after
``n_x`` new jumps at each ``x`` the hypothesis expects the difference

    d_TR + sum_x n_x D_TR(x)   with standard error   sqrt(se_TR^2 + sum_x n_x V_TR(x)),

where ``d_TR`` and ``se_TR`` are the paired difference and its SE on the data so far. A
plan *settles* the tie in expectation when under every hypothesis that difference passes
the rule (``min_gain`` nats and ``se_factor`` SE). Jumps are added one at a time to the
setting that most raises the worst hypothesis's ratio to the rule (a greedy maximin
allocation), until the plan settles or the budget ``max_jumps`` is spent.

What this leaves out, and why it is measured rather than assumed: the posteriors move
when the new jumps are fitted (a rival with freedom left can partly absorb them), so the
expected separation is an estimate of the gain, not a promise. How often designed jumps,
simulated from the truth and fitted, break real ties, against the same number of jumps
at settings drawn at random, is measured by ``benchmarks/design_ties.py`` (results in
``benchmarks/results/design_ties/`` and the README). Only jump heights are designed
(tracked jumps and intrusion tests are not proposed), and unidentified parameters are
not a target (only ties between laws).
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .commands import COMMAND_NAMES
from .criticism import DiagnoseSettings, distinguished
from .forces import terms_of
from .prediction import predict
from .saved import SavedFit, as_saved_fit, load_fit

__all__ = [
    "Design",
    "allocate_jumps",
    "candidate_settings",
    "design_from_diagnosis",
    "design_jumps",
    "load_tie",
    "normal_separation",
    "save_tie_laws",
    "ties_of",
]

#: Commands whose waveform has a hold: ``delay_ms`` matters for them only.
_DELAYED = ("delayed_stutter", "delayed_stutter_preload")
#: Settings columns of a candidate (and of a plan's rows).
SETTINGS = ("command", "phi", "freq_hz", "delay_ms")


def normal_separation(
    mean_t: np.ndarray, sd_t: np.ndarray, mean_r: np.ndarray, sd_r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of log p_T(y) - log p_R(y) for y ~ p_T, both normal [nats].

    The mean is the Kullback-Leibler divergence KL(p_T || p_R).

    Parameters
    ----------
    mean_t, sd_t : ndarray
        Mean and standard deviation of the true law's predictive distribution [mm].
    mean_r, sd_r : ndarray
        The same for the rival [mm].

    Returns
    -------
    kl, var : ndarray
        Expected log ratio per jump and its variance [nats, nats^2] (broadcast shape).

    Examples
    --------
    >>> kl, var = normal_separation(0.0, 1.0, 2.0, 1.0)  # equal widths: delta^2 / 2
    >>> float(kl), float(var)
    (2.0, 4.0)
    """
    st2, sr2 = np.square(sd_t), np.square(sd_r)
    delta = np.asarray(mean_t) - np.asarray(mean_r)
    kl = np.log(np.sqrt(sr2 / st2)) + (st2 + delta**2) / (2.0 * sr2) - 0.5
    # log ratio = const + e * delta / sr2 + e^2 (1 / (2 sr2) - 1 / (2 st2)), e ~ N(0, st2)
    var = (delta / sr2) ** 2 * st2 + 2.0 * st2**2 * (0.5 / sr2 - 0.5 / st2) ** 2
    return kl, var


def allocate_jumps(
    kl: np.ndarray,
    var: np.ndarray,
    diff_now: np.ndarray,
    se_now: np.ndarray,
    *,
    max_jumps: int,
    min_gain: float = 4.0,
    se_factor: float = 2.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Greedy maximin allocation of new jumps over settings (module docstring).

    Jumps are added one at a time, each to the setting that most raises the worst
    hypothesis's ratio to the rule, ``min(d / min_gain, d / (se_factor * se))``, until
    that ratio exceeds 1 (every hypothesis passes the rule in expectation) or
    ``max_jumps`` are spent.

    Parameters
    ----------
    kl, var : ndarray, shape (n_hypotheses, n_settings)
        Expected log ratio truth/rival per jump and its variance, per hypothesis and
        setting [nats, nats^2] (:func:`normal_separation`).
    diff_now, se_now : ndarray, shape (n_hypotheses,)
        Paired difference truth - rival and its SE on the data so far [nats].
    max_jumps : int
        Budget.
    min_gain, se_factor : float
        The rule: a difference counts when > ``min_gain`` nats and > ``se_factor`` SE.

    Returns
    -------
    counts : ndarray of int, shape (n_settings,)
        Jumps per setting.
    diff, se : ndarray, shape (n_hypotheses,)
        Expected difference after the jumps and its SE [nats].
    settled : bool
        Whether every hypothesis passes the rule in expectation.

    Examples
    --------
    >>> import numpy as np
    >>> counts, diff, se, settled = allocate_jumps(
    ...     np.array([[1.0, 0.1]]), np.array([[1.0, 0.1]]), np.zeros(1), np.zeros(1),
    ...     max_jumps=20)
    >>> counts.tolist(), diff.tolist(), settled  # 5 jumps: 5 > 4 nats and 5 > 2 sqrt(5)
    ([5, 0], [5.0], True)
    """
    kl, var = np.atleast_2d(kl), np.atleast_2d(var)
    mean, v = np.array(diff_now, dtype=float), np.square(np.asarray(se_now, dtype=float))
    counts = np.zeros(kl.shape[1], dtype=int)

    def ratio(m: np.ndarray, w: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            by_se = np.where(w > 0, m / (se_factor * np.sqrt(w)), np.sign(m) * np.inf)
        return np.minimum(m / min_gain, by_se).min(axis=0)

    settled = bool(ratio(mean[:, None], v[:, None])[0] > 1.0)
    while not settled and counts.sum() < max_jumps:
        score = ratio(mean[:, None] + kl, v[:, None] + var)
        best = int(np.argmax(score))
        counts[best] += 1
        mean += kl[:, best]
        v += var[:, best]
        settled = bool(score[best] > 1.0)
    return counts, mean, np.sqrt(v), settled


def candidate_settings(
    measured: pd.DataFrame,
    *,
    commands: Sequence[str] | None = None,
    phis: Sequence[float] | None = None,
    freqs_hz: Sequence[float] | None = None,
    delays_ms: Sequence[float] | None = None,
    n_freqs: int = 5,
) -> pd.DataFrame:
    """Settings a next jump may have: by default, within what the lab has measured.

    Parameters
    ----------
    measured : pandas.DataFrame
        The jumps measured so far (``phi``, ``command``, ``freq_hz``, and ``delay_ms`` if
        the table has it).
    commands : sequence of str, optional
        Default: every command.
    phis : sequence of float, optional
        Volume fractions [-] (default: the measured ones; a per-phi fit predicts at those
        only).
    freqs_hz : sequence of float, optional
        Frequencies [Hz] (default: ``n_freqs`` evenly from the lowest measured to the
        highest, the measured ones included: no extrapolation).
    delays_ms : sequence of float, optional
        Holds of the delayed commands [ms] (default: the measured ones, or the
        experiment's setting when the table has no ``delay_ms`` column: ``NaN``).
    n_freqs : int
        Frequencies of the default grid.

    Returns
    -------
    pandas.DataFrame
        One row per setting: ``command``, ``phi``, ``freq_hz``, ``delay_ms`` (``NaN``:
        the fit's experiment setting; also for commands without a hold).
    """
    commands = list(commands or COMMAND_NAMES)
    unknown = sorted(set(commands) - set(COMMAND_NAMES))
    if unknown:
        raise ValueError(f"unknown command(s) {unknown}; known: {list(COMMAND_NAMES)}")
    phis = sorted(set(map(float, phis if phis is not None else measured["phi"])))
    if freqs_hz is None:
        f = np.unique(measured["freq_hz"].to_numpy(float))
        grid = np.linspace(f.min(), f.max(), n_freqs) if f.size > 1 else f
        freqs_hz = np.unique(np.round(np.concatenate([grid, f]), 6))
    if delays_ms is None:
        delays_ms = (
            np.unique(measured["delay_ms"].dropna().to_numpy(float))
            if "delay_ms" in measured and measured["delay_ms"].notna().any()
            else [np.nan]
        )
    rows = []
    for command, phi, freq in itertools.product(commands, phis, sorted(map(float, freqs_hz))):
        for delay in delays_ms if command in _DELAYED else [np.nan]:
            rows.append({"command": command, "phi": phi, "freq_hz": freq, "delay_ms": delay})
    return pd.DataFrame(rows, columns=list(SETTINGS))


def _predictive_moments(
    fit: SavedFit, candidates: pd.DataFrame, n_draws: int, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and SD [mm] of a new measured jump at every candidate, and the failed share."""
    mean = np.full(len(candidates), np.nan)
    sd, failed = mean.copy(), mean.copy()
    groups = candidates.assign(_d=candidates["delay_ms"].fillna(-1.0)).groupby(
        ["command", "_d"], sort=False
    )
    for (command, delay), rows in groups:
        for (phi, freq), cell in rows.groupby(["phi", "freq_hz"], sort=False):
            p = predict(
                fit,
                command,
                float(phi),
                freq_hz=float(freq),
                delay_ms=None if delay < 0 else float(delay),
                n_draws=n_draws,
                rng=seed,
            )
            y = p.height_mm[:, 0]
            ok = np.isfinite(y)
            mean[cell.index] = np.mean(y[ok]) if ok.any() else np.nan
            sd[cell.index] = np.std(y[ok], ddof=1) if ok.sum() > 1 else np.nan
            failed[cell.index] = 1.0 - ok.mean()
    return mean, sd, failed


@dataclass(frozen=True)
class Design:
    """A plan of next jumps and the separation it is expected to give.

    Attributes
    ----------
    plan : pandas.DataFrame
        The jumps to measure: the settings (``command``, ``phi``, ``freq_hz``,
        ``delay_ms``) and ``trials``, most trials first.
    hypotheses : pandas.DataFrame
        One row per ordered pair of laws (``truth``, ``rival``): the paired ELPD
        difference truth - rival on the data so far (``elpd_diff_now``, ``se_now``), and
        expected after the plan (``elpd_diff_expected``, ``se_expected``) [nats], and
        ``settled`` (the rule passed in expectation).
    candidates : pandas.DataFrame
        Every setting considered: per law the predictive mean and SD of a new jump
        [mm] (``mean_mm[<law>]``, ``sd_mm[<law>]``), per hypothesis the expected
        separation per jump ``kl[<truth> vs <rival>]`` [nats] and its variance, and
        ``worst_kl`` (the smallest over the hypotheses), best first.
    n_jumps : int
        Jumps in the plan.
    settled : bool
        Whether the plan passes the rule under every hypothesis in expectation (if not,
        ``max_jumps`` was too small, or the settings considered cannot separate the
        laws).
    laws : tuple of str
        The laws, as ``+``-joined terms.
    rule : dict
        ``min_gain`` [nats] and ``se_factor``.
    notes : tuple of str
        What the design assumed or dropped, in words.
    """

    plan: pd.DataFrame
    hypotheses: pd.DataFrame
    candidates: pd.DataFrame
    n_jumps: int
    settled: bool
    laws: tuple[str, ...]
    rule: dict = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict:
        """JSON-ready summary (``design.json``)."""

        def records(df: pd.DataFrame) -> list[dict]:
            return json.loads(df.to_json(orient="records"))

        return {
            "laws": list(self.laws),
            "n_jumps": self.n_jumps,
            "settled": self.settled,
            "rule": self.rule,
            "plan": records(self.plan),
            "hypotheses": records(self.hypotheses),
            "method": "Box & Hill (1967) expected Kullback-Leibler separation of the laws' "
            "posterior predictive distributions (normal approximation), greedy maximin "
            "allocation of jumps over the hypotheses",
            "notes": list(self.notes),
        }


def _law_name(fit: SavedFit) -> str:
    return "+".join(fit.config.terms)


def design_jumps(
    fits: Mapping[str, object] | Sequence[object],
    *,
    evidence: Mapping[tuple[str, str], tuple[float, float]] | None = None,
    candidates: pd.DataFrame | None = None,
    max_jumps: int = 60,
    n_draws: int = 1000,
    config: DiagnoseSettings | None = None,
    rng: np.random.Generator | int = 0,
) -> Design:
    """Propose the next jumps that best separate rival laws fitted to the same data.

    Parameters
    ----------
    fits : mapping of str to fit, or sequence of fits
        Two or more fits of the same measurements (``granbayes.fit`` results, DataTrees,
        or ``posterior.nc`` paths), by law name (a sequence: named by their terms).
    evidence : mapping, optional
        ``{(truth, rival): (elpd_diff, se)}``, the paired ELPD difference truth - rival on
        the data so far and its SE [nats], for the ordered pairs given (the reverse pair
        is implied). Default: PSIS-LOO of the fits, paired over the same units
        (:func:`granbayes.stats.loo` and :func:`granbayes.stats.elpd_difference`).
    candidates : pandas.DataFrame, optional
        Settings a next jump may have (:func:`candidate_settings`; default: that of the
        first fit's measured jumps).
    max_jumps : int
        Budget: jumps added until the plan settles the tie, at most this many.
    n_draws : int
        Posterior draws per law and setting for the predictive moments.
    config : DiagnoseSettings, optional
        The rule's thresholds (``min_gain``, ``se_factor``; default ``DiagnoseSettings()``).
    rng : numpy.random.Generator or int
        Seed of the predictive draws (the same draws of each law at every setting).

    Returns
    -------
    Design

    Raises
    ------
    ValueError
        Fewer than two laws, fits of different data, or no setting every law predicts.
    """
    cfg = config or DiagnoseSettings()
    if max_jumps < 1:
        raise ValueError(f"max_jumps = {max_jumps}: must be >= 1")
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    seed = int(rng.integers(2**31))
    items = fits.items() if isinstance(fits, Mapping) else [(None, f) for f in fits]
    saved = {}
    for name, f in items:
        s = as_saved_fit(f)
        saved[name or _law_name(s)] = s
    laws = tuple(saved)
    if len(laws) < 2:
        raise ValueError(f"design_jumps needs two or more laws, got {list(laws)}")
    shas = {n: s.datatree.attrs.get("data_sha256") for n, s in saved.items()}
    if len(set(shas.values())) > 1:
        raise ValueError(f"the fits are of different data (sha256 by law: {shas})")
    first = saved[laws[0]]
    if candidates is None:
        candidates = candidate_settings(first.observed())
    candidates = candidates.reset_index(drop=True)
    moments = {law: _predictive_moments(s, candidates, n_draws, seed) for law, s in saved.items()}
    usable = np.ones(len(candidates), dtype=bool)
    for mean, sd, failed in moments.values():
        usable &= np.isfinite(mean) & np.isfinite(sd) & (sd > 0) & (failed <= 0.05)
    notes = []
    if not usable.all():
        notes.append(
            f"{int((~usable).sum())} of {len(candidates)} settings dropped: a law's jump did "
            "not finish in more than 5% of the draws there"
        )
    if not usable.any():
        raise ValueError("no setting that every law predicts: widen the candidates")
    table = candidates.copy()
    for law, (mean, sd, _) in moments.items():
        table[f"mean_mm[{law}]"] = mean
        table[f"sd_mm[{law}]"] = sd
    table = table[usable].reset_index(drop=True)
    evidence = dict(evidence) if evidence is not None else _loo_evidence(saved)
    pairs = list(itertools.permutations(laws, 2))
    d0, se0, kl, var = [], [], [], []
    for t, r in pairs:
        if (t, r) in evidence:
            d, s = evidence[(t, r)]
        elif (r, t) in evidence:
            d, s = evidence[(r, t)]
            d = -d
        else:
            raise ValueError(f"no evidence for the pair ({t}, {r})")
        k, v = normal_separation(
            table[f"mean_mm[{t}]"].to_numpy(),
            table[f"sd_mm[{t}]"].to_numpy(),
            table[f"mean_mm[{r}]"].to_numpy(),
            table[f"sd_mm[{r}]"].to_numpy(),
        )
        table[f"kl[{t} vs {r}]"], table[f"kl_var[{t} vs {r}]"] = k, v
        d0.append(float(d))
        se0.append(float(s))
        kl.append(k)
        var.append(v)
    d0, se0 = np.array(d0), np.array(se0)
    kl, var = np.array(kl), np.array(var)  # (hypothesis, setting)
    counts, mean_sum, se_sum, settled = allocate_jumps(
        kl, var, d0, se0, max_jumps=max_jumps, min_gain=cfg.min_gain, se_factor=cfg.se_factor
    )
    table["worst_kl"] = kl.min(axis=0)
    plan = table.loc[counts > 0, list(SETTINGS)].assign(trials=counts[counts > 0])
    plan = plan.sort_values("trials", ascending=False, kind="stable").reset_index(drop=True)
    hyp = pd.DataFrame(
        {
            "truth": [t for t, _ in pairs],
            "rival": [r for _, r in pairs],
            "elpd_diff_now": d0,
            "se_now": se0,
            "elpd_diff_expected": mean_sum,
            "se_expected": se_sum,
        }
    )
    hyp["settled"] = [
        distinguished(m, s, cfg)
        for m, s in zip(hyp["elpd_diff_expected"], hyp["se_expected"], strict=True)
    ]
    if all(distinguished(d, s, cfg) for d, s in zip(d0, se0, strict=True)):
        notes.append("the data already separate the laws: no jump needed")
    return Design(
        plan=plan,
        hypotheses=hyp,
        candidates=table.sort_values("worst_kl", ascending=False, kind="stable").reset_index(
            drop=True
        ),
        n_jumps=int(counts.sum()),
        settled=settled,
        laws=laws,
        rule={"min_gain": cfg.min_gain, "se_factor": cfg.se_factor},
        notes=tuple(notes),
    )


def _loo_evidence(saved: Mapping[str, SavedFit]) -> dict[tuple[str, str], tuple[float, float]]:
    """Paired PSIS-LOO difference of every pair of laws on their common units [nats]."""
    from . import stats

    loos = {law: stats.loo(s.datatree)["elpd_i"] for law, s in saved.items()}
    out = {}
    for t, r in itertools.combinations(saved, 2):
        d, se = stats.elpd_difference(loos[t], loos[r])
        out[(t, r)] = (float(d), float(se))
    return out


# ----------------------------------------------------------------------------------------
# from a saved diagnosis
# ----------------------------------------------------------------------------------------
def ties_of(record: Mapping) -> list[dict]:
    """The ties of a ``diagnosis.json`` document, with the two laws each compares.

    In round ``r`` the law with the first ``r`` added terms was compared with the law of
    round ``r - 1`` plus the rival term, on the same jumps.

    Parameters
    ----------
    record : mapping
        The ``diagnosis.json`` document.

    Returns
    -------
    list of dict
        Per tie: ``round``, ``selected``/``term`` (the terms), ``laws`` (the two laws'
        terms, selected first), ``elpd_diff`` and ``elpd_diff_se`` [nats].
    """
    base = tuple(record["baseline"]["terms"])
    added = tuple(record["selected"]["added"])
    out = []
    for tie in record["selected"]["indistinguishable"]:
        r = int(tie["round"])
        winner = terms_of(base + added[:r])
        rival = terms_of(base + added[: r - 1] + (tie["term"],))
        out.append({**tie, "laws": (winner, rival)})
    return out


def law_files(laws: Sequence[Sequence[str]]) -> dict[str, str]:
    """File names (under a diagnosis folder) of the posteriors of tied laws.

    Parameters
    ----------
    laws : sequence of sequence of str
        The laws, as their terms.

    Returns
    -------
    dict
        ``{"depth+drag": "laws/depth+drag.nc", ...}``.
    """
    return {"+".join(t): f"laws/{'+'.join(t)}.nc" for t in laws}


def load_tie(folder: str | Path, index: int = 0) -> tuple[dict, dict[str, SavedFit]]:
    """A diagnosis folder's tie and the saved posteriors of its two laws.

    Parameters
    ----------
    folder : str or Path
        Output folder of ``granbayes diagnose`` (``diagnosis.json``, ``laws/``).
    index : int
        Which tie (in the order of ``selected.indistinguishable``).

    Returns
    -------
    tie : dict
        As :func:`ties_of` gives it.
    fits : dict of str to SavedFit
        The two laws' fits, the selected law first.

    Raises
    ------
    ValueError
        If the diagnosis reports no tie, or the index is out of range.
    FileNotFoundError
        If a law's posterior is missing (diagnoses written before ``laws/`` existed).
    """
    folder = Path(folder)
    record = json.loads((folder / "diagnosis.json").read_text())
    ties = ties_of(record)
    if not ties:
        raise ValueError(
            f"{folder / 'diagnosis.json'}: no indistinguishable laws (the diagnosis "
            f"separated every candidate it fitted): nothing to design"
        )
    if not 0 <= index < len(ties):
        raise ValueError(f"tie {index}: the diagnosis has {len(ties)} (0..{len(ties) - 1})")
    tie = ties[index]
    fits = {}
    for law, name in law_files(tie["laws"]).items():
        path = folder / name
        if not path.exists():
            raise FileNotFoundError(
                f"{path}: the posterior of {law} is missing (rerun granbayes diagnose: "
                "diagnoses write the laws of every tie under laws/)"
            )
        fits[law] = load_fit(path)
    return tie, fits


def save_tie_laws(diagnosis: object, folder: str | Path) -> list[Path]:
    """Write the posteriors of the laws of every tie of a diagnosis under ``folder/laws/``.

    ``granbayes diagnose`` calls it, so that ``granbayes design`` can read them back
    (:func:`load_tie`).

    Parameters
    ----------
    diagnosis : granbayes.criticism.Diagnosis
        An in-memory diagnosis (its ``record`` and ``fits``).
    folder : str or Path
        The diagnosis folder.

    Returns
    -------
    list of Path
        Files written (none when the diagnosis has no tie).
    """
    from . import datatree as gdt

    folder = Path(folder)
    written = []
    for tie in ties_of(diagnosis.record.to_json()):
        for law, name in law_files(tie["laws"]).items():
            path = folder / name
            if path.exists():
                continue
            path.parent.mkdir(parents=True, exist_ok=True)
            gdt.write_datatree(diagnosis.fits[terms_of(law.split("+"))].datatree, path)
            written.append(path)
    return written


def design_from_diagnosis(
    folder: str | Path,
    *,
    tie: int = 0,
    candidates: pd.DataFrame | None = None,
    max_jumps: int = 60,
    n_draws: int = 1000,
    rng: np.random.Generator | int = 0,
) -> tuple[dict, Design]:
    """:func:`design_jumps` for a tie of a saved diagnosis (``granbayes design``).

    The evidence so far is the diagnosis's own paired difference of the two laws (the
    estimate its rule used: PSIS-LOO, moment matched, refits or K-fold) and its rule.

    Parameters
    ----------
    folder : str or Path
        Output folder of ``granbayes diagnose``.
    tie : int
        Which tie of ``selected.indistinguishable``.
    candidates : pandas.DataFrame, optional
        Settings a next jump may have (default: :func:`candidate_settings` of the
        measured jumps).
    max_jumps, n_draws, rng
        As :func:`design_jumps`.

    Returns
    -------
    tie : dict
        The tie (:func:`ties_of`).
    design : Design
    """
    record = json.loads((Path(folder) / "diagnosis.json").read_text())
    chosen, fits = load_tie(folder, tie)
    winner, rival = ("+".join(t) for t in chosen["laws"])
    rule = record["rule"]
    cfg = DiagnoseSettings(min_gain=float(rule["min_gain"]), se_factor=float(rule["se_factor"]))
    design = design_jumps(
        fits,
        evidence={(winner, rival): (chosen["elpd_diff"], chosen["elpd_diff_se"])},
        candidates=candidates,
        max_jumps=max_jumps,
        n_draws=n_draws,
        config=cfg,
        rng=rng,
    )
    return chosen, design
