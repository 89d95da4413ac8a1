"""Shared test configuration.

Hypothesis runs with ``deadline=None`` (the first call of the compiled integrator triggers a
numba compilation that takes seconds) and ``derandomize=True`` (every run draws the same
examples, so a failure is reproducible in CI and locally), with 25 examples per property to
keep the suite fast. ``HYPOTHESIS_PROFILE=thorough`` draws 500 fresh random examples per
property for a deeper local search.
"""

from __future__ import annotations

import os

from hypothesis import settings

settings.register_profile(
    "granbayes", deadline=None, derandomize=True, database=None, max_examples=25
)
settings.register_profile("thorough", deadline=None, max_examples=500, database=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "granbayes"))


def pytest_configure(config):
    """Under pytest-xdist, one numba thread per worker (2 workers x 2 threads on 2 cores
    oversubscribe the machine); tests that ask for more threads explicitly still get them,
    up to NUMBA_NUM_THREADS."""
    import os

    if os.environ.get("PYTEST_XDIST_WORKER"):
        import numba

        numba.set_num_threads(1)
