"""Shared test configuration.

Hypothesis runs with ``deadline=None`` (the first call of the compiled integrator triggers a
numba compilation that takes seconds) and ``derandomize=True`` (every run draws the same
examples, so a failure is reproducible in CI and locally), with 25 examples per property to
keep the suite fast. ``HYPOTHESIS_PROFILE=thorough`` draws 500 fresh random examples per
property for a deeper local search.

Plain NumPy random draws in tests come from the ``rng`` fixture: a generator seeded with
:data:`RNG_SEED`, fresh for every test, so each test draws the same numbers whatever else
runs (in any order, on any pytest-xdist worker). SYNTHETIC jump tables come from the test
kit, :func:`granbayes.testing.synthetic_jumps` (seeded by its ``seed`` argument).

The shared contracts (``shared/`` beside the repository)
--------------------------------------------------------
No test needs ``shared/`` to check the package: the converged reference heights are read
from the repository's own copy ``tests/data/reference-heights.csv``, and the contract
texts are the first parts of ``docs/data-format.md`` and ``docs/physics-model.md``. Only
the checks that these copies equal the contracts read ``shared/``, through the
``shared_file`` fixture, which decides:

* ``shared/`` is beside the repository (as in CI): the file must be there; a missing one
  fails the test, naming the path.
* The environment variable ``GRANBAYES_SHARED`` names the folder: the same, in that
  folder (a wrong path fails, it does not skip).
* Neither (a clone on its own): the copy checks are skipped, with the reason naming the
  folder looked for (``-ra``, the default, lists it in the summary). The tests of the
  package itself still run, on the repository's copies.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

settings.register_profile(
    "granbayes", deadline=None, derandomize=True, database=None, max_examples=25
)
settings.register_profile("thorough", deadline=None, max_examples=500, database=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "granbayes"))

#: Seed of the ``rng`` fixture (the date of the energy-identity fix, 2026-11-23; any fixed
#: value would do: what matters is that it never changes silently).
RNG_SEED = 20261123


@pytest.fixture
def rng() -> np.random.Generator:
    """A NumPy random generator seeded with :data:`RNG_SEED`, fresh for every test."""
    return np.random.default_rng(RNG_SEED)


#: Where the shared contracts sit when ``GRANBAYES_SHARED`` is not set: beside the repository.
SHARED_BESIDE = Path(__file__).resolve().parents[2] / "shared"


@pytest.fixture(scope="session")
def shared_file() -> Callable[[str], Path]:
    """``shared_file(name)``: the path of ``name`` in the shared contracts (policy: module
    docstring). Fails if the folder is there (or named by ``GRANBAYES_SHARED``) but the
    file is not; skips, saying why, only where no shared folder is beside the repository."""
    named = os.environ.get("GRANBAYES_SHARED")
    folder = Path(named) if named else SHARED_BESIDE

    def find(name: str) -> Path:
        path = folder / name
        if path.is_file():
            return path
        if named or folder.is_dir():
            source = f"GRANBAYES_SHARED={named}" if named else "shared/ beside the repository"
            pytest.fail(f"shared contract {path} is missing ({source})", pytrace=False)
        pytest.skip(
            f"no shared contracts at {folder} (a clone on its own; set GRANBAYES_SHARED to "
            "check against them): the repository's own copies are used"
        )

    return find


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the longest tests first: the hidden-effect cases of ``ci_subset`` (a diagnosis
    each, ~40-60 s), then the fast tests marked ``long`` (> ~10 s), then the rest in file
    order. pytest-xdist hands the tests out one at a time in this order, so the two workers
    end together instead of one running a minute-long test while the other idles (longest
    first is the classic greedy rule for two machines). A stable sort: within each class
    the file order, and so the sharing of module fixtures, is kept.

    With ``--dist loadgroup`` (``make test``) xdist puts groups of several tests before
    single ones (the installed-wheel tests, ~15 s, are one group). The kernels are
    compiled before the workers start (:func:`pytest_sessionstart`)."""

    def rank(item: pytest.Item) -> int:
        if item.get_closest_marker("ci_subset"):
            return 0
        return 1 if item.get_closest_marker("long") else 2

    items.sort(key=rank)


def pytest_sessionstart(session: pytest.Session) -> None:
    """Under pytest-xdist, compile the numba kernels into numba's cache before the workers
    start, the heights and the frames parts side by side (tests/compile_kernels.py).

    Each kernel specialization takes 10-35 s to compile on a fresh clone, and numba's
    cache is shared through the files only: two workers whose first tests need the same
    specialization each compile it, and did (a fresh-clone run on a slow machine spent
    ~150 s of its workers' time compiling, about twice the compilation itself). Runs in
    the controlling process (this hook precedes pytest-xdist's, which starts the
    workers); with a warm cache it only loads (~3 s). A part that fails is reported and
    left to the tests, which then compile (and fail) on their own."""
    config = session.config
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    import subprocess
    import sys

    script = Path(__file__).with_name("compile_kernels.py")
    parts = {
        part: subprocess.Popen(
            [sys.executable, str(script), part], stdout=subprocess.PIPE, stderr=subprocess.STDOUT
        )
        for part in ("heights", "frames")
    }
    for part, proc in parts.items():
        output, _ = proc.communicate()
        if proc.returncode:
            print(f"tests/compile_kernels.py {part} failed:\n{output.decode(errors='replace')}")


def pytest_configure(config):
    """Under pytest-xdist, one numba thread per worker (2 workers x 2 threads on 2 cores
    oversubscribe the machine); tests that ask for more threads explicitly still get them,
    up to NUMBA_NUM_THREADS."""
    import os

    if os.environ.get("PYTEST_XDIST_WORKER"):
        import numba

        numba.set_num_threads(1)
