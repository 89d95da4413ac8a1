"""Calibration study of ``diagnose``'s selection rule: false discoveries, power, unknown physics.

Runs :func:`granbayes.calibration.diagnose_case` on SYNTHETIC data sets (robot, noise,
design and effect size drawn per case; ``granbayes.calibration`` documents the ranges) as a
Dask campaign (``granbayes.campaign``): by default 60 null cases (none of 60 naming a term
bounds the false-discovery rate below 5% at one-sided 95% confidence; 40 cannot), 10 per
library term and 10 per out-of-library force of the oracle (``STUDY_KINDS``), each
diagnosed with two sampler seeds (the verdict's flip rate under Monte Carlo noise). Each
finished case is written at once, so the study runs in parts: rerun with ``--resume`` and
only the missing cases are computed.

Writes into OUT (default ``docs/verdicts``):

- ``results.csv``: one row per case (truth summary, verdict, gains, misfit statistics);
- ``summary.md`` / ``summary.json``: error rates per kind with binomial standard errors,
  the false-discovery rate, the power per term and the out-of-library outcomes, the
  threshold sweep (round-1 decisions rederived without refitting), the cost per case;
- ``rates.png``: the rates with their error bars.

Usage::

    python benchmarks/calibrate_verdicts.py [--out DIR] [--seed S] [--null N] [--per-term N]
        [--kinds null,drag,...] [--sampler-seeds 2] [--workers N | --scheduler ADDRESS]
        [--resume]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import numpy as np
import pandas as pd
from _studies import (  # this folder
    add_campaign_options,
    chosen_kinds,
    run_study,
    summarize_finished,
)
from matplotlib.figure import Figure

from granbayes import __version__
from granbayes._criticism import DiagnoseSettings
from granbayes.calibration import (
    CASE_KINDS,
    DESIGN_RANGES,
    FALSE_CLAIM,
    LIBRARY_EFFECTS,
    OUT_OF_LIBRARY,
    OUTCOMES,
    PHYSICAL_EFFECTS,
    STEP_BUDGET,
    clopper_pearson,
    compare_studies,
    diagnose_case,
    flip_rates,
    named_terms,
    outcome,
    primary_rows,
    rederive_verdicts,
    summarize,
)
from granbayes.campaign import Task, spawn_seeds
from granbayes.report import markdown_table

ROOT = Path(__file__).resolve().parents[1]
#: The seed of the study in ``docs/verdicts`` (its cases), so that the command without
#: ``--seed`` reruns it. The rule's thresholds were chosen on the cases of 20261123 (the
#: studies of 80ecd1b and 160a653): a study on that seed measures the rule where it was tuned.
SEED = 20261130
#: The kinds of the study by default: null, the library terms and the out-of-library
#: effects that are forces of the oracle. The two that rescale k per cell
#: (``pause_stiffening``, ``rate_stiffening``; each cell alone a depth-only law) stay
#: available with ``--kinds``; the study of 80ecd1b ran them.
STUDY_KINDS = ("null", *LIBRARY_EFFECTS, *PHYSICAL_EFFECTS)
#: Threshold grid of the sweep: (min_gain, se_factor, strong_gain, family_alpha). The study
#: runs diagnose as shipped, screening included, so min_gain starts at the screening bar
#: (4 nats: a candidate whose best in-sample gain is below it has no ELPD to rederive).
SWEEP = [
    (mg, sf, sg, fa)
    for mg in (4.0, 6.0, 8.0)
    for sf in (2.0, 3.0)
    for sg in (10.0, 20.0)
    for fa in (0.01, 0.05)
]


def tasks(
    kinds: list[str], n_null: int, n_per_term: int, seed: int, sampler_seeds: int = 2
) -> list[Task]:
    """The study's tasks: seeds spawned per kind, so adding cases never changes others.

    The kinds are interleaved (case 0 of every kind, then case 1, ...), so a study stopped
    part-way has every kind covered about equally. Each case is diagnosed with
    ``sampler_seeds`` sampler seeds (task ``<kind>-<i>`` with the case's own, then
    ``<kind>-<i>-s<r>``: the same data, sampler replicate ``r``), right after one another.
    """
    per_kind = []
    for kind_index, kind in enumerate(CASE_KINDS):
        if kind not in kinds:
            continue
        n = n_null if kind == "null" else n_per_term
        seeds = spawn_seeds(seed + 1000 * kind_index, n)
        per_kind.append(
            [
                [
                    Task(
                        f"{kind}-{i:03d}" + (f"-s{r}" if r else ""),
                        diagnose_case,
                        (kind, i),
                        {"sampler_replicate": r} if r else {},
                        seed=s,
                    )
                    for r in range(sampler_seeds)
                ]
                for i, s in enumerate(seeds)
            ]
        )
    longest = max((len(t) for t in per_kind), default=0)
    return [task for i in range(longest) for t in per_kind if i < len(t) for task in t[i]]


def sweep(results: pd.DataFrame) -> pd.DataFrame:
    """False-discovery rate and power of the round-1 decision over the threshold grid."""
    rows = []
    null = results["kind"] == "null"
    lib = results["kind"].isin(LIBRARY_EFFECTS)
    for mg, sf, sg, fa in SWEEP:
        added = rederive_verdicts(
            results, min_gain=mg, se_factor=sf, strong_gain=sg, family_alpha=fa
        )
        fdr = float((added[null] != "").mean()) if null.any() else np.nan
        power = float((added[lib] == results.loc[lib, "kind"]).mean()) if lib.any() else np.nan
        rows.append(
            {
                "min_gain": mg,
                "se_factor": sf,
                "strong_gain": sg,
                "family_alpha": fa,
                "false_term_rate_null": fdr,
                "power_round1": power,
            }
        )
    return pd.DataFrame(rows)


def gain_honesty(results: pd.DataFrame) -> pd.DataFrame | None:
    """The reported gain against the gain on a new run of the same experiment.

    Over the cases where a term was added: the selected law's ELPD gain over the baseline
    as ``diagnose`` reports it (PSIS-LOO over jumps, and leaving out one cell at a time),
    both computed on the data used for selection, against the log predictive density
    gain the two fitted laws achieve on an independent repetition of the experiment
    (same truth and design, new noise: ``gain_fresh``), which no selection has seen.
    """
    ext = results[(results["verdict"] != "over_budget") & (results["added"].fillna("") != "")]
    if ext.empty or "gain_fresh" not in ext:
        return None
    g, gc, gf = (ext[c].astype(float) for c in ("elpd_gain", "elpd_gain_cells", "gain_fresh"))
    rows = []
    for label, est in (("PSIS-LOO over jumps", g), ("leave one cell out", gc)):
        rows.append(
            {
                "estimate": label,
                "n": len(ext),
                "median_estimate_nats": float(est.median()),
                "median_fresh_nats": float(gf.median()),
                "median_estimate_minus_fresh": float((est - gf).median()),
                "mean_estimate_minus_fresh": float((est - gf).mean()),
                "se_of_mean": float((est - gf).std(ddof=1) / np.sqrt(len(ext))),
                "fraction_estimate_above_fresh": float((est > gf).mean()),
            }
        )
    rows.append(
        {
            "estimate": "fresh data, gain > 0",
            "n": len(ext),
            "median_estimate_nats": float(gf.median()),
            "median_fresh_nats": float(gf.median()),
            "median_estimate_minus_fresh": 0.0,
            "mean_estimate_minus_fresh": 0.0,
            "se_of_mean": 0.0,
            "fraction_estimate_above_fresh": float((gf > 0).mean()),
        }
    )
    return pd.DataFrame(rows)


#: The colour of each outcome (``granbayes.calibration.OUTCOMES``, stacked in that order).
COLOURS = dict(
    zip(
        OUTCOMES,
        ("tab:green", "yellowgreen", "lightgrey", "tab:orange", "tab:red", "tab:purple", "black"),
        strict=True,
    )
)


def figure(results: pd.DataFrame, summary: pd.DataFrame, stopped: str = "") -> Figure:
    """Outcomes per case kind (stacked fractions) with the right-answer rate's 95% interval.

    ``stopped``: a line for the title of a study stopped part-way (how many cases).
    """
    fig = Figure(figsize=(9.0, 4.4), layout="constrained")
    ax = fig.subplots()
    kinds = list(summary["kind"])
    labels = results.apply(outcome, axis=1)
    x = np.arange(len(kinds))
    bottom = np.zeros(len(kinds))
    for name, colour in COLOURS.items():
        frac = np.array([float((labels[results["kind"] == k] == name).mean()) for k in kinds])
        if not frac.any():
            continue
        ax.bar(x, frac, bottom=bottom, color=colour, label=name, edgecolor="white", lw=0.5)
        bottom += frac
    err = np.vstack(
        [summary["right"] - summary["right_lo95"], summary["right_hi95"] - summary["right"]]
    )
    ax.errorbar(
        x, summary["right"], yerr=err, fmt="_", color="k", capsize=3, label="right: exact 95% CI"
    )
    n = dict(zip(summary["kind"], summary["n"], strict=True))
    ax.set_xticks(
        x,
        [f"{k} (n={n[k]})" for k in kinds],
        rotation=40,
        ha="right",
        rotation_mode="anchor",
        fontsize=8,
    )
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("fraction of cases")
    ax.set_title(
        "SYNTHETIC data (granbayes.calibration, benchmarks/calibrate_verdicts.py):\n"
        "what diagnose concluded, by hidden truth. Right: null -> baseline_adequate;\n"
        "library term -> extended with that term; outside the library -> misfit_remains\n"
        "or a law as good as the truth on a fresh replicate" + (f"\n{stopped}" if stopped else ""),
        fontsize=8,
        loc="left",
    )
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return fig


def _omnibus_level(results: pd.DataFrame) -> float | None:
    """The omnibus lack-of-fit test's level the rows were diagnosed with (None: rows made
    before the test entered the rule, or with it reported only)."""
    if "lack_of_fit_alpha" not in results:
        return None
    levels = results["lack_of_fit_alpha"].dropna().unique()
    return float(levels[0]) if len(levels) == 1 else None


def write_summary(
    out: Path,
    results: pd.DataFrame,
    config: DiagnoseSettings,
    seed: int,
    n_planned: int | None = None,
    against: Path | None = None,
) -> None:
    """summary.md, summary.json, rates.png from the tidy results.

    The rates are those of each case's first diagnosis (sampler replicate 0); the other
    replicates give the flip rate. ``against``: the ``results.csv`` of an earlier run of
    the study (same seed), compared case by case.
    """
    flips, flipped = flip_rates(results)
    if against is not None:
        # only empty cells are missing: pandas would read the kind "null" as NaN
        earlier = pd.read_csv(against, keep_default_na=False, na_values=[""])
        changes, changed = compare_studies(earlier, results)
    else:
        changes = changed = None
    results = primary_rows(results).copy()
    results["added"] = results["added"].fillna("")
    stopped = bool(n_planned and n_planned > len(results))
    summary = summarize(results)
    named, tied = named_terms(results)
    swept = sweep(results)
    null = summary[summary["kind"] == "null"]
    null_rows = results[results["kind"] == "null"]
    n_null = len(null_rows)
    # one-sided 95% upper bounds = upper limits of the two-sided 90% exact intervals
    fdr_upper = (
        clopper_pearson(int((null_rows["added"] != "").sum()), n_null, 0.90)[1] if n_null else None
    )
    alarm_upper = (
        clopper_pearson(int((null_rows["verdict"] != "baseline_adequate").sum()), n_null, 0.90)[1]
        if n_null
        else None
    )
    gains = gain_honesty(results)
    lib_rows = results[results["kind"].isin(LIBRARY_EFFECTS)]
    lib_false = int((lib_rows.apply(outcome, axis=1) == FALSE_CLAIM).sum()) if len(lib_rows) else 0
    lib_false_upper = clopper_pearson(lib_false, len(lib_rows), 0.90)[1] if len(lib_rows) else None
    doc = {
        "seed": seed,
        "granbayes": __version__,
        "rule": {
            "min_gain": config.min_gain,
            "se_factor": config.se_factor,
            "strong_gain": config.strong_gain,
            "family_alpha": config.family_alpha,
        },
        "n_cases": len(results),
        "n_planned": n_planned or len(results),
        # a discovery is a named term; a false alarm is any verdict but baseline_adequate
        "false_discovery_rate": None if null.empty else float(null["wrong_term"].iloc[0]),
        "false_alarm_rate": None if null.empty else 1.0 - float(null["right"].iloc[0]),
        "false_discovery_upper95": fdr_upper,
        "false_alarm_upper95": alarm_upper,
        "false_claims_library_terms": lib_false,
        "n_library_term_cases": len(lib_rows),
        "false_claim_library_upper95": lib_false_upper,
        "gain_reported_vs_fresh": None if gains is None else gains.to_dict("records"),
        "n_over_budget": int((results["verdict"] == "over_budget").sum()),
        "step_budget": STEP_BUDGET,
        "per_kind": summary.to_dict("records"),
        "sweep": swept.to_dict("records"),
        "median_time_per_case_s": float(results["wall_time_s"].median()),
        "named_terms": named.to_dict("records"),
        "tied_terms": tied.to_dict("records"),
        "flip_rates": flips.to_dict("records"),
        "flipped": flipped.to_dict("records"),
    }
    if changes is not None:
        doc["against"] = str(against)
        doc["changes_against"] = changes.to_dict("records")
        doc["changed_against"] = changed.to_dict("records")
    (out / "summary.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    fmt = summary.copy()
    for c in fmt.columns:
        if c not in ("kind", "n"):
            fmt[c] = fmt[c].map(lambda v: f"{v:.2f}")
    lines = [
        "# Error rates of diagnose's verdicts (SYNTHETIC data)",
        "",
        f"Generated by `benchmarks/calibrate_verdicts.py` (seed {seed}) with "
        f"`granbayes.calibration`; {len(results)} cases"
        + (
            f" (**a stopped study: {len(results)} of the {n_planned} planned cases "
            "finished; read the rates as a pilot, with their standard errors**)"
            if stopped
            else ""
        )
        + ". Rule: gain > "
        f"{config.min_gain:g} nats and > {config.se_factor:g} SE, misfit present (family-wise "
        f"alpha {config.family_alpha:g} over the cells"
        + (
            f", or the omnibus lack-of-fit test at {omnibus:g}"
            if (omnibus := _omnibus_level(results)) is not None
            else ""
        )
        + f") or gain > {config.strong_gain:g} nats.",
        "",
        markdown_table(fmt),
        "",
        "`right`: null -> baseline_adequate; a library term -> extended with exactly that "
        "term; out-of-library -> misfit_remains or an extended law that predicts a fresh "
        "replicate as well as the truth, within the rule's margin (in rows made before that "
        "check, study version 2: a law that leaves no misfit cell). "
        "`right_se`: binomial standard error; `right_lo95`, `right_hi95`: exact "
        "(Clopper-Pearson) 95% interval. `right_alone`: right, and no other term reported as "
        "indistinguishable from the named one. `ambiguous`: a term was reported as "
        "indistinguishable from an added one (`diagnosis.json` "
        "`selected.indistinguishable`). `wrong_term`: a term named that is not the truth "
        "(for null: a false discovery). `false_claim`: a wrong term named without the truth "
        "reported as indistinguishable from it; `false_claim_hi95`: its one-sided 95% "
        "upper bound, each kind on its own. `over_budget`: stopped after "
        f"{STEP_BUDGET:,} sampler steps without a verdict (counted as not right).",
        "",
        f"False-discovery rate (a term named on null data): {doc['false_discovery_rate']:.3f}, "
        f"one-sided 95% upper bound {fdr_upper:.3f}; false-alarm rate (any verdict but "
        f"baseline_adequate): {doc['false_alarm_rate']:.3f}, upper bound {alarm_upper:.3f} "
        f"({n_null} null cases)."
        if n_null
        else "No null case finished.",
        "",
        f"False claims with a library term hidden (a wrong term named, the truth not reported "
        f"as indistinguishable): {lib_false} of {len(lib_rows)}, one-sided 95% upper bound "
        f"{lib_false_upper:.3f}."
        if len(lib_rows)
        else "",
        "",
        "## Which terms were named, by truth",
        "",
        "Per kind of truth, the cases whose diagnosis added each library term (in any "
        "round), then those that reported it as not distinguished from an added term: "
        "the confusions and ties behind `wrong_term`, `ambiguous` and each kind's own "
        "`false_claim` bound (`false_claim_hi95`, one-sided 95%) above.",
        "",
        "Named (added to the law):",
        "",
        markdown_table(named),
        "",
        "Reported as not distinguished from an added term:",
        "",
        markdown_table(tied),
        "",
        "## Honest gain: the reported gain against fresh data",
        "",
        "Over the cases where a term was added: the selected law's ELPD gain over the "
        "baseline as diagnose reports it, estimated on the data used for selection (PSIS-LOO "
        "over jumps; leaving out one cell, a command at one setting, at a time), against "
        "the log predictive density gain of the same two fitted laws on an independent "
        "repetition of the experiment (same truth and design, new noise), which the "
        "selection never saw. A positive `estimate_minus_fresh` is optimism [nats].",
        "",
        markdown_table(gains, ".3g")
        if gains is not None
        else "No case added a term (or the results predate the fresh-data score).",
        "",
        "## Monte Carlo sensitivity: the same data, another sampler seed",
        "",
        "Each case diagnosed again with another sampler seed (`sampler_replicate` > 0). "
        "A pair flips when the verdict or the claim differs (the terms named, each with the "
        "terms reported as not distinguished from it); `outcome_flips`: right in one run "
        "and not in the other. `flip_lo`, `flip_hi`: exact (Clopper-Pearson) 95% interval "
        "of the flip rate (target <= 5%).",
        "",
        markdown_table(flips, ".3g") if len(flips) else "No case has a second diagnosis yet.",
        "",
        *(
            [
                "Where the flips happen (per run, `_0` the first and `_r` the replicate: the "
                "reported gain, the best round-1 candidate's gain against the rule's 4 nats "
                "and 2 SE, the baseline's largest misfit |z| and what the selected law "
                "leaves, against `z_threshold`):",
                "",
                markdown_table(flipped, ".3g"),
                "",
            ]
            if len(flipped)
            else []
        ),
        *(
            [
                f"## Against an earlier run of the study (`{against}`)",
                "",
                "The same cases (same seed: the same drawn truths and designs) in both runs, "
                "each case's first diagnosis. A change is another verdict or other terms "
                "named (ties are not compared: earlier rows may hold every round's ties "
                "together). `right_before`, `right_after`: right answers (alone or tied) "
                "in each run; `change_lo`, `change_hi`: exact 95% interval.",
                "",
                markdown_table(changes, ".3g"),
                "",
                markdown_table(changed, ".3g") if len(changed) else "No case changed.",
                "",
            ]
            if changes is not None
            else []
        ),
        "## Threshold sweep (round 1 rederived from the recorded candidates, no refits)",
        "",
        markdown_table(swept, ".3g"),
        "",
        "![rates](rates.png)",
    ]
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    note = f"A STOPPED STUDY: {len(results)} of the {n_planned} planned cases (a pilot)"
    figure(results, summary, note if stopped else "").savefig(out / "rates.png", dpi=130)


def main(argv: list[str] | None = None) -> int:
    """Run (or resume) the study and write its results."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_campaign_options(parser, ROOT / "docs" / "verdicts", STUDY_KINDS)
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--null", type=int, default=60, help="null cases (default 60)")
    parser.add_argument("--per-term", type=int, default=10, help="cases per effect (10)")
    parser.add_argument(
        "--against",
        type=Path,
        help="results.csv of an earlier run of the study: what changed, case by case",
    )
    parser.add_argument(
        "--sampler-seeds",
        type=int,
        default=2,
        help="diagnoses of each case with different sampler seeds (default 2: the flip rate)",
    )
    args = parser.parse_args(argv)
    kinds = chosen_kinds(args.kinds, CASE_KINDS)
    if kinds is None:
        return 2
    config = DiagnoseSettings()
    if args.sampler_seeds < 1:
        print("error: --sampler-seeds must be at least 1")
        return 2
    todo = tasks(kinds, args.null, args.per_term, args.seed, args.sampler_seeds)
    if args.summarize_only:
        n_cases = sum(1 for t in todo if not t.kwargs)  # the first diagnosis of each case
        return summarize_finished(
            args.out,
            lambda results: write_summary(
                args.out, results, config, args.seed, n_cases, args.against
            ),
        )
    description = {
        "kind": "granbayes.calibration",
        "seed": args.seed,
        "rule": [config.min_gain, config.se_factor, config.strong_gain, config.family_alpha],
        # version 2: indistinguishable terms reported, the gain scored on fresh data;
        # version 3: data from the independent oracle, out-of-library physics as ground
        # forces, out-of-library laws judged on a fresh replicate against the truth
        "study_version": 3,
        "out_of_library": list(OUT_OF_LIBRARY),
        "design": DESIGN_RANGES,
    }
    result = run_study(todo, args, description)
    ok = result.results
    write_summary(result.folder, ok, config, args.seed, against=args.against)
    print((result.folder / "summary.md").read_text())
    return 0 if result.n_failed == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
