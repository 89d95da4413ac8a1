"""What a result was computed with: package versions and the machine (private).

Fits, diagnoses, calibrations and analyses store :func:`environment` with their results,
so a number can be traced to the software and the hardware that produced it. Two results
are bit-identical only when their :func:`reproducibility_key` agree (same seed and data as
well); elsewhere they agree within Monte Carlo error (README, "Reproducibility"):

* the package versions: a new numpy, scipy, numba or llvmlite can change the last bits of
  a computation, and an MCMC chain amplifies one changed bit into a different (equally
  valid) chain;
* the machine: numba compiles the simulator for the CPU it runs on (``host`` target: its
  instruction set, e.g. AVX-512 and FMA, decides which instructions LLVM emits), numpy
  dispatches its vectorised loops on the CPU features found at run time, and the C
  library's maths functions differ between versions.

Nothing here reads or records a path, a user name or a host name.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import platform

__all__ = ["PACKAGES", "environment", "machine", "package_versions", "reproducibility_key"]

#: Distributions whose versions are recorded (the numerical stack and the result formats).
PACKAGES = (
    "granbayes",
    "numpy",
    "scipy",
    "numba",
    "llvmlite",
    "emcee",
    "pandas",
    "xarray",
    "arviz",
    "arviz-base",
    "arviz-stats",
    "h5py",
    "h5netcdf",
)

#: CPU features that decide the instructions numba and numpy use for floating point.
_SIMD_FEATURES = (
    "sse2",
    "sse4.1",
    "sse4.2",
    "avx",
    "avx2",
    "fma",
    "avx512f",
    "avx512dq",
    "avx512vl",
    "avx512bw",
    "neon",
    "sve",
)


def package_versions() -> dict[str, str]:
    """Python and the installed version of every distribution of :data:`PACKAGES`.

    Returns
    -------
    dict of str to str
        Distribution name to version (``"not installed"`` where it is missing).
    """
    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def _cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, else :func:`platform.processor`)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.lower().startswith(("model name", "hardware", "cpu model")):
                    return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _numba_target() -> dict[str, object]:
    """The CPU numba compiles for: its name and the SIMD features enabled."""
    try:
        import llvmlite.binding as llvm
        from numba.core import config

        name = config.CPU_NAME or llvm.get_host_cpu_name()
        features = config.CPU_FEATURES
        if features is None:
            features = llvm.get_host_cpu_features().flatten()
    except Exception as exc:  # numba missing or broken: say so, never fail a result
        return {"cpu_name": f"unavailable ({type(exc).__name__})"}
    enabled = {f[1:] for f in features.split(",") if f.startswith("+")}
    return {
        "cpu_name": name,
        "simd": [f for f in _SIMD_FEATURES if f in enabled],
        "features_sha256": hashlib.sha256(features.encode()).hexdigest()[:16],
        "threads": int(config.NUMBA_NUM_THREADS),
    }


def _numpy_simd() -> list[str]:
    """The SIMD targets numpy found on this CPU (its run-time dispatch)."""
    try:
        from numpy._core._multiarray_umath import __cpu_features__ as found
    except ImportError:  # numpy < 2
        try:
            from numpy.core._multiarray_umath import __cpu_features__ as found
        except ImportError:
            return []
    return sorted(name for name, ok in found.items() if ok)


def machine() -> dict[str, object]:
    """The machine: platform, CPU model and count, numba's target, numpy's SIMD, libc.

    Returns
    -------
    dict
        JSON-ready: ``platform``, ``machine`` (architecture), ``cpu``, ``cpu_count``,
        ``libc``, ``numba_target`` (``cpu_name``, ``simd``, ``features_sha256``,
        ``threads``) and ``numpy_simd``.
    """
    libc, libc_version = platform.libc_ver()
    return {
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "libc": f"{libc} {libc_version}".strip() or "unknown",
        "numba_target": _numba_target(),
        "numpy_simd": _numpy_simd(),
    }


def environment() -> dict[str, dict]:
    """``{"versions": package_versions(), "machine": machine()}``."""
    return {"versions": package_versions(), "machine": machine()}


def reproducibility_key(env: dict | None = None) -> str:
    """A short hash of what bit-identical results require to be the same.

    The package versions, the architecture, the C library, numba's target CPU and features
    and numpy's SIMD targets. Not the thread count (each jump is simulated by one thread;
    results do not depend on it) nor the CPU's marketing name or the OS kernel.

    Parameters
    ----------
    env : dict, optional
        An :func:`environment` record (default: this process's).

    Returns
    -------
    str
        16 hexadecimal digits.
    """
    env = environment() if env is None else env
    m = env["machine"]
    target = {k: v for k, v in m["numba_target"].items() if k != "threads"}
    key = {
        "versions": env["versions"],
        "machine": m["machine"],
        "libc": m["libc"],
        "numba_target": target,
        "numpy_simd": m["numpy_simd"],
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
