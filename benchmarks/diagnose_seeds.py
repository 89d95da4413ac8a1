"""Study: does ``diagnose``'s verdict on the SYNTHETIC reference data depend on the seed?

Diagnoses ``granbayes/data/reference`` with seeds 0 .. N-1 as a Dask campaign
(``granbayes.calibration.diagnose_folder``) and records per seed the verdict, the added
terms, the gain, convergence, reruns, the candidates screened out and the smallest ELPD gain
of a fitted candidate over its nested parent (a value far below zero would be a sampling
failure: an extension cannot honestly be worse than the law it contains). Writes
``benchmarks/results/diagnose_seeds.csv`` and ``.md``.

Usage: ``python benchmarks/diagnose_seeds.py [--seeds 5] [--workers 2] [--out DIR] [--resume]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from granbayes._synthetic import REFERENCE_DATA
from granbayes.calibration import diagnose_folder
from granbayes.campaign import ClusterSettings, Task, run_campaign
from granbayes.report import markdown_table

HERE = Path(__file__).resolve().parent


def main(argv: list[str] | None = None) -> int:
    """Run (or resume) the study and write its table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("diagnose-seeds"))
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args(argv)
    tasks = [
        Task(f"seed-{s}", diagnose_folder, (str(REFERENCE_DATA),), seed=s)
        for s in range(args.seeds)
    ]
    res = run_campaign(
        tasks,
        args.out,
        description={"kind": "diagnose seeds", "data": "granbayes/data/reference"},
        cluster=ClusterSettings(n_workers=args.workers),
        resume=args.resume,
        log=lambda m: print(m, file=sys.stderr),
    )
    table = res.results.sort_values("seed")
    (HERE / "results").mkdir(exist_ok=True)
    table.to_csv(HERE / "results" / "diagnose_seeds.csv", index=False)
    shown = table.drop(columns=["candidates"])
    same = table["verdict"].nunique() == 1 and table["added"].nunique() == 1
    same_claim = table["verdict"].nunique() == 1 and table["claim"].nunique() == 1
    lines = [
        "# `diagnose` on the SYNTHETIC reference data with different seeds",
        "",
        f"{len(table)} seeds, {args.workers} Dask workers; truth: depth + drag + compaction "
        "(granbayes/data/reference/TRUTH.md). `min_gain_vs_parent`: the smallest ELPD gain "
        "of a fitted candidate over the law it extends [nats] (every candidate's gains: "
        "`diagnose_seeds.csv`).",
        "",
        markdown_table(shown, ".3g"),
        "",
        f"Same verdict and terms for every seed: {same}. Same claim (each round's added "
        f"term with the terms it is not distinguished from, `claim`): {same_claim}.",
    ]
    (HERE / "results" / "diagnose_seeds.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0 if res.n_failed == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
