"""Compile the numba kernels the tests use into numba's cache (run by tests/conftest.py).

``python tests/compile_kernels.py FOLDER`` compiles, in this order, the batched heights
kernel (``simulate_batch``), after which it creates the file ``FOLDER/heights``; then a
recorded trajectory, the intrusion curves, the batched kernel with frames (tracked jumps)
and the tracked-jump likelihood's sums, after which (or after a failure, then with its
traceback) it creates ``FOLDER/done``. One process, in this order, because the kernels share
their integrator's functions: compiled first with the heights kernel, they are loaded from
numba's cache by the others (the kernel with frames: ~19 s after the heights kernel, ~45 s
in a process of its own on a slow 2-core machine). With a warm cache everything only
loads (about 3 s). The pytest-xdist workers wait for these files (tests/conftest.py): the
hidden-effect diagnoses, which need the heights kernel only, run while this process
compiles the rest.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def heights() -> None:
    """The batched heights kernel (``simulate_batch``)."""
    import granbayes as gb

    gb.simulate("single", 0.612, {"k": 3000.0, "c_d": 50.0})


def the_rest() -> None:
    """A recorded trajectory, an intrusion curve, a tracked jump (``simulate_frames_batch``)
    and the tracked-jump likelihood's sums (with the argument types of
    ``TrajectoryBlock._shift_terms``)."""
    import granbayes as gb
    from granbayes._likelihood._trajectories import _quadratic_sums

    law = {"k": 3000.0, "c_d": 50.0}
    gb.simulate_trajectory("single", 0.612, law)
    gb.intrusion_force(0.612, law, np.array([1.0, 2.0]), np.array([10.0, 10.0]))
    gb.simulate_frames("single", 0.612, law, np.linspace(0.0, 0.2, 20))
    n, grid, shifts, frames_, jumps = 2, 5, 3, 4, 2
    _quadratic_sums(
        np.zeros((n, grid, 4)),
        np.zeros(1, dtype=np.int64),
        np.zeros((shifts, frames_), dtype=np.int64),
        np.zeros((1, frames_)),
        np.full(frames_, np.inf),
        np.ones((n, jumps)),
        np.ones((n, 1, jumps)),
        np.array([0, 2], dtype=np.int64),
        np.zeros((3, n, shifts, jumps)),
        np.zeros((n, jumps)),
    )


if __name__ == "__main__":
    folder = Path(sys.argv[1])
    outcome = "ok"
    try:
        heights()
        (folder / "heights").touch()
        the_rest()
    except BaseException:
        import traceback

        outcome = traceback.format_exc()
        raise
    finally:
        (folder / "done").write_text(outcome)
