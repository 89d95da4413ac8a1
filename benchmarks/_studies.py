"""What the Dask studies of ``benchmarks/`` share: their campaign options and the summary
of a study stopped part-way (``calibrate_verdicts.py``, ``power_curves.py``)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from granbayes.campaign import (
    CampaignError,
    CampaignResult,
    ClusterSettings,
    Task,
    finished_tasks,
    run_campaign,
)


def add_campaign_options(parser: argparse.ArgumentParser, out: Path, kinds: Sequence[str]) -> None:
    """``--out``, ``--kinds``, ``--workers``, ``--scheduler``, ``--resume`` and
    ``--summarize-only``, the same in every study."""
    parser.add_argument("--out", type=Path, default=out)
    parser.add_argument("--kinds", default=",".join(kinds), help="kinds to run")
    parser.add_argument("--workers", type=int, help="local Dask workers (default: cores)")
    parser.add_argument("--scheduler", help="address of an existing Dask scheduler")
    parser.add_argument("--resume", action="store_true", help="continue a killed study")
    parser.add_argument(
        "--summarize-only",
        action="store_true",
        help="write the summary of the cases finished so far (a stopped study) and exit",
    )


def run_study(
    tasks: Sequence[Task], args: argparse.Namespace, description: Mapping[str, Any]
) -> CampaignResult:
    """Run (or, with ``--resume``, continue) a study's campaign as its options say
    (:func:`add_campaign_options`), its log on stderr."""
    return run_campaign(
        tasks,
        args.out,
        description=description,
        cluster=ClusterSettings(scheduler_address=args.scheduler, n_workers=args.workers),
        resume=args.resume,
        log=lambda m: print(m, file=sys.stderr),
    )


def chosen_kinds(text: str, known: Sequence[str]) -> list[str] | None:
    """The kinds of ``--kinds``; None (and a message) if one is unknown."""
    kinds = [k.strip() for k in text.split(",") if k.strip()]
    unknown = sorted(set(kinds) - set(known))
    if unknown:
        print(f"error: --kinds: unknown {unknown}; expected {', '.join(known)}")
        return None
    return kinds


def summarize_finished(out: Path, write_summary: Callable[[pd.DataFrame], None]) -> int:
    """Summarise the cases a stopped study finished (its task files): ``results.csv`` and
    whatever ``write_summary(results)`` writes into ``out``; the exit status."""
    try:
        _, results = finished_tasks(out)
    except CampaignError as err:
        print(f"error: {err}")
        return 1
    if results.empty:
        print(f"error: no finished case in {out}")
        return 1
    out.mkdir(parents=True, exist_ok=True)
    results.to_csv(out / "results.csv", index=False)
    write_summary(results)
    print((out / "summary.md").read_text())
    return 0
