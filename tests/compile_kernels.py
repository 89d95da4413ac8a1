"""Compile the numba kernels the tests use into numba's cache (run by tests/conftest.py).

``python tests/compile_kernels.py heights`` compiles the batched heights kernel, the
recorded trajectory and the intrusion curves; ``frames`` the batched kernel with frames
(tracked jumps) and the tracked-jump likelihood's sums. With a warm cache each part only
loads (about 2 s); on a fresh clone each compiles once (about 45 s on a slow 2-core
machine) what the two pytest-xdist workers would otherwise each compile when their tests
first need it (tests/conftest.py, ``pytest_sessionstart``).
"""

from __future__ import annotations

import sys

import numpy as np


def heights() -> None:
    """Heights (``simulate_batch``), a recorded trajectory and an intrusion curve."""
    import granbayes as gb

    law = {"k": 3000.0, "c_d": 50.0}
    gb.simulate("single", 0.612, law)
    gb.simulate_trajectory("single", 0.612, law)
    gb.intrusion_force(0.612, law, np.array([1.0, 2.0]), np.array([10.0, 10.0]))


def frames() -> None:
    """A tracked jump (``simulate_frames_batch``) and the tracked-jump likelihood's sums
    (called with the argument types of ``TrajectoryBlock._shift_terms``)."""
    import granbayes as gb
    from granbayes._likelihood._trajectories import _quadratic_sums

    gb.simulate_frames("single", 0.612, {"k": 3000.0, "c_d": 50.0}, np.linspace(0.0, 0.2, 20))
    n, grid, shifts, frames_, jumps = 2, 5, 3, 4, 2
    _quadratic_sums(
        np.zeros((n, grid)),
        np.zeros((n, grid)),
        np.zeros((shifts, frames_), dtype=np.int64),
        np.zeros(frames_),
        np.zeros((n, frames_)),
        np.ones((n, frames_)),
        np.array([0, 2], dtype=np.int64),
        np.zeros((3, n, shifts, jumps)),
    )


if __name__ == "__main__":
    {"heights": heights, "frames": frames}[sys.argv[1]]()
