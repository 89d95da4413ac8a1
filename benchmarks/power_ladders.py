"""Check of the power curves' effect-size ladders: the effect in the heights at each size.

For each kind and size of ``granbayes.calibration.POWER_SIZES``, ``--cases`` SYNTHETIC
cases drawn as the power study draws them (``make_case(kind, seed, size=, design=
POWER_DESIGN)``, seeds 0, 1, ...; the oracle of ``granbayes.testing``) and the effect's
signal-to-noise ratio in their heights before any refit (``calibration.effect_size``:
``sqrt(sum over jumps (height change / scatter)^2)``). A ladder is useful when its weakest
size sits near the noise floor (a ratio of a few) and its strongest well above what the
rule needs (the gain of the truth over the baseline in nats is about half the square of the
ratio left after the baseline's refit). No fit is run: minutes of one core.

Writes ``benchmarks/results/power_ladders.md`` (and ``.json``).

Usage: ``python benchmarks/power_ladders.py [--cases 6] [--kinds drag,...]``
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from _studies import chosen_kinds  # this folder

from granbayes import __version__
from granbayes.calibration import POWER_DESIGN, POWER_SIZES, effect_size, make_case

HERE = Path(__file__).resolve().parent


def main(argv: list[str] | None = None) -> int:
    """Tabulate the effect sizes of every ladder."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=6, help="cases per size (seeds 0, 1, ...)")
    parser.add_argument("--kinds", default=",".join(POWER_SIZES))
    parser.add_argument("--out", type=Path, default=HERE / "results" / "power_ladders")
    args = parser.parse_args(argv)
    kinds = chosen_kinds(args.kinds, list(POWER_SIZES))
    if kinds is None:
        return 2
    rows = []
    t0 = time.perf_counter()
    for kind in kinds:
        for size in POWER_SIZES[kind]:
            sizes = [
                effect_size(make_case(kind, seed, size=size, design=POWER_DESIGN))
                for seed in range(args.cases)
            ]
            snr = np.array([s["effect_snr"] for s in sizes])
            rms = np.array([s["effect_rms_mm"] for s in sizes])
            rows.append(
                {
                    "kind": kind,
                    "size": size,
                    "snr_median": float(np.median(snr)),
                    "snr_min": float(snr.min()),
                    "snr_max": float(snr.max()),
                    "rms_mm_median": float(np.median(rms)),
                }
            )
            print(f"{kind} {size:g}: SNR median {rows[-1]['snr_median']:.1f}", flush=True)
    lines = [
        "# Effect sizes of the power curves' ladders (SYNTHETIC cases)",
        "",
        f"`benchmarks/power_ladders.py --cases {args.cases}` (granbayes {__version__}, "
        f"{time.perf_counter() - t0:.0f} s): per kind and size of "
        "`granbayes.calibration.POWER_SIZES`, cases drawn as the power study draws them "
        "(`make_case(kind, seed, size=, design=POWER_DESIGN)`, seeds "
        f"0-{args.cases - 1}; heights from the oracle of `granbayes.testing`) and the "
        "effect in their heights before any refit (`effect_size`): `snr` = sqrt(sum over "
        "jumps of (height change / scatter)^2), `rms_mm` the RMS height change over cells. "
        "A depth-dependent drag's change is against the same drag without its depth "
        "dependence.",
        "",
        "| kind | size | SNR median | SNR min | SNR max | RMS change median [mm] |",
        "|---|---:|---:|---:|---:|---:|",
        *(
            f"| {r['kind']} | {r['size']:g} | {r['snr_median']:.1f} | {r['snr_min']:.1f} | "
            f"{r['snr_max']:.1f} | {r['rms_mm_median']:.2f} |"
            for r in rows
        ),
    ]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=2) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
