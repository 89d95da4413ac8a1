"""The machine a benchmark ran on, as its JSON results record it and its report shows it.

One place for what every timing benchmark of this folder writes about its machine
(``bench_simulator.py``, ``bench_frames.py``, ``bench_batch.py``): the CPU model and count
come from :func:`granbayes._provenance.machine` (the package's own record of a machine),
the versions of the packages the benchmark exercises from their ``__version__``.
"""

from __future__ import annotations

import datetime
import importlib
import os
import platform

import numba

import granbayes
from granbayes._provenance import machine


def machine_info(packages: tuple[str, ...] = ("numpy", "numba", "scipy")) -> dict:
    """Platform, CPU, thread counts, package versions and date of the run.

    Parameters
    ----------
    packages : tuple of str
        Packages whose versions to record (besides Python and granbayes).

    Returns
    -------
    dict
        JSON-ready: ``platform``, ``cpu``, ``cpu_count``, ``cpus_available`` (this
        process's affinity), ``numba_threads``, ``python``, one key per package,
        ``granbayes`` and ``date`` (UTC).
    """
    here = machine()
    info: dict[str, object] = {
        "platform": here["platform"],
        "cpu": here["cpu"],
        "cpu_count": here["cpu_count"],
        "cpus_available": len(os.sched_getaffinity(0))
        if hasattr(os, "sched_getaffinity")
        else None,
        "numba_threads": numba.config.NUMBA_NUM_THREADS,
        "python": platform.python_version(),
    }
    for name in packages:
        info[name] = importlib.import_module(name).__version__
    info["granbayes"] = granbayes.__version__
    info["date"] = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return info


def machine_markdown(info: dict) -> list[str]:
    """The report's "Machine" section of :func:`machine_info`'s record, as lines."""
    return ["## Machine", "", *(f"- {key}: {value}" for key, value in info.items())]
