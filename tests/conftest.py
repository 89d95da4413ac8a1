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


@pytest.fixture(scope="session")
def kill_when_written() -> Callable[[list, Path, str], None]:
    """``kill_when_written(command, folder, pattern)``: run ``command`` (a list of
    arguments) in a process group of its own, with its output discarded, and kill the
    whole group (the command and any local Dask cluster it started) with SIGKILL as soon
    as ``folder`` holds a file matching ``pattern``. Fails if the command ends first or
    nothing is written within 120 s: the tests of resuming a killed campaign use it."""
    import signal
    import subprocess
    import time

    def run(command: list, folder: Path, pattern: str) -> None:
        proc = subprocess.Popen(
            command,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,  # the command and its local cluster: one group to kill
        )
        try:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and proc.poll() is None:
                if list(folder.glob(pattern)):
                    break
                time.sleep(0.02)
            assert proc.poll() is None, f"{command[0]} ended before it could be killed"
            assert list(folder.glob(pattern)), f"nothing matching {pattern} in {folder}"
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=30)

    return run


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the tests that need no kernel first (:data:`KERNEL_FREE`, while the heights
    kernel compiles), then the longest: the hidden-effect cases of ``ci_subset`` (a
    diagnosis each, ~40-60 s), then the fast tests marked ``long`` (> ~10 s), then the
    rest in file order. pytest-xdist hands the tests out one at a time in this order, so
    the two workers end together instead of one running a minute-long test while the
    other idles (longest first is the classic greedy rule for two machines). A stable
    sort: within each class the file order, and so the sharing of module fixtures, is
    kept.

    With ``--dist loadgroup`` (``make test``) xdist puts groups of several tests before
    single ones (the installed-wheel tests, ~15 s, are one group). The other kernels
    compile while the first tests run (:func:`pytest_sessionstart`)."""

    def rank(item: pytest.Item) -> int:
        if item.path.name in KERNEL_FREE:
            return -1
        if item.get_closest_marker("ci_subset"):
            return 0
        return 1 if item.get_closest_marker("long") else 2

    items.sort(key=rank)


#: The environment variables by which the pytest-xdist workers find the kernels' compilation
#: (:func:`pytest_sessionstart`): the folder of its files and its process id.
FOLDER_VARIABLE, PID_VARIABLE = "GRANBAYES_TEST_KERNELS", "GRANBAYES_TEST_KERNELS_PID"

_compilation: dict = {}


def pytest_sessionstart(session: pytest.Session) -> None:
    """Under pytest-xdist, compile the numba kernels into numba's cache in one process
    beside the workers (tests/compile_kernels.py): the heights kernel first, then the
    others. The workers' first tests need no kernel (:data:`KERNEL_FREE`); the
    hidden-effect diagnoses (``ci_subset``) wait for the heights kernel, every other
    test for all of them (:func:`_kernels_compiled`).

    Each kernel specialization takes 10-35 s to compile on a fresh clone, and numba's
    cache is shared through the files only: two workers whose first tests need the same
    specialization each compile it, and did (a fresh-clone run on a slow machine spent
    ~150 s of its workers' time compiling, about twice the compilation itself). One
    process, because the kernels share their integrator's functions: the kernel with
    frames compiled in a process of its own compiled them again (~26 s of ~45 s). Runs
    from the controlling process (this hook precedes pytest-xdist's, which starts the
    workers); with a warm cache it only loads (~3 s). If the compilation fails, the
    workers go on (their tests then compile, and fail, on their own) and the failure is
    printed at the end of the session."""
    config = session.config
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    import subprocess
    import sys
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix="granbayes-kernels-"))
    script = Path(__file__).with_name("compile_kernels.py")
    log = open(folder / "compile.log", "wb")  # closed in pytest_sessionfinish
    proc = subprocess.Popen(
        [sys.executable, str(script), str(folder)], stdout=log, stderr=subprocess.STDOUT
    )
    _compilation.update(proc=proc, log=log, folder=folder)
    os.environ[FOLDER_VARIABLE], os.environ[PID_VARIABLE] = str(folder), str(proc.pid)


def pytest_sessionfinish(session: pytest.Session) -> None:
    """Wait for the kernels' compilation (:func:`pytest_sessionstart`); print its output
    if it failed."""
    if not _compilation:
        return
    import shutil

    proc, log, folder = _compilation["proc"], _compilation["log"], _compilation["folder"]
    code = proc.wait()
    log.close()
    if code:
        text = (folder / "compile.log").read_text(errors="replace")
        print(f"tests/compile_kernels.py failed (exit {code}):\n{text}")
    shutil.rmtree(folder, ignore_errors=True)


#: Test modules none of whose fast tests runs a numba kernel in its own process (each run
#: alone, 2026-11-28: no dispatcher of ``granbayes._kernel`` had a signature afterwards).
#: They run first, while the kernels compile (:func:`_kernels_compiled`); a test of one
#: that did need a kernel would compile it itself (time, not a failure).
KERNEL_FREE = frozenset(
    {
        "test_benchmarks.py",
        "test_docs.py",
        "test_elpd_difference.py",
        "test_experiment.py",
        "test_figures.py",
        "test_lab_data.py",
        "test_layers.py",
        "test_moment_matching.py",
        "test_oracle_effects.py",
        "test_oracle_kinds.py",
        "test_packaging.py",
        "test_search.py",
        "test_starts.py",
    }
)

_compiled: set[str] = set()


@pytest.fixture(autouse=True)
def _kernels_compiled(request: pytest.FixtureRequest) -> None:
    """In a pytest-xdist worker, before a test outside :data:`KERNEL_FREE`: wait until the
    kernels it may need are in numba's cache, the heights kernel for the hidden-effect
    diagnoses (``ci_subset``), all of them for the others (or until the compilation has
    ended, whatever its outcome; :func:`pytest_sessionstart`)."""
    folder = os.environ.get(FOLDER_VARIABLE)
    if not folder or not os.environ.get("PYTEST_XDIST_WORKER"):
        return
    if request.node.path.name in KERNEL_FREE:
        return
    needed = "heights" if request.node.get_closest_marker("ci_subset") else "done"
    if needed in _compiled or "done" in _compiled:
        return
    import time

    pid = int(os.environ[PID_VARIABLE])
    deadline = time.monotonic() + 900.0
    while time.monotonic() < deadline:
        if (Path(folder) / needed).exists() or (Path(folder) / "done").exists():
            break
        try:  # killed before it could say so (then a zombie until the session's end)
            os.kill(pid, 0)
            status = Path(f"/proc/{pid}/status")
            if status.exists() and "State:\tZ" in status.read_text():
                break
        except OSError:
            break
        time.sleep(0.1)
    _compiled.add(needed)


def pytest_configure(config):
    """Under pytest-xdist, one numba thread per worker (2 workers x 2 threads on 2 cores
    oversubscribe the machine); tests that ask for more threads explicitly still get them,
    up to NUMBA_NUM_THREADS."""
    import os

    if os.environ.get("PYTEST_XDIST_WORKER"):
        import numba

        numba.set_num_threads(1)
